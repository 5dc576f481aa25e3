"""How far to trust the analysis: scores against ground truth (:mod:`.scores`), the
standard suite of rendered sequences (:mod:`.suite`), the exact-point ceiling
(:mod:`.ceiling`), flow validation of a resynthesis (:mod:`.validation`), the round trip
(:mod:`.roundtrip`) and the demo (:mod:`.demo`)."""
