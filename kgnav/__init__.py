"""kgnav: reusable Abstract Models for Object Goal Navigation.

Three faces: the knowledge-graph memory (:mod:`kgnav.memory`, whose main names are here), the
ObjectNav agent (:mod:`kgnav.agent`, its learned parts in :mod:`kgnav.nets`) and the benchmark
(:mod:`kgnav.benchmark`, over :mod:`kgnav.envs` and the embedded simulator :mod:`kgnav.sim`).

>>> from kgnav import AbstractModel, Detection, ModelStore, Relocator, merge, query
"""

import sys as _sys
import types as _types

from kgnav import _deprecated
from kgnav.errors import (
    FeatureDimError,
    KgnavError,
    ModelFileError,
    SchemaVersionError,
    StoreError,
    UnknownClassError,
    UnknownStateError,
)
from kgnav.memory import query
from kgnav.memory.merge import best_anchor, merge
from kgnav.memory.model import ACTIONS, AbstractModel, Detection, ObjectInfo
from kgnav.memory.relocator import Match, Relocator
from kgnav.memory.store import ModelStore

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
    "query",
]

_deprecated.install()


class _Package(_types.ModuleType):
    # Importing the old module path ``kgnav.merge`` makes the import system bind that module as
    # ``kgnav.merge``, over the public function of the same name: the function stays.
    def __setattr__(self, name, value):
        if name == "merge" and isinstance(value, _types.ModuleType):
            return
        super().__setattr__(name, value)


_sys.modules[__name__].__class__ = _Package
