"""How a candidate is scored on a log: through the base run's gains (:mod:`.gains`, the two-stage
filter) or by runs of its own (:mod:`.trials`), ranked (:mod:`.trace`) as its scores
(:mod:`.scored`), held out (:mod:`.holdout`), and each sensor's noise matched to the log first
(:mod:`.noise_match`)."""
