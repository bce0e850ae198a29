"""The candidate effects each model can add, as changes to the model with the parameters a log
estimates (:mod:`.candidate`): the altitude model's (:mod:`.altitude`), the attitude model's
(:mod:`.attitude`) and the thrust model's (:mod:`.thrust`; its filter :mod:`.thrust_model`, with
the airframe's thrust curve and the battery it reads), and thrust lost with the battery, traced
beside the altitude model (:mod:`.thrust_side`)."""
