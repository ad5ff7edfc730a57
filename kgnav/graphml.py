"""Read and write Abstract Models as GraphML: one self-describing file per model.

GraphML holds only scalar attributes, so each state's feature vector is stored as the base64 of
its little-endian float32 bytes (the graph records ``feature_dim`` and ``feature_dtype``); every
other attribute is a GraphML scalar. A saved model loads back equal, features bit for bit. Saving
is atomic: the file is written beside the target and renamed over it.

The files are plain GraphML that ``networkx.read_graphml(path, force_multigraph=True)`` reads
(edge ids are the action keys, as networkx writes them). kgnav writes and parses them itself, with
lxml, because networkx's generic reader and writer take about 1.5 s each for a 1e4-state model
with 2048-d features, against 0.3–0.5 s here (``bench/bench_graphml.py``).

>>> import numpy as np, tempfile, os
>>> from kgnav import AbstractModel
>>> m = AbstractModel(feature_dim=3, model_id="doc")
>>> s = m.add_state(np.array([0.1, 0.2, 0.3]), pose=(1.0, 2.0, 0.5))
>>> path = os.path.join(tempfile.mkdtemp(), "m.graphml")
>>> write_model(m, path)
>>> read_model(path) == m
True
"""

from __future__ import annotations

import base64
import os
from xml.sax.saxutils import escape, quoteattr

import networkx as nx
import numpy as np
from lxml import etree

from kgnav.atomic import atomic_open
from kgnav.errors import ModelFileError, SchemaVersionError
from kgnav.model import SCHEMA_VERSION, AbstractModel

_DTYPE = np.dtype("<f4")

_GRAPH_ATTRS = {
    "kgnav_schema": int,
    "model_id": str,
    "feature_dim": int,
    "feature_dtype": str,
    "extractor": str,
    "classes": str,
    "episodes": str,
    "merged_from": str,
    "pose_tol": float,
    "angle_tol": float,
    "feature_tol": float,
    "object_radius": float,
}
_NODE_ATTRS = {
    "state": {"x": float, "y": float, "theta": float, "episode": int, "step": int, "origin": str},
    "object": {
        "cls": str,
        "x": float,
        "y": float,
        "z": float,
        "n_obs": int,
        "n_views": int,
        "origin": str,
    },
}
_EDGE_ATTRS = {
    "transition": {"count": int},
    "sees": {
        "u0": float,
        "v0": float,
        "u1": float,
        "v1": float,
        "distance": float,
        "pixels": int,
        "ox": float,
        "oy": float,
        "oz": float,
    },
}


def encode_features(f: np.ndarray) -> str:
    """Base64 of the vector's little-endian float32 bytes."""
    return base64.b64encode(np.ascontiguousarray(f, dtype=_DTYPE).tobytes()).decode("ascii")


def decode_features(text: str, dim: int) -> np.ndarray:
    """Inverse of :func:`encode_features`; raises ``ValueError`` on a bad payload."""
    # non-strict decoding is 3x faster; a damaged payload still fails the length check
    raw = base64.b64decode(text)
    if len(raw) != dim * _DTYPE.itemsize:
        raise ValueError(f"{len(raw) // _DTYPE.itemsize} values, expected {dim}")
    f = np.frombuffer(raw, dtype=_DTYPE).astype(np.float32)
    f.setflags(write=False)
    return f


_NS = "http://graphml.graphdrawing.org/xmlns"
_HEADER = (
    "<?xml version='1.0' encoding='utf-8'?>\n"
    f'<graphml xmlns="{_NS}" xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" '
    f'xsi:schemaLocation="{_NS} {_NS}/1.0/graphml.xsd">\n'
)
_XML_TYPE = {bool: "boolean", int: "long", float: "double", str: "string"}
_PY_TYPE = {"boolean": bool, "int": int, "long": int, "float": float, "double": float, "string": str}


def _scalar(value) -> str:
    t = type(value)
    if t is float:
        return repr(value)  # shortest repr round-trips exactly
    if t is int:
        return str(value)
    if t is bool:
        return "true" if value else "false"
    return escape(value) if ("&" in value or "<" in value or ">" in value) else value


class _Keys:
    """GraphML ``<key>`` declarations, one per (scope, attribute name)."""

    def __init__(self) -> None:
        self.ids: dict[tuple[str, str], str] = {}
        self.decls: list[str] = []

    def id(self, scope: str, name: str, value) -> str:
        kid = self.ids.get((scope, name))
        if kid is None:
            kid = self.ids[(scope, name)] = f"d{len(self.ids)}"
            xml_type = _XML_TYPE[type(value)]
            self.decls.append(
                f'<key id="{kid}" for="{scope}" attr.name={quoteattr(name)} '
                f'attr.type="{xml_type}" />\n'
            )
        return kid

    def data(self, scope: str, attrs: dict) -> str:
        return "".join(
            f'<data key="{self.id(scope, k, v)}">{_scalar(v)}</data>' for k, v in attrs.items()
        )


def to_graphml(model: AbstractModel) -> bytes:
    """The model as a GraphML document (features base64-encoded)."""
    keys = _Keys()
    body = [
        '<graph edgedefault="directed">\n',
        keys.data("graph", model.graph.graph),
        "\n",
    ]
    for n, d in model.graph.nodes(data=True):
        if d["kind"] == "state":
            d = dict(d, features=encode_features(d["features"]))
        body.append(f"<node id={quoteattr(n)}>{keys.data('node', d)}</node>\n")
    for u, v, k, d in model.graph.edges(keys=True, data=True):
        body.append(
            f"<edge id={quoteattr(k)} source={quoteattr(u)} target={quoteattr(v)}>"
            f"{keys.data('edge', d)}</edge>\n"
        )
    body.append("</graph>\n</graphml>\n")
    return "".join([_HEADER, *keys.decls, *body]).encode("utf-8")


def write_model(model: AbstractModel, path: str | os.PathLike[str]) -> None:
    """Save ``model`` to ``path`` (GraphML), replacing any previous file atomically."""
    data = to_graphml(model)
    with atomic_open(path, "wb") as fh:
        fh.write(data)


def _bool(text: str) -> bool:
    return text.strip().lower() in ("true", "1")


def parse_graphml(path: str) -> nx.MultiDiGraph:
    """Read a single-graph GraphML file into a ``MultiDiGraph`` (string node ids, edge id = key).

    Raises ``ValueError`` for XML that is not GraphML as kgnav writes it.
    """
    parser = etree.XMLParser(resolve_entities=False, no_network=True, huge_tree=False)
    root = etree.parse(path, parser).getroot()
    if root.tag != f"{{{_NS}}}graphml":
        raise ValueError(f"root element is {etree.QName(root).localname!r}, not graphml")
    keys: dict[str, tuple[str, object]] = {}
    graph_el = None
    for el in root:
        if el.tag == f"{{{_NS}}}key":
            typ = _PY_TYPE.get(el.get("attr.type", "string"))
            if typ is None:
                raise ValueError(f"key {el.get('id')!r} has unsupported type {el.get('attr.type')!r}")
            keys[el.get("id")] = (el.get("attr.name"), _bool if typ is bool else typ)
        elif el.tag == f"{{{_NS}}}graph":
            if graph_el is not None:
                raise ValueError("more than one graph in the file")
            graph_el = el
    if graph_el is None:
        raise ValueError("no graph element")

    data_tag = f"{{{_NS}}}data"

    def data_of(el) -> dict:
        out = {}
        for d in el:
            if d.tag != data_tag:
                continue
            try:
                name, conv = keys[d.get("key")]
            except KeyError:
                raise ValueError(f"data refers to undeclared key {d.get('key')!r}") from None
            out[name] = conv(d.text or "")
        return out

    g = nx.MultiDiGraph()
    g.graph.update(data_of(graph_el))
    for el in graph_el:
        if el.tag == f"{{{_NS}}}node":
            g.add_node(el.get("id"), **data_of(el))
        elif el.tag == f"{{{_NS}}}edge":
            u, v = el.get("source"), el.get("target")
            if u not in g or v not in g:
                raise ValueError(f"edge {u!r}->{v!r} refers to a missing node")
            g.add_edge(u, v, key=el.get("id"), **data_of(el))
    return g


def _check(path, where: str, data: dict, spec: dict) -> None:
    for name, typ in spec.items():
        if name not in data:
            raise ModelFileError(path, f"{where}: missing attribute {name!r}")
        value = data[name]
        # GraphML may store an int-typed key as "long"; accept ints where floats are expected.
        if typ is float and isinstance(value, int) and not isinstance(value, bool):
            data[name] = value = float(value)
        if not isinstance(value, typ) or isinstance(value, bool):
            raise ModelFileError(
                path, f"{where}: attribute {name!r} is {type(value).__name__}, expected {typ.__name__}"
            )


def read_model(path: str | os.PathLike[str]) -> AbstractModel:
    """Load a model saved by :func:`write_model`, validating it.

    Raises :class:`~kgnav.errors.ModelFileError` (missing, unreadable, not GraphML, not a kgnav
    model, malformed) or :class:`~kgnav.errors.SchemaVersionError` naming the file and the reason.
    """
    path = os.fspath(path)
    if not os.path.exists(path):
        raise ModelFileError(path, "no such file")
    try:
        g = parse_graphml(path)
    except etree.XMLSyntaxError as exc:
        raise ModelFileError(path, f"not valid XML ({exc.msg})") from None
    except (ValueError, TypeError) as exc:
        raise ModelFileError(path, f"not a readable GraphML file ({exc})") from None
    except OSError as exc:
        raise ModelFileError(path, f"cannot read ({exc.strerror or exc})") from None
    if not isinstance(g, nx.MultiDiGraph) or "kgnav_schema" not in g.graph:
        raise ModelFileError(path, "not a kgnav Abstract Model (no kgnav_schema attribute)")
    version = g.graph["kgnav_schema"]
    if version != SCHEMA_VERSION:
        raise SchemaVersionError(
            path, f"schema version {version!r}, this kgnav reads version {SCHEMA_VERSION}"
        )
    _check(path, "graph", g.graph, _GRAPH_ATTRS)
    dim = g.graph["feature_dim"]
    if g.graph["feature_dtype"] != "float32" or dim <= 0:
        raise ModelFileError(path, f"unsupported features {g.graph['feature_dtype']}[{dim}]")
    classes = set(g.graph["classes"].split(","))
    for n, d in g.nodes(data=True):
        kind = d.get("kind")
        if kind not in _NODE_ATTRS:
            raise ModelFileError(path, f"node {n!r}: unknown kind {kind!r}")
        _check(path, f"node {n!r}", d, _NODE_ATTRS[kind])
        if kind == "state":
            try:
                d["features"] = decode_features(d.get("features", ""), dim)
            except (ValueError, TypeError) as exc:
                raise ModelFileError(path, f"state {n!r}: bad feature payload ({exc})") from None
        elif d["cls"] not in classes:
            raise ModelFileError(path, f"object {n!r}: class {d['cls']!r} not in the model's classes")
    for u, v, k, d in g.edges(keys=True, data=True):
        kind = d.get("kind")
        if kind not in _EDGE_ATTRS:
            raise ModelFileError(path, f"edge {u!r}->{v!r}: unknown kind {kind!r}")
        _check(path, f"edge {u!r}->{v!r}", d, _EDGE_ATTRS[kind])
        want = ("state", "object") if kind == "sees" else ("state", "state")
        if (g.nodes[u]["kind"], g.nodes[v]["kind"]) != want:
            raise ModelFileError(path, f"edge {u!r}->{v!r}: a {kind} edge must join {want}")
    return AbstractModel.from_graph(g)
