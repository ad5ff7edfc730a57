"""Errors a user can cause. Each names what was wrong (file, class, size) and why.

The CLI turns any :class:`KgnavError` into one line on stderr and exit status 1.
"""

from __future__ import annotations

import os
from collections.abc import Sequence


class KgnavError(Exception):
    """Base class of every error kgnav raises for bad input."""


class ModelFileError(KgnavError):
    """A model file cannot be read: missing, corrupt, foreign or of another schema version."""

    def __init__(self, path: str | os.PathLike[str], reason: str):
        self.path = os.fspath(path)
        self.reason = reason
        super().__init__(f"{self.path}: {reason}")


class SchemaVersionError(ModelFileError):
    """The file is a kgnav model written with a schema version this release cannot read."""


class FeatureDimError(KgnavError, ValueError):
    """A feature vector does not have the model's dimension."""

    def __init__(self, got: object, expected: int):
        self.got = got
        self.expected = expected
        super().__init__(f"feature vector has shape {got}, expected ({expected},)")


class UnknownClassError(KgnavError, ValueError):
    """An object class is not in the vocabulary in use."""

    def __init__(self, name: str, classes: Sequence[str]):
        self.name = name
        self.classes = tuple(classes)
        shown = ", ".join(self.classes[:12]) + (", ..." if len(self.classes) > 12 else "")
        super().__init__(f"unknown object class {name!r} (known: {shown})")


class UnknownStateError(KgnavError, KeyError):
    """A state id that the model does not hold."""

    def __init__(self, state: str, model_id: str = ""):
        self.state = state
        where = f" in model {model_id!r}" if model_id else ""
        super().__init__(f"no state {state!r}{where}")

    def __str__(self) -> str:  # KeyError would quote the whole message
        return self.args[0]


class StoreError(KgnavError):
    """A model store operation failed (missing model, unwritable directory, lock timeout)."""


class SceneFileError(KgnavError):
    """A simulator scene or episode file cannot be read or fails validation."""

    def __init__(self, path: str | os.PathLike[str], reason: str):
        self.path = os.fspath(path)
        self.reason = reason
        super().__init__(f"{self.path}: {reason}")
