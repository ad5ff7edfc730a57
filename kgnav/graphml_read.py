"""Reading Abstract Model files: one pass that checks every value, whatever the file holds.

:func:`read_model` opens only a regular file within the size limit, refuses compressed data, and
hands the file to one of two tokenizers, which both feed a :class:`_Builder`:

* :func:`_read_canonical` reads the layout kgnav writes — the header, one key, node or edge per
  line — with plain string splitting, in about half the time of building XML elements. It
  accepts a file only if every line is in that layout and every byte is one XML reads the same
  way (no markup, entity or CDATA inside a value, no control character, valid UTF-8); at the
  first doubt, or at any error, it gives up and
* :class:`_XmlReader` reads the file as any GraphML, with lxml's pull parser (elements freed as
  they are handled, so memory holds the model, not the document; when the graph's attributes
  come after the nodes, as networkx writes them, the nodes' and edges' text waits for them in
  memory, about 2.5x the file at the peak). It refuses what it cannot
  read faithfully: a DTD (hence entities), XInclude, markup inside a value, nested graphs,
  hyperedges and ports, ``<default>`` values, undirected graphs. Its errors are the ones
  reported.

The builder checks every value against the schema rows of the file's version
(:mod:`kgnav.graphml_schema`), each node against the graph's attributes (:func:`_check_node`),
edges against their ends, and the whole model against its invariants (:func:`_check_model`).
Every problem becomes a :class:`~kgnav.errors.ModelFileError` naming the file, the element with
its line, and the reason; no other exception escapes :func:`read_model`.
"""

from __future__ import annotations

import codecs
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
from kgnav.geometry import ScanGeometry
from kgnav.graphml_schema import (
    COMPATIBLE,
    DOMAIN,
    GRAPHML_TYPES,
    KNOWN,
    NODE_ID,
    READABLE_VERSIONS,
    Long,
    parse_other,
    schema,
    show,
    upgrade,
)
from kgnav.model import ACTIONS, SEES, AbstractModel

NS = "http://graphml.graphdrawing.org/xmlns"

#: Largest file :func:`read_model` reads unless told otherwise (``max_bytes=`` or the
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


def read_model(path: str | os.PathLike[str], *, max_bytes: int | None = None) -> AbstractModel:
    """Load a model saved by :func:`kgnav.graphml.write_model`, validating every value.

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


def _chunks(path: str, limit: int):
    """The file's bytes in chunks; refuses compressed data and a file grown past ``limit``."""
    with _open_regular(path, limit) as fh:
        total = 0
        while chunk := fh.read(CHUNK):
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
        attrs = self.values(what, line, kind, raw, {"kind": kind})
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
            attrs = {"kind": kind}
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
                        nbrs[v] = self.pred[v][u] = {key: attrs}
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
        attrs = self.values(what, line, kind, raw, {"kind": kind})
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
            nbrs[v] = self.pred[v][u] = {key: attrs}
        elif key in keydict:
            raise self.fail(what, line, "appears twice")
        else:
            keydict[key] = attrs

    # -------------------------------------------------------------------- the model
    def finish(self) -> AbstractModel:
        if self.g is None:
            raise ModelFileError(self.path, "no graph element")
        for args in self.later:
            self.link(*args)
        _check_model(self, self.g)
        upgrade(self.g, self.version)
        return AbstractModel.from_graph(self.g)


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


_LONGEST_LINE = 1 << 25  # a 2**20-d state is 6 MB


class _NotCanonical(Exception):
    """The file is not in kgnav's own layout (or in doubt): read it as any GraphML."""


def _pairs(line: str, start: int, stop: int) -> dict[str, str]:
    """``{k1: v1, k2: v2}`` from ``k1">v1</data><data key="k2">v2`` at ``line[start:stop]``.

    Only the values are copied out of the line. (That no value holds ``<`` is checked once for
    the whole file: see :func:`_read_canonical`.)
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


class _Scan:
    """The file's lines as text, if every byte is one XML reads as it is; counts the ``<``."""

    def __init__(self, path: str, limit: int):
        self.path, self.limit = path, limit
        self.markup = 0  # the number of "<" in the file

    def lines(self):
        decoder = codecs.getincrementaldecoder("utf-8")("strict")
        tail = ""
        last = b""  # the previous chunk's last two bytes
        for chunk in _chunks(self.path, self.limit):
            a = np.frombuffer(chunk, np.uint8)
            # no control character (XML refuses them; \r would read as \n) but tab and newline,
            # no entity or character reference, no CDATA end, no U+FFFE or U+FFFF
            controls = np.count_nonzero(a < 32)
            if (
                (controls and controls != np.count_nonzero(a == 10) + np.count_nonzero(a == 9))
                or b"&" in chunk
                or (b"]" in chunk and b"]]>" in last + chunk)
            ):
                raise _NotCanonical
            last = chunk[-2:]
            if not chunk.isascii() and (b"\xef\xbf\xbe" in chunk or b"\xef\xbf\xbf" in chunk):
                raise _NotCanonical
            self.markup += np.count_nonzero(a == 60)
            text = tail + decoder.decode(chunk)
            lines = text.split("\n")
            tail = lines.pop()
            if len(tail) > _LONGEST_LINE:
                raise _NotCanonical
            yield from lines
        yield tail + decoder.decode(b"", final=True)


def _read_canonical(path: str, limit: int) -> AbstractModel:
    """Read a file in the exact layout kgnav writes; :class:`_NotCanonical` at any other."""
    b = _Builder(path)
    scan = _Scan(path, limit)
    lines = enumerate(scan.lines(), 1)
    for want in _HEADER:
        if next(lines, (0, None))[1] != want:
            raise _NotCanonical
    markup = 2  # "<" the lines parsed hold: two in the header
    line = ""
    for n, line in lines:
        m = _KEY_LINE.fullmatch(line)
        if m is None:
            break
        b.key(m[1], m[2], m[3], m[4], n)
        markup += 1
    if line != '<graph edgedefault="directed">':
        raise _NotCanonical
    n, line = next(lines)
    data = {}
    if line:
        if not (line.startswith('<data key="') and line.endswith("</data>")):
            raise _NotCanonical
        data = _pairs(line, 11, len(line) - 7)
    b.graph(data, n, True)
    markup += 3 + 2 * len(data)  # graph open and close, graphml close, data
    node, edge = b.node, b.edge
    for n, line in lines:
        # ids need no check here: the builder only takes a node id of the schema's form, and
        # an edge id or end that is not one it knows sends the file to the XML reader
        if line.endswith("</data></edge>"):
            q = line.find('"><data key="')
            tag = line[:q].split('"')
            if q < 0 or len(tag) != 6 or tag[0] != "<edge id=" or tag[2] != " source=" or (
                tag[4] != " target="
            ):
                raise _NotCanonical
            data = _pairs(line, q + 13, len(line) - 14)
            edge(tag[1], tag[3], tag[5], data, n)
        elif line.endswith("</data></node>"):
            q = line.find('"><data key="')
            if q < 10 or not line.startswith('<node id="') or '"' in line[10:q]:
                raise _NotCanonical
            data = _pairs(line, q + 13, len(line) - 14)
            node(line[10:q], data, n)
        else:
            break
        markup += 2 + 2 * len(data)
    if [line, *(text for _, text in lines)] != ["</graph>", "</graphml>", ""]:
        raise _NotCanonical
    if scan.markup != markup:  # a "<" inside some value: markup, a comment, CDATA...
        raise _NotCanonical
    return b.finish()


# ---------------------------------------------------------------------------------------- XML

_T = {t: f"{{{NS}}}{t}" for t in ("graphml", "key", "graph", "node", "edge", "data", "desc")}
_XINCLUDE = ("http://www.w3.org/2001/XInclude", "http://www.w3.org/2003/XInclude")


class _XmlReader:
    """Any GraphML file, through lxml's pull parser, freeing elements as it goes."""

    def __init__(self, path: str, limit: int):
        self.path, self.limit = path, limit
        self.b = _Builder(path)
        self.graph_el = None
        self.graph_data: dict[str, str] = {}  # the graph's own attributes, by key id
        self.started = False  # the builder has them
        self.pending: list[tuple] | None = None  # nodes and edges read before them
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
    def read(self) -> AbstractModel:
        parser = etree.XMLPullParser(
            events=("end",),
            tag=[_T["key"], _T["graph"], _T["node"], _T["edge"]],
            resolve_entities=False,
            no_network=True,
            load_dtd=False,
            remove_comments=True,  # text around a comment reads as one value
            remove_pis=True,
            huge_tree=False,  # keeps libxml2's limits on depth and text size
            collect_ids=False,
        )
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

        try:
            for chunk in _chunks(self.path, self.limit):
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
                self.pending = []
                return
        self.end_graph_data()

    def graph_child(self, el) -> None:
        """A child of the graph other than a node or edge: an attribute, or a description."""
        if el.tag == _T["desc"]:
            return
        if el.tag != _T["data"]:
            raise self.stray(el)
        kid = el.get("key")
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
