"""What every part of kgnav shares: atomic file writes (:mod:`~kgnav.common.atomic`), SE(2)
poses (:mod:`~kgnav.common.se2`) and the object-class vocabulary (:mod:`~kgnav.common.classes`)."""
