"""The 3-DOF lab helicopter's closed loop: a rig session's readings (:mod:`.session`), the lab's
model and what a rig adds to it as numbers to fit (:mod:`.model`, :mod:`.catalogue`), the search
that finds what the session shows (:mod:`.identify`), the model's error before and after
(:mod:`.predict`, :mod:`.kalman`), the steps in order (:mod:`.diagnose`), and the files
(:mod:`.report`)."""
