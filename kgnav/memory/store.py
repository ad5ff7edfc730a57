"""A directory of Abstract Models, one GraphML file per model: the agent's long-term memory.

Writes take a lock file in the directory and replace files atomically, so two processes saving to
one store never leave a half-written file, and a crash mid-save keeps the previous version. A file
that is corrupt, foreign or of another schema version is reported with its name and the reason
and skipped — never deleted — and the rest of the store still loads; so is an entry named like a
model that is not a regular file (a directory, a FIFO, a dangling symbolic link or a loop).

Symbolic links are followed: a link ``<id>.graphml`` to a model file is that model, and saving it
writes the file the link points to (see :mod:`kgnav.common.atomic`). Every locked write also
removes the temporary files that killed writers on this host left behind; :meth:`ModelStore.check`
reports everything else that is wrong, changing nothing.

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
>>> store.check()
(['house-1'], [])
"""

from __future__ import annotations

import contextlib
import errno
import os
import stat
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from filelock import FileLock, Timeout

from kgnav.common import atomic
from kgnav.errors import ModelFileError, StoreError
from kgnav.memory.graphml import describe_mode, write_model
from kgnav.memory.model import SAFE_ID, AbstractModel
from kgnav.registry import Registry


@dataclass(frozen=True)
class StoreProblem:
    """Something wrong in a store, and why.

    ``kind`` is ``"model"`` (a model file that does not load), ``"entry"`` (named like a model
    but not a regular file) or ``"temp"`` (a temporary file a save left behind).
    """

    path: str
    reason: str
    kind: str = "model"

    def __str__(self) -> str:
        return f"{self.path}: {self.reason}"


@dataclass(frozen=True)
class FeatureBatch:
    """Some consecutive states of one stored model and their features, as
    :meth:`ModelStore.feature_batches` streams them to a relocator."""

    model_id: str
    extractor: str
    feature_dim: int
    state_ids: list[str]
    features: np.ndarray  # (len(state_ids), feature_dim) float32
    #: The model turned out bad after some of its batches were sent: forget all of it.
    retract: bool = False


#: Where a store keeps its models, by name: ``directory`` (one GraphML file per model, this
#: module) and ``ladybug`` (an embedded graph database, :mod:`kgnav.memory.graphdb`, imported on
#: first use).
BACKENDS: Registry[type] = Registry("store backend", plugins=("kgnav.memory.graphdb",))
#: File names that hold a graph database rather than name a directory.
DB_SUFFIXES = (".lbug", ".kuzu", ".kgdb")


def backend_of(root: str | os.PathLike[str]) -> str:
    """``ladybug`` for a path ending in one of :data:`DB_SUFFIXES`, else ``directory``."""
    return "ladybug" if Path(root).suffix in DB_SUFFIXES else "directory"


def check_model_id(model_id) -> None:
    """A :class:`StoreError` unless ``model_id`` is a plain name (it names files and keys)."""
    if not isinstance(model_id, str) or not SAFE_ID.match(model_id):
        raise StoreError(
            f"invalid model id {model_id!r}: use letters, digits and _ . + - (max 128)"
        )


@BACKENDS.register("directory")
class ModelStore:
    """The memory: Abstract Models by id. ``ModelStore(path)`` keeps them as one GraphML file per
    model under the directory ``path`` (created if missing), or in a graph database when
    ``path`` names one (:func:`backend_of`; :class:`kgnav.memory.graphdb.GraphDBStore`): the
    same interface either way.

    Parameters
    ----------
    root:
        The directory.
    lock_timeout:
        Seconds to wait for another writer before raising :class:`StoreError`.
    max_bytes:
        Largest model file read (see :func:`kgnav.memory.graphml.read_graph`).
    """

    SUFFIX = ".graphml"
    LOCK_NAME = ".kgnav-store.lock"

    def __new__(cls, root: str | os.PathLike[str], **kwargs):
        if cls is ModelStore and backend_of(root) != "directory":
            cls = BACKENDS.get(backend_of(root))
        return super().__new__(cls)

    def __init__(
        self,
        root: str | os.PathLike[str],
        *,
        lock_timeout: float = 60.0,
        max_bytes: int | None = None,
    ):
        self.root = Path(root)
        if self.root.exists() and not self.root.is_dir():
            raise StoreError(f"{self.root}: not a directory")
        self.lock_timeout = lock_timeout
        self.max_bytes = max_bytes

    def __repr__(self) -> str:
        return f"ModelStore({str(self.root)!r})"

    # ------------------------------------------------------------------ naming
    def path_of(self, model_id: str) -> Path:
        """The file that holds ``model_id``; the id must be a plain file-name stem."""
        check_model_id(model_id)
        return self.root / f"{model_id}{self.SUFFIX}"

    def _listing(self) -> list[Path]:
        """Every entry of the directory, sorted by name (none if it does not exist)."""
        try:
            return sorted(self.root.iterdir())
        except FileNotFoundError:
            return []
        except OSError as exc:
            raise StoreError(f"{self.root}: cannot list ({exc.strerror or exc})") from None

    def _entries(self) -> Iterator[tuple[str, Path, str | None]]:
        """``(model id, path, problem)`` of each entry named like a model file (not hidden);
        ``problem`` says why it is not a regular file, or is None."""
        for p in self._listing():
            if p.name.endswith(self.SUFFIX) and not p.name.startswith("."):
                yield p.name[: -len(self.SUFFIX)], p, _not_a_file(p)

    def ids(self) -> list[str]:
        """Ids of the model files present, sorted (hidden and temporary files are ignored)."""
        return [model_id for model_id, _, problem in self._entries() if problem is None]

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
        """Take the store lock; then remove what killed writers on this host left behind."""
        try:
            lock = self._lock()
            lock.acquire()
        except Timeout:
            raise StoreError(
                f"{self.root}: another writer held the store lock for {self.lock_timeout:g} s"
            ) from None
        except OSError as exc:
            raise StoreError(f"{self.root}: cannot lock ({exc.strerror or exc})") from None
        self.remove_stale_temps()
        return lock

    def remove_stale_temps(self) -> list[Path]:
        """Delete the temporary files of saves whose writer (on this host) is gone.

        Called under the lock by every write; returns what it removed.
        """
        removed = []
        with contextlib.suppress(StoreError):
            for p in self._listing():
                if atomic.stale_temp(p.name):
                    with contextlib.suppress(OSError):
                        p.unlink()
                        removed.append(p)
        return removed

    # ------------------------------------------------------------------ reading
    def load(self, model_id: str) -> AbstractModel:
        """Load one model; raises :class:`StoreError` if absent, :class:`ModelFileError` if bad."""
        path = self.path_of(model_id)
        if not os.path.lexists(path):
            raise StoreError(f"{self.root}: no model {model_id!r}")
        model = AbstractModel.load(path, max_bytes=self.max_bytes)
        if model.model_id != model_id:
            raise ModelFileError(
                path, f"holds model {model.model_id!r}, but its file name says {model_id!r}"
            )
        return model

    def each(self) -> Iterator[tuple[str, AbstractModel | None, StoreProblem | None]]:
        """Every model id with its model, or with the problem that kept it from loading: one
        model in memory at a time."""
        for model_id, path, problem in self._entries():
            if problem is not None:
                yield model_id, None, StoreProblem(str(path), problem, "entry")
                continue
            try:
                yield model_id, self.load(model_id), None
            except (ModelFileError, StoreError) as exc:
                yield model_id, None, StoreProblem(str(path), _reason(exc))

    def load_all(self) -> tuple[dict[str, AbstractModel], list[StoreProblem]]:
        """Every loadable model by id, and a problem per entry named like a model file that
        could not be loaded (a bad file, or not a file)."""
        models: dict[str, AbstractModel] = {}
        problems: list[StoreProblem] = []
        for model_id, model, problem in self.each():
            if model is not None:
                models[model_id] = model
            else:
                problems.append(problem)
        return models, problems

    def reading(self):
        """A block whose reads share one open store: a no-op for a directory (each model is its
        own file); a graph database stays open inside it (see
        :meth:`kgnav.memory.graphdb.GraphDBStore.reading`)."""
        return contextlib.nullcontext(self)

    def feature_batches(self, problems: list[StoreProblem] | None = None
                        ) -> Iterator[FeatureBatch]:
        """Every model's state features, model by model in id order and each model's states in
        its order, without holding more than one model: what fitting a relocator needs. A model
        that does not load is skipped and appended to ``problems``."""
        for model_id, model, problem in self.each():
            if model is None:
                if problems is not None:
                    problems.append(problem)
                continue
            ids, feats = model.state_features()
            yield FeatureBatch(model_id, model.extractor, model.feature_dim, ids, feats)

    def state_count(self) -> int | None:
        """How many states the store holds, when it can say so without loading models (a
        directory cannot: None)."""
        return None

    def revision(self) -> str:
        """A token that changes whenever a model is saved, replaced or deleted: an index built
        from the store (:meth:`kgnav.memory.relocator.Relocator.open`) is current while it holds
        the same token. Here: each model file's name, inode, size and modification time (an
        atomic save always makes a new inode)."""
        import hashlib

        h = hashlib.blake2b(digest_size=16)
        for model_id, path, _problem in self._entries():
            try:
                st = os.stat(path)
            except OSError:
                continue
            h.update(f"{model_id}\0{st.st_ino}\0{st.st_size}\0{st.st_mtime_ns}\n".encode())
        return "files:" + h.hexdigest()

    def index_path(self) -> Path:
        """Where a relocator index built from this store is kept (inside the directory, hidden
        so that it is never taken for a model)."""
        return self.root / ".relocator.npz"

    def check(self) -> tuple[list[str], list[StoreProblem]]:
        """Everything wrong in the store, changing nothing: the ids that load, and a problem per
        model file that does not, per entry named like one that is not a regular file, and per
        temporary file that no running save on this host owns (one whose writer was killed,
        runs on another host, or predates the writer's name in the file name)."""
        good: list[str] = []
        problems: list[StoreProblem] = []
        for model_id, model, problem in self.each():  # one model in memory at a time
            if model is not None:
                good.append(model_id)
            else:
                problems.append(problem)
        for p in self._listing():
            reason = _temp_problem(p.name)
            if reason is not None:
                problems.append(StoreProblem(str(p), reason, "temp"))
        return good, problems

    # ------------------------------------------------------------------ writing
    def save(self, model: AbstractModel) -> Path:
        """Write ``model`` as ``<model_id>.graphml`` (atomic, under the store lock)."""
        path = self.path_of(model.model_id)
        lock = self._locked()
        try:
            _write(model, path)
        finally:
            lock.release()
        return path

    def update(
        self, model_id: str, fn: Callable[[AbstractModel | None], AbstractModel]
    ) -> AbstractModel:
        """Read-modify-write under the lock: ``fn(current or None)`` returns the model to save.

        Use this when several processes may extend the same model, so no update is lost.
        """
        path = self.path_of(model_id)
        lock = self._locked()
        try:
            current = self.load(model_id) if os.path.lexists(path) else None
            new = fn(current)
            if new.model_id != model_id:
                raise StoreError(f"update of {model_id!r} returned model {new.model_id!r}")
            _write(new, path)
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
        except OSError as exc:
            raise StoreError(f"{path}: cannot delete ({exc.strerror or exc})") from None
        finally:
            lock.release()


def _write(model: AbstractModel, path: Path) -> None:
    try:
        write_model(model, path)
    except OSError as exc:
        raise StoreError(f"{path}: cannot write ({exc.strerror or exc})") from None


def _reason(exc: Exception) -> str:
    return exc.reason if isinstance(exc, ModelFileError) else str(exc)


def _not_a_file(path: Path) -> str | None:
    """Why ``path`` (links followed) is not a regular file, or None."""
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        if path.is_symlink():
            return f"dangling symbolic link (to {os.readlink(path)})"
        return "vanished while listing"
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            return "symbolic link loop"
        return f"cannot stat ({exc.strerror or exc})"
    return None if stat.S_ISREG(mode) else f"not a regular file ({describe_mode(mode)})"


def _temp_problem(name: str) -> str | None:
    """Why a directory entry is a stray temporary file, or None (not one, or in use)."""
    if not (name.startswith(".") and name.endswith(atomic.TEMP_SUFFIX)):
        return None
    info = atomic.temp_file_info(name)
    if info is None:
        return "temporary file of an interrupted save (no writer named: remove it by hand)"
    if not info.this_host:
        return f"temporary file of a save by process {info.pid} on another host"
    if atomic.pid_alive(info.pid):
        return None  # a save in progress
    return (f"temporary file of an interrupted save (process {info.pid} is gone; the next "
            "write to the store removes it)")
