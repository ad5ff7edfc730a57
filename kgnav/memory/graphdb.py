"""The memory in an embedded graph database: a LadybugDB file holding every model of a store.

One schema for every model (``docs/graphdb.md`` draws it): node tables ``Model`` (id, extractor,
feature dimension, the graph's attributes), ``State`` (pose, episode, step, features, range
profile) and ``Object`` (class, position, extent, evidence), and relationship tables
``Transition`` (State -> State: action, count), ``Sees`` (State -> Object: bbox, distance,
pixels, observed position, score), ``HasState`` (Model -> State) and ``HasObject`` (Model ->
Object). LadybugDB indexes a node table by its primary key only, so a model's own states are
reached through ``HasState`` from its ``Model`` node: read as ``WHERE s.model = $m``, every
read of one model would scan the whole ``State`` table, features included (100 times slower at
a million states). Every node and edge carries its model's id and its order in the model, so a
model read back is equal to the one saved (features bit for bit) and iterates in the same
order. A ``Meta`` node records the layout's version (:data:`DB_SCHEMA_VERSION`).

Values go through the same codecs as GraphML (:mod:`kgnav.memory.graphml.schema`): a value the
GraphML reader would refuse is refused here, and one it reads comes back as it would from a
file. Attributes outside the schema (added by another tool) are kept as JSON in ``extra``.
Features and range profiles are stored as raw little-endian bytes (``BLOB``): as a fixed-size
``FLOAT[512]`` array a save took 84 times longer (21 ms a state through the Python binding).

Saving a model is one transaction: a crash or ``kill -9`` mid-save leaves the previous version.
Writers (and readers, since an open database is exclusive to one process) take a lock file
beside the database, so processes sharing a store queue instead of failing.

>>> import tempfile, os, numpy as np
>>> from kgnav import AbstractModel, ModelStore
>>> store = ModelStore(os.path.join(tempfile.mkdtemp(), "memory.lbug"))
>>> m = AbstractModel(feature_dim=2, model_id="house-1")
>>> _ = m.add_state(np.ones(2), pose=(0, 0, 0))
>>> _ = store.save(m)
>>> store.ids(), store.load("house-1") == m
(['house-1'], True)
"""

from __future__ import annotations

import contextlib
import json
import os
from collections.abc import Callable, Iterator
from pathlib import Path
from types import SimpleNamespace

import numpy as np
from filelock import FileLock, Timeout

from kgnav.errors import ModelFileError, StoreError
from kgnav.memory.constants import SCHEMA_VERSION, SEES
from kgnav.memory.geometry import ScanGeometry
from kgnav.memory.graphml.schema import format_other, other_type, parse_other, schema
from kgnav.memory.model import AbstractModel
from kgnav.memory.store import (
    BACKENDS,
    FeatureBatch,
    ModelStore,
    StoreProblem,
    check_model_id,
)

#: Version of the database layout below; a database of another version is refused
#: (version 1, without ``HasState``/``HasObject``, is upgraded by :func:`upgrade`).
DB_SCHEMA_VERSION = 2
#: The earlier layout version :meth:`GraphDBStore.upgrade` brings to this one.
UPGRADES_FROM = 1
#: What a database of this layout says it is (the ``Meta`` node).
DB_KIND = "kgnav-memory"
#: Page cache of a read-only open (LadybugDB's default is most of the machine's memory).
READ_POOL_BYTES = 256 * 2**20

_ROWS = schema(SCHEMA_VERSION)
# element kind -> (column, type) of the attributes the schema names (features and ranges: BLOB)
_BLOB = {"features", "ranges"}
_TYPES = {"Double": "DOUBLE", "Long": "INT64", "Numbers": "DOUBLE[]"}


def _column_type(attr) -> str:
    if attr.name in _BLOB:
        return "BLOB"
    return _TYPES.get(type(attr.codec).__name__, "STRING")


def _columns(kind: str) -> list[tuple[str, str]]:
    return [(name, _column_type(a)) for name, a in _ROWS[kind].items()]


_NODE_TABLE = {"state": "State", "object": "Object"}
_HAS = {"State": "HasState", "Object": "HasObject"}  # Model -> its nodes (layout version 2)
_HAS_DDL = [f"CREATE REL TABLE {rel}(FROM Model TO {table})" for table, rel in _HAS.items()]
_DDL = [
    "CREATE NODE TABLE Meta(key STRING, kind STRING, version INT64, PRIMARY KEY(key))",
    "CREATE NODE TABLE Model(id STRING, extractor STRING, feature_dim INT64, graph STRING, "
    "PRIMARY KEY(id))",
    *(
        f"CREATE NODE TABLE {table}(key STRING, model STRING, id STRING, ord INT64, "
        + "".join(f"{c} {t}, " for c, t in _columns(kind))
        + "extra STRING, PRIMARY KEY(key))"
        for kind, table in _NODE_TABLE.items()
    ),
    "CREATE REL TABLE Transition(FROM State TO State, model STRING, ord INT64, action STRING, "
    + "".join(f"{c} {t}, " for c, t in _columns("transition")) + "extra STRING)",
    "CREATE REL TABLE Sees(FROM State TO Object, model STRING, ord INT64, "
    + "".join(f"{c} {t}, " for c, t in _columns("sees")) + "extra STRING)",
    *_HAS_DDL,
]


@BACKENDS.register("ladybug")
class GraphDBStore(ModelStore):
    """A :class:`~kgnav.memory.store.ModelStore` kept in one LadybugDB database file.

    Same interface and guarantees as the directory store: ``ids``, ``load``, ``load_all``,
    ``check``, ``save``, ``update``, ``delete``; a bad or foreign database is one
    :class:`~kgnav.errors.StoreError` line naming it, and nothing is changed.
    """

    def __init__(self, root: str | os.PathLike[str], *, lock_timeout: float = 60.0,
                 max_bytes: int | None = None):
        self.root = Path(root)
        if os.path.lexists(self.root):
            _check_file(self.root)  # a FIFO, a directory or a text file: refused before opening
        self.lock_timeout = lock_timeout
        self.max_bytes = max_bytes  # kept for the interface; a database holds no model files
        self._session = None  # the read-only connection of an open reading() block

    def __repr__(self) -> str:
        return f"ModelStore({str(self.root)!r})"

    # ------------------------------------------------------------------ the database
    def _lock(self) -> FileLock:
        self.root.parent.mkdir(parents=True, exist_ok=True)
        return FileLock(str(self.root) + ".kgnav-lock", timeout=self.lock_timeout)

    @contextlib.contextmanager
    def reading(self):
        """Keep the database open (read-only) across the calls made inside the block: each
        read otherwise opens and closes it, which costs more than a small question itself.
        Other processes wait for the block to end; a write inside it is refused.

        >>> with store.reading():                       # doctest: +SKIP
        ...     inventories = class_inventories(store)
        ...     chairs = find_objects(store, "chair")
        """
        if self._session is not None:
            yield self
            return
        with self._connect(write=False) as conn:
            self._session = conn if conn is not None else False
            try:
                yield self
            finally:
                self._session = None

    @contextlib.contextmanager
    def _connect(self, *, write: bool, layout: bool = True):
        """The database, open for this process alone while the lock is held (its layout version
        checked unless ``layout`` is false)."""
        if self._session is not None:
            if write:
                raise StoreError(f"{self.root}: cannot write inside a reading() block")
            yield self._session or None
            return
        try:
            lock = self._lock()
            lock.acquire()
        except Timeout:
            raise StoreError(f"{self.root}: another process held the database for "
                             f"{self.lock_timeout:g} s") from None
        except OSError as exc:
            raise StoreError(f"{self.root}: cannot lock ({exc.strerror or exc})") from None
        try:
            new = not self.root.exists()
            if new and not write:
                yield None
                return
            if not new:
                _check_file(self.root)
            db, conn = _open(self.root, read_only=not write)
            try:
                if new:
                    _create(conn)
                else:
                    _check_meta(conn, self.root, version=DB_SCHEMA_VERSION if layout else None)
                yield conn
            finally:
                conn.close()
                db.close()
        finally:
            lock.release()

    # ------------------------------------------------------------------ reading
    def path_of(self, model_id: str) -> Path:
        """The database file (every model lives in it); the id must be a plain name."""
        check_model_id(model_id)
        return self.root

    def ids(self) -> list[str]:
        with self._connect(write=False) as conn:
            if conn is None:
                return []
            return [r[0] for r in _rows(conn, "MATCH (m:Model) RETURN m.id ORDER BY m.id")]

    def load(self, model_id: str) -> AbstractModel:
        """Load one model; :class:`StoreError` if absent."""
        check_model_id(model_id)
        with self._connect(write=False) as conn:
            if conn is None:
                raise StoreError(f"{self.root}: no model {model_id!r}")
            return _read_model(conn, model_id, self.root)

    def each(self) -> Iterator[tuple[str, AbstractModel | None, StoreProblem | None]]:
        for model_id in self.ids():
            try:
                yield model_id, self.load(model_id), None
            except (ModelFileError, StoreError) as exc:
                yield model_id, None, StoreProblem(f"{self.root}#{model_id}", str(exc))

    def _listing(self) -> list[Path]:
        return []  # no files of its own beside the database: an unfinished save is rolled back

    def feature_batches(self, problems: list[StoreProblem] | None = None, *,
                        batch: int = 16384) -> Iterator[FeatureBatch]:
        """Every model's state features straight from the ``State`` table, ``batch`` states at a
        time, models in id order and states in their model's order: no model is loaded, so a
        relocator fits over a store larger than its models would be as Python objects. The
        database stays open (and locked) until the iteration ends. Features are checked as the
        model reader checks them (size, finite); a model with a bad one is appended to
        ``problems`` and skipped whole: if part of it was already sent, a batch with ``retract``
        set tells the caller to forget it."""
        with self._connect(write=False) as conn:
            if conn is None:
                return
            tops = dict(_rows(conn, "MATCH (m:Model)-[:HasState]->(s:State) "
                                    "RETURN m.id, max(s.ord)"))
            for mid, extractor, dim in _rows(
                    conn, "MATCH (m:Model) RETURN m.id, m.extractor, m.feature_dim ORDER BY m.id"):
                dim, sent = int(dim), False
                try:
                    for b in self._model_batches(conn, mid, extractor or "", dim, tops.get(mid),
                                                 batch):
                        sent = True
                        yield b
                except ModelFileError as exc:
                    if problems is not None:
                        problems.append(StoreProblem(f"{self.root}#{mid}", exc.reason))
                    if sent:  # found bad after some of it went out: take that back
                        yield FeatureBatch(mid, extractor or "", dim, [],
                                           np.zeros((0, dim), np.float32), retract=True)

    def _model_batches(self, conn, mid: str, extractor: str, dim: int, top, batch: int
                       ) -> Iterator[FeatureBatch]:
        if top is None:  # a model without states
            yield FeatureBatch(mid, extractor, dim, [], np.zeros((0, dim), np.float32))
            return
        # A filter on the states (`s.ord` in a range) makes LadybugDB plan a hash join built from
        # a scan of the whole State table, features included, which fills a reader's page cache
        # at a million states; so a model that fits one batch is read whole through HasState,
        # and a larger one as its keys in order, then a batch of primary-key lookups at a time.
        q = "MATCH (m:Model)-[:HasState]->(s:State) WHERE m.id = $m "
        if int(top) < batch:
            pages = [_rows(conn, q + "RETURN s.ord, s.id, s.features ORDER BY s.ord", {"m": mid})]
        else:
            keys = [k for k, in _rows(conn, q + "RETURN s.key ORDER BY s.ord", {"m": mid})]
            pages = (sorted(_rows(conn, "UNWIND $keys AS k MATCH (s:State) WHERE s.key = k "
                                        "RETURN s.ord, s.id, s.features",
                                  {"keys": keys[lo:lo + batch]}))
                     for lo in range(0, len(keys), batch))
        for page in pages:  # rows (ord, id, features) in the model's order
            rows = [r[1:] for r in page]
            if not rows:
                continue
            blobs = [r[1] for r in rows]
            if any(b is None or len(b) != 4 * dim for b in blobs):
                raise ModelFileError(f"{self.root}#{mid}", f"a state's features are not "
                                                           f"{dim} float32 values")
            feats = np.frombuffer(b"".join(blobs), "<f4").reshape(len(rows), dim)
            if not np.isfinite(feats.sum(dtype=np.float64)):
                raise ModelFileError(f"{self.root}#{mid}",
                                     "a state's features contain NaN or infinite values")
            yield FeatureBatch(mid, extractor, dim, [r[0] for r in rows],
                               feats.astype(np.float32, copy=False))

    def state_count(self) -> int:
        """States in the database, counted by the database."""
        with self._connect(write=False) as conn:
            return 0 if conn is None else int(_rows(conn, "MATCH (s:State) RETURN count(*)")[0][0])

    def revision(self) -> str:
        """The database's identity and write count (a ``Meta`` row every save, update and
        delete increments in its transaction): changes whenever a model does."""
        with self._connect(write=False) as conn:
            if conn is None:
                return "db:empty"
            found = _rows(conn, "MATCH (g:Meta) WHERE g.key = 'generation' "
                                "RETURN g.kind, g.version")
        return f"db:{found[0][0]}:{found[0][1]}" if found else "db:0"

    def index_path(self) -> Path:
        """Beside the database: ``memory.lbug.relocator.npz``."""
        return self.root.with_name(self.root.name + ".relocator.npz")

    def cypher(self, query: str, params: dict | None = None) -> tuple[list[str], list[list]]:
        """Run a read-only Cypher query: its column names and rows. The database is opened
        read-only, so a query that would write is refused by LadybugDB itself
        (:class:`StoreError`) and changes nothing."""
        with self._connect(write=False) as conn:
            if conn is None:
                raise StoreError(f"{self.root}: no such database")
            try:
                result = conn.execute(query, params or {})
                if isinstance(result, list):
                    raise StoreError("one query at a time")
                return result.get_column_names(), result.get_all()
            except RuntimeError as exc:
                msg = _first_line(exc)
                if "read-only" in msg.lower() or "read only" in msg.lower():
                    raise StoreError(f"a query that would write is refused ({msg})") from None
                raise StoreError(f"query failed: {msg}") from None

    # ------------------------------------------------------------------ writing
    def save(self, model: AbstractModel) -> Path:
        """Write ``model``, replacing its previous version, in one transaction."""
        check_model_id(model.model_id)
        rows = _model_rows(model)
        with self._connect(write=True) as conn:
            _transaction(conn, lambda: (_delete(conn, model.model_id),
                                        _insert(conn, rows), _bump(conn)))
        return self.root

    def update(self, model_id: str, fn: Callable[[AbstractModel | None], AbstractModel]
               ) -> AbstractModel:
        """Read-modify-write in one transaction under the lock: no concurrent update is lost."""
        check_model_id(model_id)
        with self._connect(write=True) as conn:
            current = (_read_model(conn, model_id, self.root)
                       if _has_model(conn, model_id) else None)
            new = fn(current)
            if new.model_id != model_id:
                raise StoreError(f"update of {model_id!r} returned model {new.model_id!r}")
            rows = _model_rows(new)
            _transaction(conn, lambda: (_delete(conn, model_id), _insert(conn, rows),
                                        _bump(conn)))
            return new

    def upgrade(self) -> int:
        """Bring a database of an earlier layout to this one, in one transaction (an error or a
        kill leaves it as it was); the version it had. Version 1 lacks the ``Model`` ->
        ``State``/``Object`` relationships, which are made from the nodes' ``model`` column.
        No model changes, so the store's revision stays and a relocator index saved beside it
        stays valid.

        >>> ModelStore("memory.lbug").upgrade()          # doctest: +SKIP
        1
        """
        if not self.root.exists():
            raise StoreError(f"{self.root}: no such database")
        with self._connect(write=True, layout=False) as conn:
            old = _rows(conn, "MATCH (m:Meta) WHERE m.key = 'kgnav' RETURN m.version")[0][0]
            if old == DB_SCHEMA_VERSION:
                return old
            if old != UPGRADES_FROM:
                raise StoreError(f"{self.root}: kgnav memory layout version {old}, this kgnav "
                                 f"upgrades version {UPGRADES_FROM} to {DB_SCHEMA_VERSION}")

            def body():
                for ddl, (table, rel) in zip(_HAS_DDL, _HAS.items(), strict=True):
                    conn.execute(ddl)
                    conn.execute(f"MATCH (m:Model), (n:{table}) WHERE n.model = m.id "
                                 f"CREATE (m)-[:{rel}]->(n)")
                _set_version(conn, DB_SCHEMA_VERSION)

            _transaction(conn, body)
            return old

    def delete(self, model_id: str) -> None:
        """Remove a model; :class:`StoreError` if it is not there."""
        check_model_id(model_id)
        with self._connect(write=True) as conn:
            if not _has_model(conn, model_id):
                raise StoreError(f"{self.root}: no model {model_id!r}")
            _transaction(conn, lambda: (_delete(conn, model_id), _bump(conn)))


# ---------------------------------------------------------------------------- helpers
def _first_line(exc: BaseException) -> str:
    return (str(exc).strip().splitlines() or [type(exc).__name__])[0]


def _open(path: Path, *, read_only: bool):
    """Database and connection. A writer killed mid-checkpoint leaves recovery pending, which
    only a read-write open completes: done here, under the store lock, before a read-only open."""
    import ladybug

    try:
        # a reader's page cache is capped: left at LadybugDB's default (most of the RAM) a scan
        # of every feature, as fitting a relocator does, would keep them all resident twice
        db = ladybug.Database(str(path), read_only=read_only,
                              buffer_pool_size=READ_POOL_BYTES if read_only else 0)
    except RuntimeError as exc:
        if not (read_only and "recovery is pending" in str(exc)):
            raise StoreError(f"{path}: not a LadybugDB database or damaged ({_first_line(exc)})"
                             ) from None
        _open(path, read_only=False)[0].close()
        return _open(path, read_only=True)
    return db, ladybug.Connection(db)


def _check_file(path: Path) -> None:
    """Refuse what is not a database before LadybugDB opens it (it would try to read a FIFO or
    a device, and may take any file for a damaged database)."""
    import stat

    try:
        st = os.stat(path)
    except OSError as exc:
        raise StoreError(f"{path}: cannot open ({exc.strerror or exc})") from None
    if stat.S_ISDIR(st.st_mode):
        raise StoreError(f"{path}: a directory, not a graph database")
    if not stat.S_ISREG(st.st_mode):
        raise StoreError(f"{path}: not a regular file, not a graph database")
    if st.st_size:
        with open(path, "rb") as fh:
            head = fh.read(64)
        if head.lstrip().startswith((b"<", b"{", b"[")) or head[:2] == b"\x1f\x8b":
            raise StoreError(f"{path}: not a LadybugDB database (a text or compressed file)")


def _rows(conn, query: str, params: dict | None = None) -> list[list]:
    return conn.execute(query, params or {}).get_all()


def _create(conn) -> None:
    for ddl in _DDL:
        conn.execute(ddl)
    conn.execute("CREATE (:Meta {key: 'kgnav', kind: $k, version: $v})",
                 {"k": DB_KIND, "v": DB_SCHEMA_VERSION})


def _set_version(conn, version: int) -> None:
    conn.execute("MATCH (m:Meta) WHERE m.key = 'kgnav' SET m.version = $v", {"v": version})


def _check_meta(conn, path: Path, *, version: int | None = DB_SCHEMA_VERSION) -> None:
    try:
        meta = _rows(conn, "MATCH (m:Meta) WHERE m.key = 'kgnav' RETURN m.kind, m.version")
    except RuntimeError:
        raise StoreError(f"{path}: a LadybugDB database, but not a kgnav memory") from None
    if not meta or meta[0][0] != DB_KIND:
        raise StoreError(f"{path}: a LadybugDB database, but not a kgnav memory")
    if version is not None and meta[0][1] != version:
        hint = (f"; `kgnav store upgrade {path}` upgrades it" if meta[0][1] == UPGRADES_FROM
                else "")
        raise StoreError(f"{path}: kgnav memory layout version {meta[0][1]}, this kgnav reads "
                         f"version {version}{hint}")


def _transaction(conn, body: Callable[[], object]) -> None:
    conn.execute("BEGIN TRANSACTION")
    try:
        body()
    except BaseException:
        conn.execute("ROLLBACK")
        raise
    conn.execute("COMMIT")


def _bump(conn) -> None:
    """Count a write (see :meth:`GraphDBStore.revision`); the first one names the database,
    so two databases with as many writes still differ."""
    import uuid

    conn.execute("MERGE (g:Meta {key: 'generation'}) ON CREATE SET g.kind = $u, g.version = 1 "
                 "ON MATCH SET g.version = g.version + 1", {"u": uuid.uuid4().hex})


def _has_model(conn, model_id: str) -> bool:
    return bool(_rows(conn, "MATCH (m:Model) WHERE m.id = $id RETURN m.id", {"id": model_id}))


def _delete(conn, model_id: str) -> None:
    for table, rel in _HAS.items():
        conn.execute(f"MATCH (m:Model)-[:{rel}]->(n:{table}) WHERE m.id = $m DETACH DELETE n",
                     {"m": model_id})
    conn.execute("MATCH (m:Model) WHERE m.id = $m DETACH DELETE m", {"m": model_id})


# ---------------------------------------------------------------------------- model -> rows
def _cell(name: str, attr, value):
    """A known attribute's value as its column holds it (checked by its GraphML codec)."""
    if name == "features":
        return np.ascontiguousarray(value, "<f4").tobytes()
    if name == "ranges":
        return np.ascontiguousarray(value, "<f2").tobytes()
    text = attr.codec.format(value)
    kind = type(attr.codec).__name__
    if kind == "Double":
        return float(text)
    if kind == "Long":
        return int(text)
    if kind == "Numbers":
        return [float(v) for v in text.split()]
    return text


def _extra(attrs: dict, known: dict) -> str | None:
    other = {k: v for k, v in attrs.items() if k not in known and k != "kind"}
    if not other:
        return None
    return json.dumps({k: [other_type(v), format_other(v, other_type(v))]
                       for k, v in other.items()})


def _element(attrs: dict, kind: str) -> dict:
    known = _ROWS[kind]
    row = {name: (_cell(name, a, attrs[name]) if attrs.get(name) is not None else None)
           for name, a in known.items()}
    row["extra"] = _extra(attrs, known)
    return row


def _model_rows(model: AbstractModel) -> dict:
    g = model.graph
    mid = model.model_id
    graph = {name: a.codec.format(g.graph[name]) for name, a in _ROWS["graph"].items()
             if g.graph.get(name) is not None}
    graph_extra = _extra(g.graph, _ROWS["graph"])
    nodes = {"state": [], "object": []}
    for i, (n, attrs) in enumerate(g.nodes(data=True)):
        kind = attrs["kind"]
        nodes[kind].append({"key": f"{mid}/{n}", "model": mid, "id": n, "ord": i,
                            **_element(attrs, kind)})
    edges = {"transition": [], "sees": []}
    for i, (u, v, k, attrs) in enumerate(g.edges(keys=True, data=True)):
        kind = "sees" if k == SEES else "transition"
        row = {"a": f"{mid}/{u}", "b": f"{mid}/{v}", "model": mid, "ord": i,
               **_element(attrs, kind)}
        if kind == "transition":
            row["action"] = k
        edges[kind].append(row)
    return {"model": {"id": mid, "extractor": g.graph.get("extractor", ""),
                      "feature_dim": int(g.graph["feature_dim"]),
                      "graph": json.dumps({"attrs": graph, "extra": graph_extra})},
            "nodes": nodes, "edges": edges}


def _insert(conn, rows: dict) -> None:
    conn.execute("CREATE (:Model {id: $id, extractor: $extractor, feature_dim: $feature_dim, "
                 "graph: $graph})", rows["model"])
    for kind, table in _NODE_TABLE.items():
        cols = ["key", "model", "id", "ord", *_ROWS[kind], "extra"]
        if rows["nodes"][kind]:
            sets = ", ".join(f"{c}: r.{c}" for c in cols)
            conn.execute(f"MATCH (m:Model) WHERE m.id = $id UNWIND $rows AS r "
                         f"CREATE (m)-[:{_HAS[table]}]->(:{table} {{{sets}}})",
                         {"id": rows["model"]["id"], "rows": rows["nodes"][kind]})
    for kind, table, src, dst in (("transition", "Transition", "State", "State"),
                                  ("sees", "Sees", "State", "Object")):
        cols = ["model", "ord", *(["action"] if kind == "transition" else []), *_ROWS[kind],
                "extra"]
        if rows["edges"][kind]:
            sets = ", ".join(f"{c}: r.{c}" for c in cols)
            # two MATCH ... WHERE clauses, not MATCH (a {key: r.a}), (b {key: r.b}): only this
            # form is planned as primary-key lookups (0.09 s for 4 000 edges among 50 000 nodes,
            # against 44 s for a join over the whole node table)
            conn.execute(f"UNWIND $rows AS r MATCH (a:{src}) WHERE a.key = r.a "
                         f"MATCH (b:{dst}) WHERE b.key = r.b "
                         f"CREATE (a)-[:{table} {{{sets}}}]->(b)", {"rows": rows["edges"][kind]})


# ---------------------------------------------------------------------------- rows -> model
def _value(name: str, attr, cell, ctx):
    """A column's cell as the GraphML reader returns the attribute (same codec, same type)."""
    if name == "features":
        text = attr.codec.format(np.frombuffer(cell, "<f4"))
    elif name == "ranges":
        text = attr.codec.format(np.frombuffer(cell, "<f2"))
    elif type(attr.codec).__name__ == "Numbers":
        text = " ".join(repr(float(v)) for v in cell)
    elif type(attr.codec).__name__ == "Double":
        text = repr(float(cell))
    else:
        text = str(cell)
    return attr.codec.parse(text, ctx)


def _attrs(names: list[str], cells: list, kind: str, ctx, where: str) -> dict:
    known = _ROWS[kind]
    out = {}
    for name, cell in zip(names, cells, strict=True):
        if name == "extra":
            if cell:
                for k, (gtype, text) in json.loads(cell).items():
                    out[k] = parse_other(gtype, text)
        elif cell is not None:
            try:
                out[name] = _value(name, known[name], cell, ctx)
            except ValueError as exc:
                raise ModelFileError(where, f"{kind} attribute {name!r}: {exc}") from None
    return out


def _read_model(conn, model_id: str, path: Path) -> AbstractModel:
    import networkx as nx

    found = _rows(conn, "MATCH (m:Model) WHERE m.id = $id RETURN m.graph", {"id": model_id})
    if not found:
        raise StoreError(f"{path}: no model {model_id!r}")
    where = f"{path}#{model_id}"
    stored = json.loads(found[0][0])
    g = nx.MultiDiGraph()
    for name, text in stored["attrs"].items():
        g.graph[name] = _ROWS["graph"][name].codec.parse(text, None)
    if stored["extra"]:
        for k, (gtype, text) in json.loads(stored["extra"]).items():
            g.graph[k] = parse_other(gtype, text)
    scan = g.graph.get("scan") or ""
    ctx = SimpleNamespace(dim=int(g.graph["feature_dim"]),
                          bins=ScanGeometry.from_json(scan).bins if scan else None)
    nodes = []
    for kind, table in _NODE_TABLE.items():
        cols = [*_ROWS[kind], "extra"]
        ret = ", ".join(f"n.{c}" for c in ("id", "ord", *cols))
        for r in _rows(conn, f"MATCH (m:Model)-[:{_HAS[table]}]->(n:{table}) "
                             f"WHERE m.id = $m RETURN {ret}", {"m": model_id}):
            nodes.append((r[1], r[0], {"kind": kind, **_attrs(cols, r[2:], kind, ctx, where)}))
    for _, n, attrs in sorted(nodes, key=lambda t: t[0]):
        g.add_node(n, **attrs)
    edges = []
    for kind, table, dst in (("transition", "Transition", "State"), ("sees", "Sees", "Object")):
        cols = [*_ROWS[kind], "extra"]
        extra_ret = ", e.action" if kind == "transition" else ""
        ret = ", ".join(f"e.{c}" for c in cols)
        for r in _rows(conn, f"MATCH (m:Model)-[:HasState]->(a:State)-[e:{table}]->(b:{dst}) "
                             f"WHERE m.id = $m RETURN a.id, b.id, e.ord{extra_ret}, {ret}",
                       {"m": model_id}):
            key, cells = (r[3], r[4:]) if kind == "transition" else (SEES, r[3:])
            edges.append((r[2], r[0], r[1], key,
                          {"kind": kind, **_attrs(cols, cells, kind, ctx, where)}))
    for _, u, v, key, attrs in sorted(edges, key=lambda t: t[0]):
        g.add_edge(u, v, key=key, **attrs)
    return AbstractModel.from_graph(g)
