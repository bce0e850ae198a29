"""Control in the loop: the design documents' controllers, fed by the ground
station's measurements and estimates, commanding the vehicle over its link.

* :mod:`.design`: gains from the lab document's equations (pole placement,
  LQR through scipy's Riccati solver, reference feed-forward);
* :mod:`.controllers`: PD pitch, LQR with feed-forward, LQR with integral
  action (3-DOF helicopter), altitude hold (quadcopter, coaxial helicopter),
  each with actuator saturation and, where it integrates, anti-windup;
* :mod:`.feedback`: where the controller's state comes from (encoders, the
  Kalman filter, raw IMU, an open-loop predictor, the altitude filter);
* :mod:`.uplink`: commands into bytes on the vehicle's own link;
* :mod:`.commander`: arming, the fixed-rate command loop, link-loss stop;
* :mod:`.station`: what each vehicle offers, and the commander in charge (the
  dashboard's Control panel, :mod:`web.control_panel`, drives it);
* :mod:`.response`: omega_0 and zeta fitted to a step, and the lab's words for it;
* :mod:`.offline`: the same pieces against the simulator stepped as fast as it
  goes (benchmarks and fast tests).
"""
