"""From tracked points to contractions: calibration on the neutral frame
(:mod:`.calibration`), the face model's response at the measurement points
(:mod:`.response`, :mod:`.model_response`), the estimators (:mod:`.estimators`,
:mod:`.flow`, :mod:`.refine`) and the registry that names them (:mod:`.registry`)."""
