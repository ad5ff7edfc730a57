"""What every part of kgnav shares: atomic file writes (:mod:`~kgnav.common.atomic`), SE(2)
poses (:mod:`~kgnav.common.se2`), the object-class vocabulary (:mod:`~kgnav.common.classes`) and
an exact, run-to-run identical distance transform (:mod:`~kgnav.common.edt`)."""
