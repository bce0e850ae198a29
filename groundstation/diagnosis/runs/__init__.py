"""The model run over a prepared log: the filter's trajectory, innovations and gains (:mod:`.run`), the
regressors' signatures through those gains (:mod:`.signature`), and the throttle between its records
(:mod:`.outputs`)."""
