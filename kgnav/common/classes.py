"""The object-class vocabulary shared by the simulator, the segmenter and the Abstract Models.

A model records the vocabulary it was built with (``AbstractModel(classes=...)``), so a user with
another segmenter (Matterport's 40 classes, COCO, ...) passes their own list; this one is the
default and is what the embedded simulator places in its houses.
"""

from __future__ import annotations

#: Every class the embedded simulator can place; 1-based index = semantic class id (0 = none).
OBJECT_CLASSES: tuple[str, ...] = (
    "chair",
    "bed",
    "plant",
    "toilet",
    "tv_monitor",
    "sofa",
    "table",
    "sink",
    "bathtub",
    "shower",
    "cabinet",
    "chest_of_drawers",
    "wardrobe",
    "desk",
    "bookshelf",
    "fridge",
    "stove",
    "counter",
    "fireplace",
    "nightstand",
    "lamp",
    "washing_machine",
    "piano",
    "stool",
)

#: The six ObjectNav challenge goal classes.
OBJECTNAV_CLASSES: tuple[str, ...] = ("chair", "bed", "plant", "toilet", "tv_monitor", "sofa")

#: The paper's eight "stable" classes (its "tv" is our ``tv_monitor``).
STABLE_CLASSES: tuple[str, ...] = (
    "chair",
    "sofa",
    "plant",
    "bed",
    "toilet",
    "tv_monitor",
    "table",
    "sink",
)


def class_id(name: str, classes: tuple[str, ...] = OBJECT_CLASSES) -> int:
    """Semantic id of a class: its 1-based index in ``classes`` (0 means "no object").

    >>> class_id("chair")
    1
    """
    from kgnav.errors import UnknownClassError

    try:
        return classes.index(name) + 1
    except ValueError:
        raise UnknownClassError(name, classes) from None
