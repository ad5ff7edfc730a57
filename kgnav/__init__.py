"""kgnav: reusable Abstract Models for Object Goal Navigation.

>>> from kgnav import AbstractModel, Detection, ModelStore, Relocator, merge
"""

from kgnav.errors import (
    FeatureDimError,
    KgnavError,
    ModelFileError,
    SchemaVersionError,
    StoreError,
    UnknownClassError,
    UnknownStateError,
)
from kgnav.merge import best_anchor, merge
from kgnav.model import ACTIONS, AbstractModel, Detection, ObjectInfo
from kgnav.relocator import Match, Relocator
from kgnav.store import ModelStore

__version__ = "0.1.0"

__all__ = [
    "ACTIONS",
    "AbstractModel",
    "Detection",
    "FeatureDimError",
    "KgnavError",
    "Match",
    "ModelFileError",
    "ModelStore",
    "ObjectInfo",
    "Relocator",
    "SchemaVersionError",
    "StoreError",
    "UnknownClassError",
    "UnknownStateError",
    "best_anchor",
    "merge",
]
