"""The model run over a prepared log: the filter's trajectory, innovations and gains (:mod:`.run`),
the signals the regressors read, kept current as it goes (:mod:`.signals`), the regressors'
signatures through its gains (:mod:`.signature`), and the throttle between its records
(:mod:`.outputs`)."""
