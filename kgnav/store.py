"""A directory of Abstract Models, one GraphML file per model: the agent's long-term memory.

Writes take a lock file in the directory and replace files atomically, so two processes saving to
one store never leave a half-written file, and a crash mid-save keeps the previous version. A file
that is corrupt, foreign or of another schema version is reported with its name and the reason
and skipped — never deleted — and the rest of the store still loads.

>>> import tempfile, numpy as np
>>> from kgnav import AbstractModel
>>> store = ModelStore(tempfile.mkdtemp())
>>> m = AbstractModel(feature_dim=2, model_id="house-1")
>>> _ = m.add_state(np.ones(2), pose=(0, 0, 0))
>>> _ = store.save(m)
>>> store.ids()
['house-1']
>>> store.load("house-1") == m
True
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

from filelock import FileLock, Timeout

from kgnav.errors import ModelFileError, StoreError
from kgnav.graphml import read_model, write_model
from kgnav.model import SAFE_ID, AbstractModel


@dataclass(frozen=True)
class StoreProblem:
    """A file of the store that could not be loaded, and why."""

    path: str
    reason: str

    def __str__(self) -> str:
        return f"{self.path}: {self.reason}"


class ModelStore:
    """One GraphML file per model under ``root`` (created if missing).

    Parameters
    ----------
    root:
        The directory.
    lock_timeout:
        Seconds to wait for another writer before raising :class:`StoreError`.
    """

    SUFFIX = ".graphml"
    LOCK_NAME = ".kgnav-store.lock"

    def __init__(self, root: str | os.PathLike[str], *, lock_timeout: float = 60.0):
        self.root = Path(root)
        if self.root.exists() and not self.root.is_dir():
            raise StoreError(f"{self.root}: not a directory")
        self.lock_timeout = lock_timeout

    def __repr__(self) -> str:
        return f"ModelStore({str(self.root)!r})"

    # ------------------------------------------------------------------ naming
    def path_of(self, model_id: str) -> Path:
        """The file that holds ``model_id``; the id must be a plain file-name stem."""
        if not isinstance(model_id, str) or not SAFE_ID.match(model_id):
            raise StoreError(
                f"invalid model id {model_id!r}: use letters, digits and _ . + - (max 128)"
            )
        return self.root / f"{model_id}{self.SUFFIX}"

    def ids(self) -> list[str]:
        """Ids of the model files present, sorted (hidden and temporary files are ignored)."""
        if not self.root.is_dir():
            return []
        return sorted(
            p.name[: -len(self.SUFFIX)]
            for p in self.root.iterdir()
            if p.name.endswith(self.SUFFIX) and not p.name.startswith(".") and p.is_file()
        )

    def __contains__(self, model_id: object) -> bool:
        return isinstance(model_id, str) and model_id in self.ids()

    def __len__(self) -> int:
        return len(self.ids())

    def __iter__(self) -> Iterator[str]:
        return iter(self.ids())

    # ------------------------------------------------------------------ locking
    def _lock(self) -> FileLock:
        self.root.mkdir(parents=True, exist_ok=True)
        return FileLock(str(self.root / self.LOCK_NAME), timeout=self.lock_timeout)

    def _locked(self):
        lock = self._lock()
        try:
            lock.acquire()
        except Timeout:
            raise StoreError(
                f"{self.root}: another writer held the store lock for {self.lock_timeout:g} s"
            ) from None
        return lock

    # ------------------------------------------------------------------ reading
    def load(self, model_id: str) -> AbstractModel:
        """Load one model; raises :class:`StoreError` if absent, :class:`ModelFileError` if bad."""
        path = self.path_of(model_id)
        if not path.is_file():
            raise StoreError(f"{self.root}: no model {model_id!r}")
        model = read_model(path)
        if model.model_id != model_id:
            raise ModelFileError(
                path, f"holds model {model.model_id!r}, but its file name says {model_id!r}"
            )
        return model

    def load_all(self) -> tuple[dict[str, AbstractModel], list[StoreProblem]]:
        """Every loadable model by id, and a problem per file that could not be loaded."""
        models: dict[str, AbstractModel] = {}
        problems: list[StoreProblem] = []
        for model_id in self.ids():
            try:
                models[model_id] = self.load(model_id)
            except (ModelFileError, StoreError) as exc:
                problems.append(StoreProblem(str(self.path_of(model_id)), _reason(exc)))
        return models, problems

    # ------------------------------------------------------------------ writing
    def save(self, model: AbstractModel) -> Path:
        """Write ``model`` as ``<model_id>.graphml`` (atomic, under the store lock)."""
        path = self.path_of(model.model_id)
        lock = self._locked()
        try:
            write_model(model, path)
        except OSError as exc:
            raise StoreError(f"{path}: cannot write ({exc.strerror or exc})") from None
        finally:
            lock.release()
        return path

    def update(
        self, model_id: str, fn: Callable[[AbstractModel | None], AbstractModel]
    ) -> AbstractModel:
        """Read-modify-write under the lock: ``fn(current or None)`` returns the model to save.

        Use this when several processes may extend the same model, so no update is lost.
        """
        lock = self._locked()
        try:
            current = self.load(model_id) if self.path_of(model_id).is_file() else None
            new = fn(current)
            if new.model_id != model_id:
                raise StoreError(f"update of {model_id!r} returned model {new.model_id!r}")
            write_model(new, self.path_of(model_id))
            return new
        finally:
            lock.release()

    def delete(self, model_id: str) -> None:
        """Remove a model's file; raises :class:`StoreError` if it is not there."""
        path = self.path_of(model_id)
        lock = self._locked()
        try:
            path.unlink()
        except FileNotFoundError:
            raise StoreError(f"{self.root}: no model {model_id!r}") from None
        finally:
            lock.release()


def _reason(exc: Exception) -> str:
    return exc.reason if isinstance(exc, ModelFileError) else str(exc)
