"""How far to trust the analysis: scores against ground truth (:mod:`.scores`), the
standard suite of rendered sequences (:mod:`.suite`), the exact-point ceiling
(:mod:`.ceiling`), how much of the skin's motion the tracked points report
(:mod:`.motion_gain`), flow validation of a resynthesis (:mod:`.validation`), the round trip
(:mod:`.roundtrip`) and the demo (:mod:`.demo`)."""
