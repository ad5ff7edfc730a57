"""Failure analysis from ground truth (paper, "Limitations and Failure analysis").

Each failed episode gets one class, decided from the agent's last object target (where it was
heading when the episode ended) and the true goal instances:

* **Last Mile**: the target was a true goal instance (one lies within ``near`` metres of the
  target point) and the agent ended with DTS < 2 m, yet did not succeed;
* **Hallucination**: the target came from a stored model only (source ``memory``) and no goal
  instance lies near it: the memory was wrong (or wrongly aligned);
* **Detection**: the target came from this episode's perception (``episode``/``live``) and no
  goal instance lies near it: the agent approached a false positive;
* **Exploration**: the agent never had an object target: it did not find the goal in time;
* **Misc**: the rest (a true goal as target but the agent ended far from it: trapped, lost).

>>> classify(True, 0.0, None, float("inf"))
>>> classify(False, 3.0, None, float("inf"))
'Exploration'
>>> classify(False, 0.5, "episode", 0.4)
'Last Mile'
>>> classify(False, 0.5, "memory", 4.0)
'Hallucination'
"""

from __future__ import annotations

FAILURE_CLASSES = ("Last Mile", "Hallucination", "Detection", "Exploration", "Misc")
NEAR = 1.5  # m: a target point this close to a true instance "is" that instance


def classify(success: bool, dts: float, target_source: str | None,
             target_to_goal: float, near: float = NEAR) -> str | None:
    """The failure class of an episode (``None`` for a success).

    ``target_source`` is the source of the last object target (``None`` if there was none);
    ``target_to_goal`` the L2 distance (m) from that target point to the nearest true goal
    instance footprint.
    """
    if success:
        return None
    if target_source is None:
        return "Exploration"
    if target_to_goal <= near:
        return "Last Mile" if dts < 2.0 else "Misc"
    if target_source == "memory":
        return "Hallucination"
    if target_source in ("episode", "live"):
        return "Detection"
    return "Misc"
