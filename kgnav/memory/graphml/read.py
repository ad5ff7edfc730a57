"""Reading Abstract Model files: one pass that checks every value, whatever the file holds.

:func:`read_graph` opens only a regular file within the size limit, refuses compressed data, and
hands the file to one of two tokenizers, which both feed a :class:`_Builder`:

* :func:`_read_canonical` (:class:`_Canonical`) reads the layout kgnav writes — the header, one
  key, node or edge per line — in about 0.3 of the time of building XML elements: the header
  line by line, the nodes and edges a block at a time with one regular expression
  (:class:`_Bulk`) whose values are checked a column at a time, and any block with a line
  outside that layout line by line (every byte checked to be one XML reads the same way: no
  markup, entity or CDATA inside a value, no control character, valid UTF-8). At the first
  doubt, or at any error, it gives up and
* :class:`_XmlReader` reads the file as any GraphML, with lxml's pull parser (elements freed as
  they are handled, so memory holds the model, not the document; when the graph's attributes
  come after the nodes, as networkx writes them, the nodes' and edges' text waits for them in
  memory, about 2.5x the file at the peak). It refuses what it cannot
  read faithfully: a DTD (hence entities), XInclude, markup inside a value, nested graphs,
  hyperedges and ports, ``<default>`` values, undirected graphs. Its errors are the ones
  reported.

The builder checks every value against the schema rows of the file's version
(:mod:`kgnav.memory.graphml.schema`), each node against the graph's attributes
(:func:`_check_node`), edges against their ends, and the whole model against its invariants
(:func:`_check_model`). Every problem becomes a :class:`~kgnav.errors.ModelFileError` naming the
file, the element with its line, and the reason; no other exception escapes :func:`read_graph`.
"""

from __future__ import annotations

import contextlib
import errno
import gc
import json
import os
import re
import stat
from dataclasses import dataclass

import networkx as nx
import numpy as np
from lxml import etree

from kgnav.errors import KgnavError, ModelFileError, SchemaVersionError
from kgnav.memory.constants import ACTIONS, SEES
from kgnav.memory.geometry import ScanGeometry
from kgnav.memory.graphml.schema import (
    COMPATIBLE,
    DOMAIN,
    GRAPHML_TYPES,
    KNOWN,
    NODE_ID,
    READABLE_VERSIONS,
    Double,
    Features,
    Long,
    Numbers,
    Ranges,
    decode_features,
    decode_ranges,
    parse_other,
    schema,
    show,
    upgrade,
)

NS = "http://graphml.graphdrawing.org/xmlns"

#: Largest file :func:`read_graph` reads unless told otherwise (``max_bytes=`` or the
#: ``KGNAV_MAX_MODEL_BYTES`` environment variable, e.g. ``4G``).
MAX_BYTES = 1 << 30
MAX_BYTES_ENV = "KGNAV_MAX_MODEL_BYTES"
CHUNK = 1 << 20

_MAGIC = {
    b"\x1f\x8b": "gzip",
    b"\xfd7zXZ\x00": "xz",
    b"BZh": "bzip2",
    b"\x28\xb5\x2f\xfd": "zstd",
    b"PK\x03\x04": "zip",
}


def max_bytes_default() -> int:
    """The size limit: ``KGNAV_MAX_MODEL_BYTES`` (bytes, or with a K/M/G suffix) or 1 GiB."""
    text = os.environ.get(MAX_BYTES_ENV, "").strip()
    if not text:
        return MAX_BYTES
    m = re.fullmatch(r"([0-9]+(?:\.[0-9]*)?)\s*([KMGT]?)i?B?", text, re.IGNORECASE)
    if m is None:
        raise KgnavError(f"{MAX_BYTES_ENV}={text!r} is not a size (e.g. 2000000000, 500M, 4G)")
    return int(float(m[1]) * 1024 ** " KMGT".index(m[2].upper() or " "))


def read_graph(path: str | os.PathLike[str], *, max_bytes: int | None = None) -> nx.MultiDiGraph:
    """The graph of a model saved by :func:`kgnav.memory.graphml.write_model`, every value checked
    and upgraded to the current schema (:meth:`kgnav.AbstractModel.load` wraps it).

    Raises :class:`~kgnav.errors.ModelFileError` (missing, unreadable, not a regular file, larger
    than ``max_bytes`` — default :func:`max_bytes_default` —, compressed, not GraphML, not a
    kgnav model, malformed) or :class:`~kgnav.errors.SchemaVersionError`, naming the file, the
    element and the reason; no other exception escapes for any file content.
    """
    path = os.fspath(path)
    limit = max_bytes_default() if max_bytes is None else int(max_bytes)
    try:
        with paused_gc():
            with contextlib.suppress(Exception):  # any doubt: the general reader decides
                return _read_canonical(path, limit)
            return _XmlReader(path, limit).read()
    except KgnavError:
        raise
    except MemoryError:
        raise ModelFileError(path, "not enough memory to read it") from None
    except RecursionError:
        raise ModelFileError(path, "nested too deeply") from None
    except OSError as exc:
        raise ModelFileError(path, f"cannot read ({exc.strerror or exc})") from None
    except Exception as exc:  # a bug: still one line, naming the file
        raise ModelFileError(
            path, f"internal error while reading ({type(exc).__name__}: {exc}); please report it"
        ) from exc


@contextlib.contextmanager
def paused_gc():
    """Pause the cyclic garbage collector: a load creates ~1e5 dicts and tuples, none in a
    cycle, and the collector's passes over them cost a tenth of the time."""
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was_enabled:
            gc.enable()


# ---------------------------------------------------------------------------------------- files


def describe_mode(st_mode: int) -> str:
    """What a file of this mode is, in words: 'a directory', 'a FIFO (named pipe)'..."""
    for test, what in (
        (stat.S_ISDIR, "a directory"),
        (stat.S_ISFIFO, "a FIFO (named pipe)"),
        (stat.S_ISSOCK, "a socket"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
    ):
        if test(st_mode):
            return what
    return "not a regular file"


def _size(n: int) -> str:
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= scale:
            return f"{n / scale:.1f} {unit}"
    return f"{n} bytes"


def _too_big(size: int, limit: int) -> str:
    return (
        f"{_size(size)}, over the {_size(limit)} limit "
        f"(raise it with max_bytes= or {MAX_BYTES_ENV})"
    )


def _open_regular(path: str, limit: int):
    """``path`` opened for reading if it is a regular file (links followed) within ``limit``.

    Opening does not block on a FIFO, and nothing but a regular file is read.
    """
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(path, flags)
    except FileNotFoundError:
        if os.path.islink(path):
            raise ModelFileError(path, f"dangling symbolic link (to {os.readlink(path)})") from None
        raise ModelFileError(path, "no such file") from None
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise ModelFileError(path, "symbolic link loop") from None
        if exc.errno == errno.ENXIO:
            raise ModelFileError(path, "not a regular file (a socket)") from None
        raise ModelFileError(path, f"cannot read ({exc.strerror or exc})") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise ModelFileError(path, f"not a regular file ({describe_mode(st.st_mode)})")
        if st.st_size > limit:
            raise ModelFileError(path, _too_big(st.st_size, limit))
        return os.fdopen(fd, "rb", buffering=0)
    except BaseException:
        os.close(fd)
        raise


def _chunks(path: str, limit: int, size: int = CHUNK):
    """The file's bytes in chunks; refuses compressed data and a file grown past ``limit``."""
    with _open_regular(path, limit) as fh:
        total = 0
        while chunk := fh.read(size):
            if not total:
                for magic, name in _MAGIC.items():
                    if chunk.startswith(magic):
                        raise ModelFileError(
                            path, f"a {name}-compressed file: kgnav reads plain GraphML only"
                        )
            total += len(chunk)
            if total > limit:
                raise ModelFileError(path, _too_big(total, limit))
            yield chunk
        if not total:
            raise ModelFileError(path, "empty file")


# ------------------------------------------------------------------------ compact attribute dicts
# A model of many small states is mostly attribute dicts: a sighting's seven attributes take a
# dict of 280 bytes and its key dict ({"sees": attrs}) 190 more, more than the sighting's text
# in the file. The __dict__s of one class's instances share one keys table (PEP 412): each is
# an ordinary dict, equal to and used like any other, at 150 and 100 bytes (CPython 3.11). Only
# loading makes them: a model built or merged in memory keeps networkx's dicts.
_SHARING = {kind: type(f"_{kind}_attributes", (), {})
            for kind in ("state", "object", "sees", "transition", "edge_keys")}


def _attrs(kind: str) -> dict:
    """``{"kind": kind}``, sharing its keys with every other dict of ``kind``."""
    d = _SHARING[kind]().__dict__
    d["kind"] = kind
    return d


def _keydict(key: str, attrs: dict) -> dict:
    """A multigraph's ``{edge key: attributes}`` for a first edge between two nodes."""
    d = _SHARING["edge_keys"]().__dict__
    d[key] = attrs
    return d


# ---------------------------------------------------------------------------------------- builder


@dataclass
class _Key:
    name: str | None
    domain: str  # graph, node, edge, all, ...
    gtype: str


class _Builder:
    """Builds a model from a file's keys, graph attributes, nodes and edges, checking each.

    Values come as ``{key id: text}``; every error names the element and its line.
    """

    def __init__(self, path: str):
        self.path = path
        self.keys: dict[str, _Key] = {}
        # per GraphML domain: key id -> attribute name, and attribute name -> key
        self.names: dict[str, dict[str, str]] = {"graph": {}, "node": {}, "edge": {}}
        self.by_name: dict[str, dict[str, _Key]] = {"graph": {}, "node": {}, "edge": {}}
        self.version = 0
        self.g: nx.MultiDiGraph | None = None
        self.later: list[tuple] = []  # edges read before their nodes

    def fail(self, what: str, line, reason: str) -> ModelFileError:
        where = f"{what} (line {line})" if line else what
        return ModelFileError(self.path, f"{where}: {reason}")

    # -------------------------------------------------------------------- keys
    def key(self, kid: str | None, domain: str, name: str | None, gtype: str, line) -> None:
        what = f"key {kid!r}"
        if kid is None:
            raise self.fail("key", line, "key without an id")
        if kid in self.keys:
            raise self.fail(what, line, "declared twice")
        if gtype not in GRAPHML_TYPES:
            raise self.fail(what, line, f"unsupported attr.type {gtype!r}")
        k = self.keys[kid] = _Key(name, domain, gtype)
        for dom in ("graph", "node", "edge") if domain == "all" else (domain,):
            if dom not in self.names:
                continue  # a key for ports, hyperedges...: unused, or refused where used
            if name is not None:
                want = KNOWN.get((dom, name))
                if want is not None and gtype not in COMPATIBLE[want]:
                    raise self.fail(what, line, f"{dom} attribute {name!r} is declared {gtype}, "
                                    f"not {want}")
                if name in self.by_name[dom]:
                    raise self.fail(what, line, f"{dom} attribute {name!r} is declared twice")
                self.by_name[dom][name] = k
            self.names[dom][kid] = name

    def named(self, domain: str, data: dict[str, str], what: str, line) -> dict[str, str]:
        """``{key id: text}`` as ``{attribute name: text}``."""
        names = self.names[domain]
        raw = {}
        for kid, text in data.items():
            name = names.get(kid, "")
            if not name:
                if kid not in self.keys:
                    why = f"refers to an undeclared key {kid!r}"
                elif name is None:
                    why = f"refers to key {kid!r}, which has no attr.name (a yEd graphics key?)"
                else:
                    why = f"refers to key {kid!r}, declared for {self.keys[kid].domain}"
                raise self.fail(what, line, f"a value {why}")
            raw[name] = text
        return raw

    def values(self, what: str, line, where: str, raw: dict[str, str], out: dict) -> dict:
        """Parse ``raw`` into ``out`` with the schema rows of ``where``; check none is missing."""
        parsers = self.parsers[where]
        name = None
        try:
            for name, text in raw.items():
                parse = parsers.get(name)
                out[name] = self.other(what, line, where, name, text) if parse is None else parse(
                    text, self
                )
        except (ValueError, OverflowError) as exc:
            raise self.fail(what, line, f"attribute {name!r}: {exc}") from None
        if not self.required[where] <= out.keys():
            missing = sorted(self.required[where] - out.keys())
            raise self.fail(what, line, f"missing attribute {missing[0]!r}")
        return out

    def other(self, what: str, line, where: str, name: str, text: str):
        """An attribute outside the schema, typed as its key declares."""
        domain = DOMAIN[where]
        if (domain, name) in KNOWN or name == "kind":
            raise self.fail(what, line, f"{name!r} is not a {where} attribute")
        return parse_other(self.by_name[domain][name].gtype, text)

    # -------------------------------------------------------------------- graph
    def declares(self, domain: str, name: str) -> bool:
        return name in self.by_name[domain]

    def graph_complete(self, data: dict[str, str]) -> bool:
        """Whether ``data`` holds every required graph attribute (or a version not read)."""
        named = {self.names["graph"].get(kid): text for kid, text in data.items()}
        if "kgnav_schema" not in named:
            return False
        try:
            version = Long().parse(named["kgnav_schema"], self)
        except ValueError:
            return True  # graph() names the error
        if version not in READABLE_VERSIONS:
            return True
        return all(n in named for n, a in schema(version)["graph"].items() if a.required)

    def graph_more(self, data: dict[str, str], line) -> None:
        """Graph attributes after the nodes, when those before were complete."""
        raw = self.named("graph", data, "graph", line)
        for name in raw:
            if name in self.g.graph:
                raise self.fail("graph", line, f"attribute {name!r} given twice")
        self.g.graph.update(self.values("graph", line, "graph", raw, dict(self.g.graph)))

    def graph(self, data: dict[str, str], line, directed: bool) -> None:
        """The graph's own attributes: they fix the schema version, feature size and classes."""
        raw = self.named("graph", data, "graph", line)
        if "kgnav_schema" not in raw:
            raise ModelFileError(
                self.path, "not a kgnav Abstract Model (no kgnav_schema attribute)"
            )
        if not directed:
            raise self.fail("graph", line, "an undirected graph is not a kgnav model")
        try:
            version = Long().parse(raw["kgnav_schema"], self)
        except ValueError as exc:
            raise self.fail("graph", line, f"attribute 'kgnav_schema': {exc}") from None
        if version not in READABLE_VERSIONS:
            raise SchemaVersionError(
                self.path,
                f"schema version {version}, this kgnav reads version "
                f"{', '.join(map(str, READABLE_VERSIONS))}",
            )
        self.version = version
        rows = schema(version)
        self.parsers = {w: {n: a.codec.parse for n, a in r.items()} for w, r in rows.items()}
        self.required = {w: {n for n, a in r.items() if a.required} for w, r in rows.items()}
        # key id -> (name, parse) of each edge kind's schema attributes, for the common case
        self.edge_parsers = {
            kind: {
                kid: (name, self.parsers[kind][name])
                for kid, name in self.names["edge"].items()
                if name in self.parsers[kind]
            }
            for kind in ("transition", "sees")
        }
        self.edge_sizes = {kind: len(self.parsers[kind]) + 1 for kind in ("transition", "sees")}
        self.bins = None
        if raw.get(self._scan_name(), ""):  # the profiles' length, before any state is read
            try:
                self.bins = ScanGeometry.from_json(raw[self._scan_name()]).bins
            except (ValueError, KeyError, TypeError, RecursionError):
                pass  # values() names the problem
        attrs = self.values("graph", line, "graph", raw, {})
        self.dim = attrs["feature_dim"]
        self.classes = set(attrs["classes"].split(","))
        self.episodes = set(json.loads(attrs["episodes"]))
        self.g = nx.MultiDiGraph()
        self.g.graph.update(attrs)
        # networkx's own dicts, filled as add_node/add_edge fill them, without their per-call
        # cost (a fifth of the load time at 1e4 states)
        self.nodes, self.succ, self.pred = self.g._node, self.g._succ, self.g._pred

    @staticmethod
    def _scan_name() -> str:
        return "scan"

    # -------------------------------------------------------------------- nodes
    def node(self, nid: str | None, data: dict[str, str], line) -> None:
        what = f"node {nid!r}"
        if nid is None:
            raise self.fail("node", line, "node without an id")
        if nid in self.nodes:
            raise self.fail(what, line, "duplicate node id")
        raw = self.named("node", data, what, line)
        kind = raw.pop("kind", None)
        if kind != "state" and kind != "object":
            raise self.fail(what, line, "no kind attribute" if kind is None else
                            f"unknown kind {kind!r}")
        if not NODE_ID[kind].fullmatch(nid):
            raise self.fail(what, line, f"a {kind} id is {kind[0]} and a number, e.g. {kind[0]}12")
        attrs = self.values(what, line, kind, raw, _attrs(kind))
        reason = _check_node(self, kind, attrs)
        if reason:
            raise self.fail(what, line, reason)
        self.nodes[nid] = attrs
        self.succ[nid] = {}
        self.pred[nid] = {}

    # -------------------------------------------------------------------- edges
    def edge(self, key: str | None, u: str | None, v: str | None, data: dict[str, str],
             line) -> None:
        # The common case first (a 1e4-state model has 6e4 edges): exactly the schema's
        # attributes, valid, between nodes read already. Anything else: edge_slow.
        kind = "sees" if key == SEES else "transition" if key in ACTIONS else None
        if kind is not None and len(data) + 1 == self.edge_sizes[kind]:
            parsers = self.edge_parsers[kind]
            attrs = _attrs(kind)
            try:
                for kid, text in data.items():
                    name, parse = parsers[kid]
                    attrs[name] = parse(text, self)
            except (KeyError, ValueError, OverflowError):
                pass
            else:
                du, dv = self.nodes.get(u), self.nodes.get(v)
                if (du is not None and dv is not None and du["kind"] == "state"
                        and dv["kind"] == ("object" if kind == "sees" else "state")):
                    nbrs = self.succ[u]
                    keydict = nbrs.get(v)
                    if keydict is None:
                        nbrs[v] = self.pred[v][u] = _keydict(key, attrs)
                        return
                    if key not in keydict:
                        keydict[key] = attrs
                        return
        self.edge_slow(key, u, v, data, line)

    def edge_slow(self, key, u, v, data: dict[str, str], line) -> None:
        what = f"edge {u!r}->{v!r} ({key!r})"
        if key is None:
            raise self.fail(what, line, "edge without an id (kgnav keeps the action, or 'sees', "
                            "there)")
        if u is None or v is None:
            raise self.fail(what, line, "edge without a source or target")
        if key == SEES:
            kind = "sees"
        elif key in ACTIONS:
            kind = "transition"
        else:
            raise self.fail(what, line, f"{key!r} is neither 'sees' nor an action "
                            f"({', '.join(ACTIONS)})")
        raw = self.named("edge", data, what, line)
        if "kind" in raw and raw.pop("kind") != kind:  # kind is implied by the id
            raise self.fail(what, line, f"a {kind} edge has kind {kind!r}")
        attrs = self.values(what, line, kind, raw, _attrs(kind))
        if u not in self.nodes or v not in self.nodes:
            self.later.append((key, u, v, attrs, line))
        else:
            self.link(key, u, v, attrs, line)

    def link(self, key, u, v, attrs: dict, line) -> None:
        """Put an edge in the graph, checking its ends."""
        what = f"edge {u!r}->{v!r} ({key!r})"
        du, dv = self.nodes.get(u), self.nodes.get(v)
        if du is None or dv is None:
            raise self.fail(what, line, f"no node {u if du is None else v!r}")
        ends = ("state", "object") if key == SEES else ("state", "state")
        if (du["kind"], dv["kind"]) != ends:
            raise self.fail(what, line, f"a {attrs['kind']} edge joins {ends[0]} -> {ends[1]}")
        nbrs = self.succ[u]
        keydict = nbrs.get(v)
        if keydict is None:
            nbrs[v] = self.pred[v][u] = _keydict(key, attrs)
        elif key in keydict:
            raise self.fail(what, line, "appears twice")
        else:
            keydict[key] = attrs

    # -------------------------------------------------------------------- the model
    def finish(self) -> nx.MultiDiGraph:
        if self.g is None:
            raise ModelFileError(self.path, "no graph element")
        for args in self.later:
            self.link(*args)
        _check_model(self, self.g)
        upgrade(self.g, self.version)
        return self.g


def _check_node(b: _Builder, kind: str, attrs: dict) -> str | None:
    """What is wrong with a node given the graph's attributes, if anything."""
    if kind == "state":
        if attrs["episode"] not in b.episodes:
            return f"episode {attrs['episode']} is not in the graph's episodes"
    elif attrs["cls"] not in b.classes:
        return f"class {attrs['cls']!r} is not in the model's classes"
    return None


def _check_model(b: _Builder, g: nx.MultiDiGraph) -> None:
    """What involves several elements: each object's ``n_views`` against the states that see
    it, and (version 2) its ``score`` against the scores of those views.

    (Edge ends, their kinds and duplicate edges are checked as edges are added.)
    """
    pred = g._pred
    for n, d in g.nodes(data=True):
        if d["kind"] == "object":
            seen = len(pred[n])  # only states point at an object, one sees edge each
            if d["n_views"] != seen:
                raise ModelFileError(
                    b.path, f"node {n!r}: n_views is {d['n_views']}, but {seen} states see it"
                )
            if b.version >= 2:
                total = sum(e[SEES]["score"] for e in pred[n].values())
                if abs(d["score"] - total) > 1e-6 * max(1.0, total):
                    raise ModelFileError(
                        b.path, f"node {n!r}: score is {d['score']!r}, but its views' scores "
                        f"add up to {total!r}")


# ---------------------------------------------------------------------------------------- canonical

_HEADER = (
    "<?xml version='1.0' encoding='utf-8'?>",
    f'<graphml xmlns="{NS}" xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" '
    f'xsi:schemaLocation="{NS} {NS}/1.0/graphml.xsd">',
)
_KEY_LINE = re.compile(
    r'<key id="([A-Za-z0-9_]{1,32})" for="(graph|node|edge|all)" '
    r'attr\.name="([A-Za-z0-9_.:-]{1,128})" attr\.type="([a-z]{1,8})" />'
)
_GRAPH_LINE = '<graph edgedefault="directed">'
_CLOSING = (b"</graph>\n", b"</graphml>\n")

_LONGEST_LINE = 1 << 25  # a 2**20-d state is 6 MB
BLOCK = 1 << 22  # bytes the canonical reader takes at a time (cut at a line's end)


class _NotCanonical(Exception):
    """The file is not in kgnav's own layout (or in doubt): read it as any GraphML."""


def _pairs(line: str, start: int, stop: int) -> dict[str, str]:
    """``{k1: v1, k2: v2}`` from ``k1">v1</data><data key="k2">v2`` at ``line[start:stop]``.

    Only the values are copied out of the line. (That no value holds ``<`` is checked once for
    each block: see :meth:`_Canonical.line_block`.)
    """
    data: dict[str, str] = {}
    find = line.find
    while True:
        q = find('">', start, stop)
        end = find('</data><data key="', q, stop)
        if end < 0:
            end = stop
        kid = line[start:q]
        if q < 0 or not kid.isalnum() or kid in data:
            raise _NotCanonical
        data[kid] = line[q + 2 : end]
        if end == stop:
            return data
        start = end + 18


def _blocks(path: str, limit: int, size: int):
    """The file's bytes in blocks of about ``size`` that end at a newline, then what follows
    the last newline (empty for a file kgnav wrote)."""
    tail = b""
    for chunk in _chunks(path, limit, size):
        cut = chunk.rfind(b"\n") + 1
        if not cut:
            tail += chunk
            if len(tail) > _LONGEST_LINE:
                raise _NotCanonical
            continue
        yield b"".join((tail, memoryview(chunk)[:cut])) if tail else chunk[:cut]
        tail = chunk[cut:]
    yield tail


# -- the bulk reader of the lines kgnav writes -------------------------------------------------
# Each value pattern takes what kgnav writes, loosely enough that Python's own int() and float()
# (the builder's parsers) decide what a number is; none takes '<', '&', ']', a newline, a control
# character or a non-ASCII byte, so a matched line reads as XML reads it. Features and range
# profiles are taken as exactly as many bytes as their base64 has (a skip, not a scan), which
# the strict base64 decoder then refuses unless they are the alphabet and nothing else.
_NUM = rb"([-+.0-9e]{1,40})"
_INT = rb"([-+0-9]{1,20})"
_SAFE = rb"([\x20-\x25\x27-\x3b\x3d-\x5c\x5e-\x7e]*)"  # printable ASCII but & < ]
_NODE_ID = {"state": rb"(s[0-9]{1,18})", "object": rb"(o[0-9]{1,18})"}


def _b64_chars(n_bytes: int) -> int:
    return 4 * -(-n_bytes // 3)


def _in_range(values: list, lo, hi) -> list:
    # values are never NaN here (the patterns exclude it): min and max decide
    if values and not (lo <= min(values) and max(values) <= hi):
        raise _NotCanonical
    return values


def _shared(parse, texts) -> list:
    """``parse`` of each text, one object per distinct text of the block: a value that repeats
    (a radius of 0, a score of 1, a clamped box edge, a pixel count) is then held once, not
    once per line (24-28 bytes each, a tenth of a sighting's memory). Keyed by the text, so
    ``-0.0`` and ``0.0`` stay apart."""
    seen = dict(zip(texts, map(parse, texts), strict=True))
    return [seen[t] for t in texts]


class _Field:
    """One attribute of a bulk line: its pattern (groups), and how its column is read."""

    def __init__(self, name: str, codec, b: _Builder):
        self.name, self.codec, self.b, self.optional = name, codec, b, False
        if isinstance(codec, Long):
            self.pattern, self.read = _INT, self.longs
        elif isinstance(codec, Double):
            self.pattern, self.read = _NUM, self.doubles
        elif isinstance(codec, Numbers):
            self.pattern, self.read = b" ".join([_NUM] * codec.n), self.numbers
        elif isinstance(codec, Features):
            n = _b64_chars(b.dim * 4)
            self.pattern, self.read = b"((?s:.){%d})" % n, self.features
        elif isinstance(codec, Ranges):
            n = _b64_chars(b.bins * 2)
            self.pattern, self.read = b"((?s:.){%d})" % n, self.ranges
        else:  # text: the codec checks it
            self.pattern, self.read = _SAFE, self.texts
        self.groups = re.compile(self.pattern).groups

    def longs(self, cols) -> list:
        return _in_range(_shared(int, cols[0]), self.codec.lo, self.codec.hi)

    def doubles(self, cols) -> list:
        return _in_range(_shared(float, cols[0]), self.codec.lo, self.codec.hi)

    def numbers(self, cols) -> list:
        bound = self.codec.bound
        return list(zip(*(_in_range(_shared(float, c), -bound, bound) for c in cols),
                        strict=True))

    def features(self, cols) -> list:
        dim = self.b.dim
        return [decode_features(text, dim, strict=True) for text in cols[0]]

    def ranges(self, cols) -> list:
        bins = self.b.bins
        return [decode_ranges(text, bins, strict=True) if text else None for text in cols[0]]

    def texts(self, cols) -> list:
        parse, b = self.codec.parse, self.b
        return [parse(text.decode("ascii"), b) for text in cols[0]]


class _Bulk:
    """The lines of nodes and edges exactly as kgnav writes them for the file's keys, as one
    regular expression: ``findall`` over a block gives every line's values in one call."""

    KINDS = ("state", "object", "sees", "transition")

    def __init__(self, b: _Builder):
        kid = {d: {name: k for k, name in b.names[d].items() if name} for d in ("node", "edge")}
        if "kind" not in kid["node"]:
            raise _NotCanonical
        rows = schema(b.version)
        self.fields: dict[str, list[_Field]] = {}
        alternatives = []
        self.first: dict[str, int] = {}  # kind -> index of its first group
        at = 0
        for kind in self.KINDS:
            domain = DOMAIN[kind]
            if domain == "node":
                head = b'<node id="%s"><data key="%s">%s</data>' % (
                    _NODE_ID[kind], re.escape(kid["node"]["kind"]).encode(), kind.encode())
                tail, groups = b"</node>\n", 1
            elif kind == "sees":
                head = b'<edge id="sees" source="%s" target="%s">' % (
                    _NODE_ID["state"], _NODE_ID["object"])
                tail, groups = b"</edge>\n", 2
            else:
                actions = b"|".join(a.encode() for a in ACTIONS)
                head = b'<edge id="(%s)" source="%s" target="%s">' % (
                    actions, _NODE_ID["state"], _NODE_ID["state"])
                tail, groups = b"</edge>\n", 3
            parts, fields = [head], []
            for name, attr in rows[kind].items():
                k = kid[domain].get(name)
                if k is None or not attr.required and (
                    not isinstance(attr.codec, Features | Ranges)
                    or isinstance(attr.codec, Ranges) and b.bins is None
                ):
                    # not declared; or optional, and either its value could be empty (present
                    # and absent would look alike) or the graph has no scan geometry: a line
                    # with it is not one the bulk reader takes
                    if attr.required:
                        raise _NotCanonical
                    continue
                f = _Field(name, attr.codec, b)
                data = b'<data key="%s">%s</data>' % (re.escape(k).encode(), f.pattern)
                if not attr.required:
                    f.optional = True
                    data = b"(?:%s)?" % data  # absent: its group is empty (a value never is)
                parts.append(data)
                fields.append(f)
                groups += f.groups
            parts.append(tail)
            self.first[kind] = at
            at += groups
            self.fields[kind] = fields
            alternatives.append(b"^" + b"".join(parts))
        self.junk = at  # the group of a line that is none of these
        alternatives.append(rb"^([^\n]*\n)")
        self.rx = re.compile(b"|".join(alternatives), re.MULTILINE)
        self.actions = {a.encode(): a for a in ACTIONS}

    def values(self, kind: str, lines: list[tuple]) -> list[dict]:
        """The attribute dicts of ``lines`` (all of ``kind``), every value checked as the
        builder checks it; :class:`_NotCanonical` at the first doubt."""
        if not lines:
            return []
        first = self.first[kind] + (1 if kind == "state" or kind == "object" else
                                    2 if kind == "sees" else 3)
        fields = self.fields[kind]
        n_groups = sum(f.groups for f in fields)
        cols = list(zip(*lines, strict=False))[first : first + n_groups]
        names, columns, at = ["kind"], [[kind] * len(lines)], 0
        optional = []
        for f in fields:
            column = f.read(cols[at : at + f.groups])
            at += f.groups
            if f.optional:
                optional.append(f.name)
            names.append(f.name)
            columns.append(column)
        out = []
        for row in zip(*columns, strict=False):
            d = _attrs(kind)
            d.update(zip(names, row, strict=False))
            out.append(d)
        for name in optional:  # absent: not in the dict (the builder would not have it either)
            for d in out:
                if d[name] is None:
                    del d[name]
        return out


class _Canonical:
    """A file in the exact layout kgnav writes; :class:`_NotCanonical` at anything else.

    The header (XML declaration, keys, graph attributes) is read line by line through the
    builder. The nodes and edges are read a block at a time by :class:`_Bulk`, which checks
    every value as the builder would (ranges, finiteness, ids, classes, episodes, ends,
    duplicates) and gives up at the first doubt; a block with any other line (an attribute
    outside the schema, a number written otherwise, ...) goes line by line through the builder.
    Every doubt or error sends the whole file to the XML reader, whose verdict stands.
    """

    def __init__(self, path: str, limit: int, block: int = BLOCK):
        self.path, self.limit, self.block = path, limit, block
        self.b = _Builder(path)
        self.state = 0  # 0, 1 header lines; 2 keys; 3 graph data; 4 body; 5 </graphml>; 6 end
        self.n = 0  # lines read
        self.bulk: _Bulk | None = None
        self.ids: dict[bytes, str] = {}  # node ids as the bulk reader sees them
        self.stats = {"bulk": 0, "line": 0}  # lines read each way (for tests and benchmarks)

    def read(self) -> nx.MultiDiGraph:
        for block in _blocks(self.path, self.limit, self.block):
            if self.state < 4:
                # the header line by line, up to the graph's data line; the rest in bulk
                at = block.find(f"\n{_GRAPH_LINE}\n".encode())
                end = block.find(b"\n", at + len(_GRAPH_LINE) + 2) + 1 if at >= 0 else 0
                if end:
                    self.line_block(block[:end])
                    block = block[end:]
                    if self.state != 4:
                        raise _NotCanonical
                else:
                    self.line_block(block)
                    continue
            if self.state == 4 and self.bulk_block(block):
                continue
            self.line_block(block)
        if self.state != 6:
            raise _NotCanonical
        return self.b.finish()

    # -------------------------------------------------------------------- in bulk
    def bulk_block(self, block: bytes) -> bool:
        """Read a block of node and edge lines (and the closing lines) in bulk; False when some
        line is not one the bulk reader takes."""
        if self.bulk is None:
            self.bulk = _Bulk(self.b)
        bulk = self.bulk
        lines = bulk.rx.findall(block)
        junk = bulk.junk
        nodes, edges = [], []
        state, obj = bulk.first["state"], bulk.first["object"]
        ends = 0
        for i, m in enumerate(lines):
            if m[junk]:  # the closing lines may end the block; anything else: line by line
                rest = [m[junk] for m in lines[i:]]
                if rest != list(_CLOSING[: len(rest)]):
                    return False
                ends = len(rest)
                lines = lines[:i]
                break
            if m[state] or m[obj]:
                if edges:
                    return False  # a node after an edge: kgnav never writes that
                nodes.append(m)
            else:
                edges.append(m)
        if nodes:
            self.add_nodes(nodes)
        if edges:
            self.add_edges(edges)
        self.n += len(lines) + ends
        self.stats["bulk"] += len(lines) + ends
        self.state += ends
        return True

    def add_nodes(self, lines: list[tuple]) -> None:
        bulk, b = self.bulk, self.b
        s, o = bulk.first["state"], bulk.first["object"]
        states = [m for m in lines if m[s]]
        objects = [m for m in lines if not m[s]]
        state_attrs = bulk.values("state", states)
        object_attrs = bulk.values("object", objects)
        if states and not {d["episode"] for d in state_attrs} <= b.episodes:
            raise _NotCanonical
        if objects and not {d["cls"] for d in object_attrs} <= b.classes:
            raise _NotCanonical
        s_attrs, o_attrs = iter(state_attrs), iter(object_attrs)
        nodes, succ, pred, ids = b.nodes, b.succ, b.pred, self.ids
        for m in lines:
            raw = m[s] or m[o]
            nid = raw.decode("ascii")
            if nid in nodes:
                raise _NotCanonical  # a duplicate
            nodes[nid] = next(s_attrs) if m[s] else next(o_attrs)
            succ[nid] = {}
            pred[nid] = {}
            ids[raw] = nid

    def add_edges(self, lines: list[tuple]) -> None:
        bulk, b = self.bulk, self.b
        e, t = bulk.first["sees"], bulk.first["transition"]
        sees = [m for m in lines if m[e]]
        trans = [m for m in lines if not m[e]]
        s_attrs = iter(bulk.values("sees", sees))
        t_attrs = iter(bulk.values("transition", trans))
        succ, pred, ids, actions = b.succ, b.pred, self.ids, bulk.actions
        try:
            for m in lines:
                if m[e]:
                    key, u, v, attrs = SEES, ids[m[e]], ids[m[e + 1]], next(s_attrs)
                else:
                    key, u, v = actions[m[t]], ids[m[t + 1]], ids[m[t + 2]]
                    attrs = next(t_attrs)
                nbrs = succ[u]
                keydict = nbrs.get(v)
                if keydict is None:
                    nbrs[v] = pred[v][u] = _keydict(key, attrs)
                elif key in keydict:
                    raise _NotCanonical  # a duplicate
                else:
                    keydict[key] = attrs
        except KeyError:  # a node not read (yet): the line-by-line reader knows what to do
            raise _NotCanonical from None

    # -------------------------------------------------------------------- line by line
    def line_block(self, block: bytes) -> None:
        """Read a block line by line through the builder, if every byte of it is one XML reads
        as it is and every ``<`` in it is markup the lines account for."""
        a = np.frombuffer(block, np.uint8)
        # no control character (XML refuses them; \r would read as \n) but tab and newline, no
        # entity or character reference, no CDATA end, no U+FFFE or U+FFFF
        controls = np.count_nonzero(a < 32)
        if (
            (controls and controls != np.count_nonzero(a == 10) + np.count_nonzero(a == 9))
            or b"&" in block
            or b"]]>" in block
            or (not block.isascii() and (b"\xef\xbf\xbe" in block or b"\xef\xbf\xbf" in block))
        ):
            raise _NotCanonical
        lines = block.decode("utf-8").split("\n")  # whole lines: no character is cut
        if lines.pop():
            raise _NotCanonical  # bytes after the last newline
        markup = 0
        for line in lines:
            self.n += 1
            markup += self.line(line)
        self.stats["line"] += len(lines)
        if markup != np.count_nonzero(a == 60):  # a "<" inside some value: markup, CDATA...
            raise _NotCanonical

    def line(self, line: str) -> int:
        """Read one line; the number of ``<`` of its markup."""
        b, n, state = self.b, self.n, self.state
        if state == 4:
            if line.endswith("</data></edge>"):
                # ids need no check here: the builder only takes a node id of the schema's
                # form, and an edge id or end that is not one it knows sends the file to the
                # XML reader
                q = line.find('"><data key="')
                tag = line[:q].split('"')
                if q < 0 or len(tag) != 6 or tag[0] != "<edge id=" or tag[2] != " source=" or (
                    tag[4] != " target="
                ):
                    raise _NotCanonical
                data = _pairs(line, q + 13, len(line) - 14)
                b.edge(tag[1], tag[3], tag[5], data, n)
            elif line.endswith("</data></node>"):
                q = line.find('"><data key="')
                if q < 10 or not line.startswith('<node id="') or '"' in line[10:q]:
                    raise _NotCanonical
                data = _pairs(line, q + 13, len(line) - 14)
                nid = line[10:q]
                b.node(nid, data, n)
                self.ids[nid.encode()] = nid
            elif line == "</graph>":
                self.state = 5
                return 1
            else:
                raise _NotCanonical
            return 2 + 2 * len(data)
        if state < 2:
            if line != _HEADER[state]:
                raise _NotCanonical
            self.state += 1
            return 1
        if state == 2:
            m = _KEY_LINE.fullmatch(line)
            if m is not None:
                b.key(m[1], m[2], m[3], m[4], n)
                return 1
            if line != _GRAPH_LINE:
                raise _NotCanonical
            self.state = 3
            return 1
        if state == 3:
            data = {}
            if line:
                if not (line.startswith('<data key="') and line.endswith("</data>")):
                    raise _NotCanonical
                data = _pairs(line, 11, len(line) - 7)
            b.graph(data, n, True)
            self.state = 4
            return 2 * len(data)
        if state == 5 and line == "</graphml>":
            self.state = 6
            return 1
        raise _NotCanonical


def _read_canonical(path: str, limit: int, block: int = BLOCK) -> nx.MultiDiGraph:
    """Read a file in the exact layout kgnav writes; :class:`_NotCanonical` at any other."""
    return _Canonical(path, limit, block).read()


# ---------------------------------------------------------------------------------------- XML

_T = {t: f"{{{NS}}}{t}" for t in ("graphml", "key", "graph", "node", "edge", "data", "desc")}
_XINCLUDE = ("http://www.w3.org/2001/XInclude", "http://www.w3.org/2003/XInclude")


_ENCODINGS = ("utf-8", "utf-16-le", "utf-16-be", "utf-32-le", "utf-32-be")
_DOCTYPES = tuple(("<!DOCTYPE".encode(e), e) for e in _ENCODINGS)
_DOCTYPE_TAIL = max(len(d) for d, _ in _DOCTYPES)


def _refuse_doctype(path: str, head: bytes) -> None:
    """A document type declaration in the bytes before the root element, in any encoding XML
    allows, is refused before the parser sees it (the same rule as :meth:`_XmlReader.check_prolog`,
    which catches what this byte scan cannot)."""
    for pattern, encoding in _DOCTYPES:
        at = head.find(pattern)
        if at >= 0:
            text = head[at:at + 400].decode(encoding, errors="replace")
            text = text[:text.find(">") + 1] or text[:100]
            raise ModelFileError(path, f"has a document type declaration ({show(text)}): "
                                       "not allowed")


def _pull_parser(tags: list[str]):
    """lxml's pull parser for the "end" of ``tags``, safe on a hostile file: no entities, no
    DTD, no network."""
    return etree.XMLPullParser(
        events=("end",),
        tag=tags,
        resolve_entities=False,
        no_network=True,
        load_dtd=False,
        remove_comments=True,  # text around a comment reads as one value
        remove_pis=True,
        huge_tree=False,  # keeps libxml2's limits on depth and text size
        collect_ids=False,
    )


class _XmlReader:
    """Any GraphML file, through lxml's pull parser, freeing elements as it goes."""

    def __init__(self, path: str, limit: int):
        self.path, self.limit = path, limit
        self.b = _Builder(path)
        self.graph_el = None
        self.graph_data: dict[str, str] = {}  # the graph's own attributes, by key id
        self.started = False  # the builder has them
        self.pending: list[tuple] | None = None  # nodes and edges read before them
        self.read_early: set[str] = set()  # graph attributes read ahead (see read_ahead)
        self.handled = 0  # nodes and edges handled since the last sweep
        self.prolog_checked = False

    def fail(self, el, reason: str) -> ModelFileError:
        tag = etree.QName(el).localname if isinstance(el.tag, str) else "entity"
        if tag == "edge":
            what = f"edge {el.get('source')!r}->{el.get('target')!r} ({el.get('id')!r})"
        else:
            what = tag if el.get("id") is None else f"{tag} {el.get('id')!r}"
        return self.b.fail(what, el.sourceline, reason)

    def stray(self, el) -> ModelFileError:
        """The error for an element that has no place in a kgnav model."""
        if not isinstance(el.tag, str):
            return self.fail(el.getparent(), "holds an entity reference (not allowed)")
        q = etree.QName(el)
        if q.namespace in _XINCLUDE:
            return self.fail(el, "XInclude is not allowed")
        if q.namespace != NS:
            return self.fail(el, f"unexpected element {q.text!r}")
        if q.localname == "graph":
            return self.fail(el, "more than one graph, or a nested graph")
        if q.localname == "data":
            return self.fail(el, "graph attributes must come before the first node")
        return self.fail(el, f"<{q.localname}> is not part of a kgnav model")

    # -------------------------------------------------------------------- driver
    def read(self) -> nx.MultiDiGraph:
        parser = _pull_parser([_T["key"], _T["graph"], _T["node"], _T["edge"]])
        handlers = {
            _T["key"]: self.key,
            _T["node"]: self.node,
            _T["edge"]: self.edge,
            _T["graph"]: self.graph_end,
        }

        def handle_events() -> None:
            for _, el in parser.read_events():
                if not self.prolog_checked:
                    self.check_prolog(el)
                handlers[el.tag](el)

        prolog = b""
        try:
            for chunk in _chunks(self.path, self.limit):
                if not self.prolog_checked:
                    # libxml2 opens an external DTD or parameter entity as it parses the
                    # DOCTYPE (a FIFO named there hangs the read): refuse it unread
                    prolog = prolog[-_DOCTYPE_TAIL:] + bytes(chunk)
                    _refuse_doctype(self.path, prolog)
                parser.feed(chunk)
                handle_events()
            root = parser.close()
            handle_events()
        except etree.LxmlError as exc:
            msg = " ".join(str(getattr(exc, "msg", None) or exc).split())  # libxml2 ends some in \n
            raise ModelFileError(self.path, f"not valid XML ({msg})") from None
        if not self.prolog_checked:
            self.check_prolog(root)
        self.check_root(root)
        return self.b.finish()

    def check_prolog(self, el) -> None:
        """Refuse a DTD (the only way to declare entities) before anything else is read."""
        self.prolog_checked = True
        doctype = el.getroottree().docinfo.doctype
        if doctype:
            raise ModelFileError(
                self.path, f"has a document type declaration ({show(doctype)}): not allowed"
            )

    def check_root(self, root) -> None:
        if root.tag != _T["graphml"]:
            q = etree.QName(root)
            if q.localname == "graphml":
                raise ModelFileError(self.path, "root element graphml lacks the GraphML namespace")
            raise ModelFileError(self.path, f"root element is {q.localname!r}, not graphml")
        if self.graph_el is None:
            raise ModelFileError(self.path, "no graph element")
        for el in root:
            if el.tag != _T["key"] and el.tag != _T["desc"] and el is not self.graph_el:
                raise self.stray(el)

    # -------------------------------------------------------------------- elements
    def key(self, el) -> None:
        parent = el.getparent()
        if parent is None or parent.tag != _T["graphml"]:
            raise self.fail(el, "a key must be a child of the graphml element")
        for child in el:
            if child.tag == f"{{{NS}}}default":
                raise self.fail(el, "default values are not supported: give every value")
            if child.tag != _T["desc"]:
                raise self.stray(child)
        self.b.key(el.get("id"), el.get("for", "all"), el.get("attr.name"),
                   el.get("attr.type", "string"), el.sourceline)

    def data_of(self, el) -> dict[str, str]:
        """The ``{key id: text}`` of an element's <data> children."""
        data: dict[str, str] = {}
        for d in el:
            if d.tag != _T["data"]:
                if d.tag == _T["desc"]:
                    continue
                raise self.stray(d)
            kid = d.get("key")
            if len(d):
                raise self.fail(el, f"the value of key {kid!r} holds markup, not text")
            if kid in data:
                raise self.fail(el, f"key {kid!r} given twice")
            data[kid] = d.text or ""
        return data

    def start_graph(self, graph_el, el) -> None:
        """At the first node or edge ``el`` (or an empty graph's end): the graph's attributes.

        When they are not all there (networkx writes them after the nodes and edges), nodes and
        edges wait in :attr:`pending` until the graph ends.
        """
        if graph_el is None:
            raise ModelFileError(self.path, f"root element is {etree.QName(el).localname!r}, "
                                 "not graphml")
        if graph_el.tag != _T["graph"]:
            raise self.fail(el, "nodes and edges must be children of a graph")
        parent = graph_el.getparent()
        if parent is None:
            raise ModelFileError(self.path, "root element is 'graph', not graphml")
        if parent.tag != _T["graphml"]:
            raise self.stray(graph_el)
        self.graph_el = graph_el
        for child in list(graph_el):
            if child.tag == _T["node"] or child.tag == _T["edge"]:
                break
            self.graph_child(child)
            graph_el.remove(child)
        if el is not graph_el and not self.b.graph_complete(self.graph_data):
            if self.b.declares("graph", "kgnav_schema"):
                later = self.read_ahead()
                if later is None or not self.b.graph_complete({**self.graph_data, **later}):
                    self.pending = []  # the buffered reading decides what is wrong
                    return
                self.graph_data.update(later)
                self.read_early = set(later)
        self.end_graph_data()

    def read_ahead(self) -> dict[str, str] | None:
        """The graph's attributes that come after its first node (networkx writes them after
        all nodes and edges), from a first pass over the file that keeps nothing else: holding
        every node and edge until they arrive took 7 times the file's size in memory. None
        when that pass meets anything odd (a value given twice or holding markup, bad XML):
        the nodes and edges then wait in :attr:`pending`, and the reading reports the error
        where it always did."""
        parser = _pull_parser([_T["node"], _T["edge"], _T["data"]])
        found: dict[str, str] = {}
        try:
            for chunk in _chunks(self.path, self.limit):
                parser.feed(chunk)
                for _, el in parser.read_events():
                    parent = el.getparent()
                    if el.tag != _T["data"]:
                        el.clear()
                        while el.getprevious() is not None:
                            del parent[0]
                    elif parent is not None and parent.tag == _T["graph"]:
                        kid = el.get("key")
                        if len(el) or kid in found:
                            return None
                        found[kid] = el.text or ""
            parser.close()
        except (etree.LxmlError, ModelFileError):
            return None
        if any(found.get(k, v) != v for k, v in self.graph_data.items()):
            return None
        return {k: v for k, v in found.items() if k not in self.graph_data}

    def graph_child(self, el) -> None:
        """A child of the graph other than a node or edge: an attribute, or a description."""
        if el.tag == _T["desc"]:
            return
        if el.tag != _T["data"]:
            raise self.stray(el)
        kid = el.get("key")
        if kid in self.read_early:  # already read ahead, and checked there
            self.read_early.discard(kid)
            return
        if len(el):
            raise self.fail(self.graph_el, f"the value of key {kid!r} holds markup, not text")
        if kid in self.graph_data:
            raise self.fail(self.graph_el, f"key {kid!r} given twice")
        self.graph_data[kid] = el.text or ""
        if self.started:  # read after the nodes: the attributes are all known already
            self.b.graph_more({kid: el.text or ""}, el.sourceline)

    def end_graph_data(self) -> None:
        """The graph's attributes are all read: build the graph, then what waited for it."""
        g = self.graph_el
        self.b.graph(self.graph_data, g.sourceline, g.get("edgedefault", "directed") == "directed")
        self.started = True
        pending, self.pending = self.pending, None
        for token in pending or ():
            if token[0] == "node":
                self.b.node(*token[1:])
            else:
                self.b.edge(*token[1:])

    def tick(self, el) -> None:
        """For every node and edge: it must be a child of the graph; every 1024, free the
        ones handled before it."""
        parent = el.getparent()
        if parent is not self.graph_el:
            if self.graph_el is None:
                self.start_graph(parent, el)
            elif parent is not None and parent.tag == _T["graph"]:
                raise self.stray(parent)
            else:
                raise self.fail(el, "nodes and edges must be children of the graph")
        self.handled += 1
        if self.handled >= 1024:
            self.sweep(parent, parent.index(el))
            self.handled = 1

    def sweep(self, parent, n: int) -> None:
        """Delete the first ``n`` children of the graph: the nodes and edges handled since the
        last sweep, and any graph attribute among them."""
        if n != self.handled - 1:
            for child in parent[:n]:
                if child.tag != _T["node"] and child.tag != _T["edge"]:
                    self.graph_child(child)
        del parent[:n]

    def graph_end(self, el) -> None:
        if self.graph_el is None:
            self.start_graph(el, el)  # a graph without nodes or edges
            return
        if el is not self.graph_el:
            raise self.stray(el)
        self.handled += 1  # as if the end were one more element
        self.sweep(el, len(el))
        if self.pending is not None:
            self.end_graph_data()

    def node(self, el) -> None:
        self.tick(el)
        token = (el.get("id"), self.data_of(el), el.sourceline)
        if self.pending is None:
            self.b.node(*token)
        else:
            self.pending.append(("node", *token))

    def edge(self, el) -> None:
        self.tick(el)
        if el.get("directed", "true") not in ("true", "1"):
            raise self.fail(el, "an undirected edge is not part of a kgnav model")
        token = (el.get("id"), el.get("source"), el.get("target"), self.data_of(el),
                 el.sourceline)
        if self.pending is None:
            self.b.edge(*token)
        else:
            self.pending.append(("edge", *token))
