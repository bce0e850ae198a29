"""What a diagnosis claims and on what evidence: the residuals' tests (:mod:`.detect`), the search an
effect at a time (:mod:`.search`), a correlate outside the catalogue (:mod:`.discover`,
:mod:`.discovered`), the effects estimated together (:mod:`.joint`), and each absolute sensor
predicted by the others (:mod:`.leave_one_out`)."""
