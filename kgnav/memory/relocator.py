"""Recognise a known environment: nearest stored state by cosine distance of state features.

The paper's best match ``s* = argmin cos_dist(F_s, F_s(i))`` over the states of every stored model,
accepted when the distance is below a threshold (0.3). :class:`Relocator` follows scikit-learn's
estimator conventions: parameters in ``__init__``, ``fit`` returns ``self``, fitted attributes end
in ``_``. The search itself is a pluggable backend (``backend=`` one of :data:`BACKENDS`):

* ``"exact"`` (default): one matrix-vector product over all unit-norm features;
* ``"hnsw"``: faiss HNSW graph over PCA-reduced features, candidates re-ranked exactly with the
  full vectors, for stores of 1e5 states and more (``pip install kgnav[ann]``).

>>> import numpy as np
>>> from kgnav import AbstractModel
>>> m = AbstractModel(feature_dim=3, model_id="kitchen")
>>> s = m.add_state(np.array([1.0, 0.0, 0.0]), pose=(0, 0, 0))
>>> r = Relocator(threshold=0.3).fit([m])
>>> r.match(np.array([0.9, 0.1, 0.0]))
Match(model_id='kitchen', state_id='s0', distance=0.006...)
>>> r.match(np.array([0.0, 1.0, 0.0])) is None
True
"""

from __future__ import annotations

import json
import os
import warnings
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO, NamedTuple

import numpy as np

from kgnav.errors import FeatureDimError, KgnavError
from kgnav.memory.index_file import Blob, IndexReader, write_index
from kgnav.memory.model import AbstractModel
from kgnav.memory.vector_table import VectorTable, unit_rows


class Match(NamedTuple):
    """A stored state matched by the relocator."""

    model_id: str
    state_id: str
    distance: float


BACKENDS: dict[str, Callable[..., SearchBackend]] = {}


def register_backend(name: str):
    """Class decorator adding a search backend under ``name`` (habitat-style registry)."""

    def deco(cls):
        BACKENDS[name] = cls
        return cls

    return deco


class SearchBackend:
    """Proposes candidate rows for a query; the relocator re-ranks them exactly."""

    #: Whether every query reads every row: such a backend fits with its rows in memory,
    #: where one that re-ranks a few rows a query can leave them on disk.
    scans_all = False

    def rebuild(self, table: VectorTable) -> None:  # pragma: no cover - interface
        """All rows changed (fit or compaction)."""

    def state(self) -> dict[str, np.ndarray | Blob]:
        """What :meth:`restore` needs to skip a rebuild, saved with the index: arrays, or
        :class:`~kgnav.memory.index_file.Blob` members the backend streams itself."""
        return {}

    def restore(self, table: VectorTable, state: dict[str, np.ndarray | BinaryIO]) -> None:
        """Take back :meth:`state` for ``table`` (a blob comes back as a binary stream);
        rebuild when it is missing or unusable."""
        self.rebuild(table)

    def added(self, table: VectorTable, start: int) -> None:  # pragma: no cover - interface
        """Rows ``start:table.n`` were appended."""

    def candidates(self, table: VectorTable, q: np.ndarray, k: int) -> np.ndarray:
        raise NotImplementedError


@register_backend("exact")
class ExactBackend(SearchBackend):
    """Brute force over every alive row: exact, O(n·d) per query."""

    scans_all = True

    def candidates(self, table: VectorTable, q: np.ndarray, k: int) -> np.ndarray:
        sims = table.vectors @ q
        sims[~table.alive] = -np.inf
        k = min(k, table.n)
        return np.argpartition(-sims, k - 1)[:k] if k < table.n else np.arange(table.n)


@register_backend("hnsw")
class HNSWBackend(SearchBackend):
    """faiss HNSW over a PCA projection of the features, exact re-rank of the candidates.

    Below ``min_rows`` rows it searches exactly: a graph index only pays off on large tables.

    Parameters
    ----------
    pca_dim:
        Dimension the features are projected to before indexing (no projection if ≥ the
        feature dimension).
    M, ef_construction, ef_search:
        HNSW graph degree and search breadths (faiss's parameters). Clustered features (many
        views of a few environments) need a well-connected graph: M=32, efConstruction=80
        lost 2% recall@1 at 2e5 states where these defaults lose none
        (``bench/bench_relocator.py``).
    train_size:
        At most this many rows train the projection (scikit-learn's randomized PCA); it is
        retrained, and the graph rebuilt, each time the table has doubled since the last
        training, so it follows new environments.
    min_rows:
        Tables smaller than this are searched exactly.
    """

    def __init__(
        self,
        pca_dim: int = 128,
        M: int = 48,
        ef_construction: int = 120,
        ef_search: int = 96,
        train_size: int = 10000,
        min_rows: int = 5000,
        seed: int = 0,
    ):
        try:
            import faiss
        except ImportError:  # pragma: no cover - depends on the environment
            raise KgnavError(
                "the 'hnsw' relocator backend needs faiss: pip install 'kgnav[ann]'"
            ) from None
        self._faiss = faiss
        self.pca_dim, self.M = pca_dim, M
        self.ef_construction, self.ef_search = ef_construction, ef_search
        self.train_size, self.min_rows, self.seed = train_size, min_rows, seed
        self._pca = None
        self._index = None
        self._trained_at = 0

    def _project(self, x: np.ndarray) -> np.ndarray:
        if self._pca is None:
            return np.ascontiguousarray(x, dtype=np.float32)
        mean, components = self._pca
        return np.ascontiguousarray((x - mean) @ components.T, dtype=np.float32)

    def rebuild(self, table: VectorTable) -> None:
        self._index, self._pca = None, None
        self._trained_at = table.n
        if table.n < self.min_rows:
            return
        from sklearn.decomposition import PCA  # only large tables pay for the import
        if self.pca_dim < table.dim:
            rng = np.random.default_rng(self.seed)
            take = np.sort(rng.choice(table.n, min(table.n, self.train_size), replace=False))
            pca = PCA(self.pca_dim, svd_solver="randomized", random_state=self.seed).fit(
                table.take(take))
            self._pca = (pca.mean_.astype(np.float32), pca.components_.astype(np.float32))
        dim = self.pca_dim if self._pca is not None else table.dim
        index = self._faiss.IndexHNSWFlat(dim, self.M)
        index.hnsw.efConstruction = self.ef_construction
        # faiss grows its arrays batch by batch (a std::vector doubling: up to 2x the graph,
        # 3x while it copies); sized once here, a resize back to 0 keeps the capacity
        codes = self._faiss.downcast_index(index.storage).codes
        links = index.hnsw.neighbors
        codes.resize(table.n * dim * 4)
        codes.resize(0)
        links.resize(table.n * (2 * self.M + 2))  # level 0's 2M links, ~M/(M-1) above
        links.resize(0)
        for _, rows in table.chunks():  # read in chunks: bounded temporaries, rows on disk
            index.add(self._project(rows))
        self._index = index

    def state(self) -> dict[str, np.ndarray | Blob]:
        out = {"trained_at": np.array(self._trained_at, dtype=np.int64)}
        if self._pca is not None:
            out["pca_mean"], out["pca_components"] = self._pca
        if self._index is not None:
            # streamed into the file: serialize_index would hold two more copies of the graph
            index, faiss = self._index, self._faiss
            out["graph"] = Blob(lambda fh: faiss.write_index(
                index, faiss.PyCallbackIOWriter(fh.write)))
        return out

    def restore(self, table: VectorTable, state: dict[str, np.ndarray | BinaryIO]) -> None:
        try:
            pca = None
            if "pca_mean" in state:
                mean = np.asarray(state["pca_mean"], np.float32)
                comp = np.asarray(state["pca_components"], np.float32)
                if mean.shape != (table.dim,) or comp.shape != (self.pca_dim, table.dim):
                    raise ValueError("projection of another shape")
                pca = (mean, comp)
            index = None
            graph = state.get("graph")
            if isinstance(graph, np.ndarray):  # an index file of version 1
                index = self._faiss.deserialize_index(np.asarray(graph, np.uint8))
            elif graph is not None:
                index = self._faiss.read_index(self._faiss.PyCallbackIOReader(graph.read))
            if graph is not None:
                want = self.pca_dim if pca is not None else table.dim
                if index.ntotal != table.n or index.d != want:
                    raise ValueError("graph of another size")
            elif table.n >= self.min_rows:
                raise ValueError("no graph")
        except (ValueError, RuntimeError, KeyError, OSError, zipfile.BadZipFile):
            self.rebuild(table)  # a stale or damaged graph costs a rebuild, not a wrong answer
            return
        self._pca, self._index = pca, index
        self._trained_at = int(state.get("trained_at", table.n))

    def added(self, table: VectorTable, start: int) -> None:
        if self._index is None or table.n >= 2 * max(self._trained_at, 1):
            self.rebuild(table)
        else:
            self._index.add(self._project(table.rows(start, table.n)))

    def candidates(self, table: VectorTable, q: np.ndarray, k: int) -> np.ndarray:
        if self._index is None:
            return ExactBackend().candidates(table, q, k)
        self._index.hnsw.efSearch = max(self.ef_search, k)
        _, idx = self._index.search(self._project(q[None, :]), k)
        return idx[0][idx[0] >= 0]


class Relocator:
    """Nearest-neighbour relocation over the states of many Abstract Models.

    Parameters
    ----------
    threshold:
        A best match is accepted when its cosine distance is below this (0.3 in the paper).
    backend:
        Name in :data:`BACKENDS` (``"exact"``, ``"hnsw"``).
    n_candidates:
        How many candidates the backend proposes for exact re-ranking.
    backend_params:
        Keyword arguments for the backend.

    Attributes
    ----------
    feature_dim_, extractor_:
        Feature dimension and extractor of the indexed models (set by the first model).
    model_ids_:
        Ids of the indexed models.
    n_states_:
        Number of indexed (alive) states.
    problems_:
        Store files skipped by the last :meth:`fit` on a :class:`~kgnav.memory.store.ModelStore`.
    """

    def __init__(
        self,
        threshold: float = 0.3,
        backend: str = "exact",
        n_candidates: int = 32,
        backend_params: dict | None = None,
    ):
        if backend not in BACKENDS:
            raise ValueError(f"unknown relocator backend {backend!r} (have: {', '.join(BACKENDS)})")
        if not 0.0 <= threshold <= 2.0:
            raise ValueError(f"threshold is a cosine distance in [0, 2], got {threshold}")
        self.threshold = threshold
        self.backend = backend
        self.n_candidates = n_candidates
        self.backend_params = backend_params
        self._reset()

    def _reset(self) -> None:
        self.feature_dim_: int | None = None
        self.extractor_: str | None = None
        self.problems_: list = []
        self.store_revision_: str | None = None
        self._table: VectorTable | None = None
        self._owners: list[tuple[str, str]] = []
        self._rows: dict[str, np.ndarray] = {}
        self._dead = 0
        self._spill = None
        self._backend = BACKENDS[self.backend](**(self.backend_params or {}))

    @property
    def model_ids_(self) -> list[str]:
        return list(self._rows)

    @property
    def n_states_(self) -> int:
        return 0 if self._table is None else self._table.n - self._dead

    def fit(self, models, *, progress: Callable[[int], None] | None = None,
            spill: str | os.PathLike[str] | None = None) -> Relocator:
        """Index every state of ``models``: a :class:`ModelStore` or an iterable of models.

        A store is read as a stream of feature batches (:meth:`ModelStore.feature_batches`):
        no model is held, and a graph-database store is never loaded as models at all, so
        fitting needs little more than the features' own bytes, or, with ``spill`` (a
        directory), only the search graph's: the feature rows wait in a temporary file there
        (:class:`~kgnav.memory.vector_table.VectorTable`), which suits a backend that reads a
        few rows a query (``hnsw``). ``progress`` is called with the number of states added by
        each batch.
        """
        from kgnav.memory.store import ModelStore

        self._reset()
        self._spill = spill
        if isinstance(models, ModelStore):
            with models.reading():  # one open of a database for all three
                self.store_revision_ = models.revision()
                n = models.state_count()
                for b in models.feature_batches(self.problems_):
                    if b.retract:
                        self.remove(b.model_id)
                        continue
                    if self._table is None and n is not None:
                        self._table = VectorTable(b.feature_dim, capacity=n, spill=spill)
                    self._extend(b.model_id, b.extractor, b.feature_dim, b.state_ids,
                                 b.features)
                    if progress is not None:
                        progress(len(b.state_ids))
            if self._dead:
                self._compact()
        else:
            for m in models:
                self._append(m)
        if self._table is not None:
            self._backend.rebuild(self._table)
        return self

    def add(self, model: AbstractModel) -> Relocator:
        """Index ``model``'s states, replacing those of an indexed model with the same id."""
        start = self._append(model)
        if start is not None:
            if self._dead > 0.25 * self._table.n:
                self._compact()
            else:
                self._backend.added(self._table, start)
        return self

    def remove(self, model_id: str) -> Relocator:
        """Forget a model's states (no-op if it is not indexed)."""
        rows = self._rows.pop(model_id, None)
        if rows is not None and len(rows):
            self._table.alive[rows] = False
            self._dead += len(rows)
        return self

    def _append(self, model: AbstractModel) -> int | None:
        self.remove(model.model_id)
        ids, feats = model.state_features()
        return self._extend(model.model_id, model.extractor, model.feature_dim, ids, feats)

    def _extend(self, model_id: str, extractor: str, dim: int, ids: list[str],
                feats: np.ndarray) -> int | None:
        """Append states of ``model_id`` after those already indexed for it (its rows stay
        contiguous: a store streams a model in consecutive batches)."""
        if self.feature_dim_ is None:
            self.feature_dim_, self.extractor_ = dim, extractor
            if self._table is None or self._table.dim != dim:
                self._table = VectorTable(dim, spill=self._spill)
        if dim != self.feature_dim_:
            raise FeatureDimError((dim,), self.feature_dim_)
        if extractor != self.extractor_:
            raise KgnavError(
                f"model {model_id!r} has features from {extractor!r}, "
                f"the relocator indexes {self.extractor_!r}"
            )
        start = self._table.append(unit_rows(feats)) if ids else self._table.n
        self._owners.extend((model_id, s) for s in ids)
        before = self._rows.get(model_id)
        first = before[0] if before is not None and len(before) else start
        self._rows[model_id] = np.arange(first, start + len(ids))
        return start if ids else None

    def _compact(self) -> None:
        keep = np.flatnonzero(self._table.alive)
        table = self._table.compacted(keep)
        remap = np.full(self._table.n, -1)
        remap[keep] = np.arange(len(keep))
        self._owners = [self._owners[i] for i in keep]
        self._rows = {m: remap[r] for m, r in self._rows.items()}
        self._table, self._dead = table, 0
        self._backend.rebuild(table)

    def _query(self, features) -> np.ndarray | None:
        if self.feature_dim_ is None:
            return None
        q = np.asarray(features, dtype=np.float32)
        if q.ndim != 1 or q.shape[0] != self.feature_dim_:
            raise FeatureDimError(tuple(q.shape), self.feature_dim_)
        norm = float(np.linalg.norm(q))
        return q / norm if norm > 0 and np.isfinite(norm) else None

    def nearest(self, features, k: int = 1) -> list[Match]:
        """The ``k`` closest stored states, best first, whatever their distance."""
        q = self._query(features)
        if q is None or self.n_states_ == 0:
            return []
        table = self._table
        cand = self._backend.candidates(table, q, max(k, self.n_candidates))
        cand = cand[table.alive[cand]]
        if len(cand) < k:  # the approximate index ran into replaced rows: fall back to exact
            cand = ExactBackend().candidates(table, q, max(k, self.n_candidates))
            cand = cand[table.alive[cand]]
        sims = table.take(cand) @ q
        order = np.argsort(-sims, kind="stable")[:k]
        return [
            Match(*self._owners[cand[i]], float(max(0.0, 1.0 - sims[i]))) for i in order
        ]

    def match(self, features) -> Match | None:
        """The best stored state if its cosine distance is below ``threshold``, else ``None``."""
        best = self.nearest(features, 1)
        return best[0] if best and best[0].distance < self.threshold else None

    # ------------------------------------------------------------------ persistence
    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the fitted index to one file (atomically, :mod:`kgnav.memory.index_file`): the
        unit features, which model and state each row is, the search backend's graph and the
        store revision it was fitted from. :meth:`load` reopens it without the store;
        :meth:`open` does both."""
        if self._dead:
            self._compact()
        model_ids = list(self._rows)
        number = {m: i for i, m in enumerate(model_ids)}
        n = self.n_states_
        meta = {"format": INDEX_FORMAT, "version": INDEX_VERSION, "backend": self.backend,
                "backend_params": self.backend_params, "threshold": self.threshold,
                "n_candidates": self.n_candidates, "feature_dim": self.feature_dim_,
                "extractor": self.extractor_, "store_revision": self.store_revision_}
        arrays = {
            "meta": np.frombuffer(json.dumps(meta).encode(), np.uint8),
            "vectors": (Blob(self._table.write_npy) if self._table is not None
                        else np.zeros((0, self.feature_dim_ or 0), np.float32)),
            "model_ids": np.array(model_ids, dtype=str),
            "owner_model": np.fromiter((number[m] for m, _ in self._owners), np.int32, n),
            "state_ids": np.array([s for _, s in self._owners], dtype=str),
        }
        blobs = {}
        for k, v in self._backend.state().items():
            (blobs if isinstance(v, Blob) else arrays)[f"backend.{k}"] = v
        return write_index(path, arrays, blobs)

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> Relocator:
        """Reopen an index written by :meth:`save`. With a backend that re-ranks a few rows a
        query (``hnsw``) the feature rows stay in the file (a query reads the rows it
        re-ranks) and only the search graph is read into memory; the exact backend, which
        reads every row each query, reads them into memory. A file that is not an index, or
        is damaged, is a :class:`~kgnav.errors.KgnavError` naming it."""
        path = Path(path)
        try:
            with IndexReader(path) as z:
                meta = json.loads(bytes(z.array("meta")).decode())
                if not isinstance(meta, dict) or meta.get("format") != INDEX_FORMAT:
                    raise ValueError("not a kgnav relocator index")
                if meta.get("version") not in INDEX_VERSIONS_READ:
                    raise ValueError(f"index version {meta.get('version')}, this kgnav reads "
                                     f"versions {', '.join(map(str, INDEX_VERSIONS_READ))}")
                r = cls(threshold=meta["threshold"], backend=meta["backend"],
                        n_candidates=meta["n_candidates"], backend_params=meta["backend_params"])
                # a backend that reads every row each query keeps them in memory; one that
                # re-ranks a few leaves them in the file
                vectors = _rows_of(z, in_file=not BACKENDS[r.backend].scans_all)
                owner = z.array("owner_model")
                model_ids, state_ids = z.array("model_ids").tolist(), z.array("state_ids").tolist()
                state = {k[len("backend."):]: z.array(k) for k in z.arrays
                         if k.startswith("backend.")}
                state.update({k[len("backend."):]: z.blob(k) for k in z.blobs
                              if k.startswith("backend.")})
                if r._fill(meta, vectors, owner, model_ids, state_ids):
                    r._backend.restore(r._table, state)  # inside: blobs are open streams
        except FileNotFoundError:
            raise KgnavError(f"{path}: no such relocator index") from None
        except (OSError, ValueError, KeyError, TypeError, EOFError, zipfile.BadZipFile,
                UnicodeDecodeError) as exc:
            raise KgnavError(f"{path}: not a usable relocator index ({exc})") from None
        return r

    def _fill(self, meta: dict, vectors: VectorTable, owner: np.ndarray, model_ids: list[str],
              state_ids: list[str]) -> bool:
        """Take the rows of a loaded index; False when it holds no features at all."""
        n, dim = len(state_ids), meta["feature_dim"]
        if (vectors is None or vectors.n != n or (dim is not None and vectors.dim != dim)
                or owner.shape != (n,)
                or (n and not 0 <= int(owner.min()) <= int(owner.max()) < len(model_ids))):
            raise ValueError("inconsistent arrays")
        self.feature_dim_, self.extractor_ = dim, meta["extractor"]
        self.store_revision_ = meta["store_revision"]
        if dim is None:
            return False
        self._table = vectors
        self._owners = [(model_ids[i], s) for i, s in zip(owner.tolist(), state_ids,
                                                          strict=True)]
        order = np.argsort(owner, kind="stable")
        bounds = np.cumsum(np.bincount(owner, minlength=len(model_ids)))
        self._rows = {m: order[(bounds[i - 1] if i else 0):bounds[i]]
                      for i, m in enumerate(model_ids)}
        return True

    @classmethod
    def open(cls, store, *, path: str | os.PathLike[str] | None = None, rebuild: bool = False,
             progress: Callable[[int], None] | None = None, **params) -> Relocator:
        """A relocator over ``store``: the index saved beside it (``store.index_path()``, or
        ``path``) when that was fitted from the store as it is now and with the same search
        backend, else one fitted from the store (streamed, see :meth:`fit`) and saved there
        for next time. ``params`` are :class:`Relocator`'s; ``threshold`` and
        ``n_candidates`` apply to a reopened index too.

        A damaged index is refitted, not trusted; an index that cannot be written is a warning
        (the fitted relocator is still returned).
        """
        want = cls(**params)
        path = Path(path) if path is not None else store.index_path()
        if not rebuild and os.path.isfile(path):
            try:
                have = cls.load(path)
            except KgnavError:
                have = None
            if (have is not None and have.store_revision_ == store.revision()
                    and have.backend == want.backend
                    and have.backend_params == want.backend_params):
                have.threshold, have.n_candidates = want.threshold, want.n_candidates
                return have
        # a backend that re-ranks a few rows a query fits with its rows on disk beside the index
        spill = (path.parent if not BACKENDS[want.backend].scans_all
                 and os.access(path.parent, os.W_OK | os.X_OK) else None)
        want.fit(store, progress=progress, spill=spill)
        try:
            want.save(path)
        except OSError as exc:
            warnings.warn(f"{path}: relocator index not saved ({exc.strerror or exc})",
                          stacklevel=2)
        return want


def _rows_of(z: IndexReader, in_file: bool = True) -> VectorTable | None:
    """The feature rows of an index file: left in the file when they lie there as plain
    float32 rows (and ``in_file``), else read; None when they are not a 2-D float32 array."""
    where = z.locate("vectors") if in_file else None
    if where is not None:
        offset, shape, dtype, fortran = where
        if dtype != np.float32 or len(shape) != 2:
            return None
        if not fortran or shape[0] <= 1 or shape[1] <= 1:
            return VectorTable.in_file(z.path, offset, shape[0], shape[1])
    rows = z.array("vectors")
    if rows.dtype != np.float32 or rows.ndim != 2:
        return None
    return VectorTable.wrap(np.ascontiguousarray(rows))


#: What a saved relocator index says it is, and the layout version this code reads.
INDEX_FORMAT = "kgnav-relocator"
INDEX_VERSION = 2
#: Version 1 held the HNSW graph as one array (a copy of the graph in memory to write or read).
INDEX_VERSIONS_READ = (1, 2)

