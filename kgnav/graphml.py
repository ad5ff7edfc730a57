"""Read and write Abstract Models as GraphML: one self-describing file per model.

The file is plain GraphML: ``<key>`` declarations name and type every attribute, state and object
nodes carry their attributes as ``<data>``, transitions and views are edges whose ``id`` is the
edge key (the action name, or ``sees``), as networkx writes multigraphs. GraphML holds only
scalars, so

* a state's feature vector is the base64 of its little-endian float32 bytes (the graph records
  ``feature_dim`` and ``feature_dtype``): a saved model loads back equal, features bit for bit;
* a view's bounding box and observed position are space-separated numbers (``bbox``, ``obs``);
* an edge's kind follows from its key and is not written.

Saving is atomic: the file is written beside the target and renamed over it.
``networkx.read_graphml(path, force_multigraph=True)`` reads the files too; kgnav writes and
parses them itself, schema first, because networkx's generic reader and writer take several
seconds for a 1e4-state model (``bench/bench_graphml.py`` measures ours).

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
from kgnav.model import SCHEMA_VERSION, SEES, AbstractModel

_DTYPE = np.dtype("<f4")
_NS = "http://graphml.graphdrawing.org/xmlns"

# Schema: scope -> attribute -> GraphML type. Node attributes are shared by both node kinds.
_GRAPH = {
    "kgnav_schema": "long",
    "model_id": "string",
    "feature_dim": "long",
    "feature_dtype": "string",
    "extractor": "string",
    "classes": "string",
    "episodes": "string",
    "merged_from": "string",
    "pose_tol": "double",
    "angle_tol": "double",
    "feature_tol": "double",
    "object_radius": "double",
}
_NODE = {
    "kind": "string",
    "x": "double",
    "y": "double",
    "theta": "double",
    "z": "double",
    "episode": "long",
    "step": "long",
    "features": "string",
    "cls": "string",
    "n_obs": "long",
    "n_views": "long",
    "origin": "string",
}
_EDGE = {"count": "long", "bbox": "string", "distance": "double", "pixels": "long", "obs": "string"}
_REQUIRED = {
    "state": {"kind", "x", "y", "theta", "episode", "step", "features", "origin"},
    "object": {"kind", "cls", "x", "y", "z", "n_obs", "n_views", "origin"},
    "transition": {"count"},
    "sees": {"bbox", "distance", "pixels", "obs"},
}
_KEY_ID = {
    **{("graph", n): f"g{i}" for i, n in enumerate(_GRAPH)},
    **{("node", n): f"n{i}" for i, n in enumerate(_NODE)},
    **{("edge", n): f"e{i}" for i, n in enumerate(_EDGE)},
}
_PY = {"boolean": bool, "int": int, "long": int, "float": float, "double": float, "string": str}


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


def _numbers(values) -> str:
    return " ".join(repr(float(v)) for v in values)


def _text(value) -> str:
    t = type(value)
    if t is float:
        return repr(value)  # shortest repr round-trips exactly
    if t is int:
        return str(value)
    value = str(value)
    return escape(value) if ("&" in value or "<" in value or ">" in value) else value


def _data(scope: str, attrs: dict) -> str:
    return "".join(f'<data key="{_KEY_ID[scope, k]}">{_text(v)}</data>' for k, v in attrs.items())


def to_graphml(model: AbstractModel) -> bytes:
    """The model as a GraphML document."""
    out = [
        "<?xml version='1.0' encoding='utf-8'?>\n"
        f'<graphml xmlns="{_NS}" xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" '
        f'xsi:schemaLocation="{_NS} {_NS}/1.0/graphml.xsd">\n'
    ]
    for scope, spec in (("graph", _GRAPH), ("node", _NODE), ("edge", _EDGE)):
        for name, typ in spec.items():
            out.append(
                f'<key id="{_KEY_ID[scope, name]}" for="{scope}" attr.name="{name}" '
                f'attr.type="{typ}" />\n'
            )
    out.append('<graph edgedefault="directed">\n')
    out.append(_data("graph", {k: model.graph.graph[k] for k in _GRAPH}))
    out.append("\n")
    for n, d in model.graph.nodes(data=True):
        if d["kind"] == "state":
            d = dict(d, features=encode_features(d["features"]))
        out.append(f"<node id={quoteattr(n)}>{_data('node', d)}</node>\n")
    for u, v, k, d in model.graph.edges(keys=True, data=True):
        if k == SEES:
            attrs = {
                "bbox": _numbers(d["bbox"]),
                "distance": d["distance"],
                "pixels": d["pixels"],
                "obs": _numbers(d["obs"]),
            }
        else:
            attrs = {"count": d["count"]}
        out.append(
            f"<edge id={quoteattr(k)} source={quoteattr(u)} target={quoteattr(v)}>"
            f"{_data('edge', attrs)}</edge>\n"
        )
    out.append("</graph>\n</graphml>\n")
    return "".join(out).encode("utf-8")


def write_model(model: AbstractModel, path: str | os.PathLike[str]) -> None:
    """Save ``model`` to ``path`` (GraphML), replacing any previous file atomically."""
    data = to_graphml(model)
    with atomic_open(path, "wb") as fh:
        fh.write(data)


def _bool(text: str) -> bool:
    return text.strip().lower() in ("true", "1")


def parse_graphml(path: str) -> tuple[nx.MultiDiGraph, dict[tuple[str, str], str]]:
    """Read a single-graph GraphML file into a ``MultiDiGraph`` (string ids, edge id = key).

    Returns the graph and the declared type of each ``(scope, attribute)``. Raises
    ``ValueError`` for XML that is not such a GraphML file.
    """
    parser = etree.XMLParser(resolve_entities=False, no_network=True, collect_ids=False)
    root = etree.parse(path, parser).getroot()
    if root.tag != f"{{{_NS}}}graphml":
        raise ValueError(f"root element is {etree.QName(root).localname!r}, not graphml")
    keys: dict[str, tuple[str, object]] = {}
    types: dict[tuple[str, str], str] = {}
    graph_el = None
    for el in root:
        if el.tag == f"{{{_NS}}}key":
            typ = el.get("attr.type", "string")
            if typ not in _PY:
                raise ValueError(f"key {el.get('id')!r} has unsupported type {typ!r}")
            name = el.get("attr.name")
            keys[el.get("id")] = (name, _bool if typ == "boolean" else _PY[typ])
            types[(el.get("for", "all"), name)] = typ
        elif el.tag == f"{{{_NS}}}graph":
            if graph_el is not None:
                raise ValueError("more than one graph in the file")
            graph_el = el
    if graph_el is None:
        raise ValueError("no graph element")
    data_tag, node_tag, edge_tag = (f"{{{_NS}}}{t}" for t in ("data", "node", "edge"))

    def data_of(el) -> dict:
        out = {}
        for d in el:
            if d.tag == data_tag:
                try:
                    name, conv = keys[d.get("key")]
                except KeyError:
                    raise ValueError(f"data refers to undeclared key {d.get('key')!r}") from None
                out[name] = conv(d.text or "")
        return out

    g = nx.MultiDiGraph()
    g.graph.update(data_of(graph_el))
    nodes, adj = g._node, g._adj
    for el in graph_el:
        if el.tag == node_tag:
            g.add_node(el.get("id"), **data_of(el))
        elif el.tag == edge_tag:
            u, v = el.get("source"), el.get("target")
            if u not in nodes or v not in nodes:
                raise ValueError(f"edge {u!r}->{v!r} refers to a missing node")
            if el.get("id") in adj[u].get(v, ()):
                raise ValueError(f"edge {u!r}->{v!r} with key {el.get('id')!r} appears twice")
            g.add_edge(u, v, key=el.get("id"), **data_of(el))
    return g, types


def _check_types(path, types: dict[tuple[str, str], str]) -> None:
    """Declared attribute types must be the schema's (a float may be declared as an integer)."""
    for scope, spec in (("graph", _GRAPH), ("node", _NODE), ("edge", _EDGE)):
        for name, want in spec.items():
            got = types.get((scope, name), types.get(("all", name)))
            if got is None or _PY[got] is _PY[want] or (_PY[want] is float and _PY[got] is int):
                continue
            raise ModelFileError(path, f"{scope} attribute {name!r} is declared {got}, not {want}")


def _floats(text: str, n: int, what: str) -> tuple[float, ...]:
    values = tuple(map(float, text.split()))
    if len(values) != n:
        raise ValueError(f"{what} has {len(values)} numbers, expected {n}")
    return values


def read_model(path: str | os.PathLike[str]) -> AbstractModel:
    """Load a model saved by :func:`write_model`, validating it.

    Raises :class:`~kgnav.errors.ModelFileError` (missing, unreadable, not GraphML, not a kgnav
    model, malformed) or :class:`~kgnav.errors.SchemaVersionError` naming the file and the reason.
    """
    path = os.fspath(path)
    if not os.path.exists(path):
        raise ModelFileError(path, "no such file")
    try:
        g, types = parse_graphml(path)
    except etree.XMLSyntaxError as exc:
        raise ModelFileError(path, f"not valid XML ({exc.msg})") from None
    except (ValueError, TypeError) as exc:
        raise ModelFileError(path, f"not a readable GraphML file ({exc})") from None
    except OSError as exc:
        raise ModelFileError(path, f"cannot read ({exc.strerror or exc})") from None
    if "kgnav_schema" not in g.graph:
        raise ModelFileError(path, "not a kgnav Abstract Model (no kgnav_schema attribute)")
    version = g.graph["kgnav_schema"]
    if version != SCHEMA_VERSION:
        raise SchemaVersionError(
            path, f"schema version {version!r}, this kgnav reads version {SCHEMA_VERSION}"
        )
    _check_types(path, types)
    missing = set(_GRAPH) - set(g.graph)
    if missing:
        raise ModelFileError(path, f"graph: missing attribute {sorted(missing)[0]!r}")
    for name in ("pose_tol", "angle_tol", "feature_tol", "object_radius"):
        g.graph[name] = float(g.graph[name])
    dim = g.graph["feature_dim"]
    if g.graph["feature_dtype"] != "float32" or dim <= 0:
        raise ModelFileError(path, f"unsupported features {g.graph['feature_dtype']}[{dim}]")
    classes = set(g.graph["classes"].split(","))
    for n, d in g.nodes(data=True):
        kind = d.get("kind")
        if kind not in ("state", "object"):
            raise ModelFileError(path, f"node {n!r}: unknown kind {kind!r}")
        missing = _REQUIRED[kind] - d.keys()
        if missing:
            raise ModelFileError(path, f"node {n!r}: missing attribute {sorted(missing)[0]!r}")
        for axis in ("x", "y", "theta") if kind == "state" else ("x", "y", "z"):
            d[axis] = float(d[axis])
        if kind == "state":
            try:
                d["features"] = decode_features(d["features"], dim)
            except (ValueError, TypeError) as exc:
                raise ModelFileError(path, f"state {n!r}: bad feature payload ({exc})") from None
        elif d["cls"] not in classes:
            raise ModelFileError(
                path, f"object {n!r}: class {d['cls']!r} not in the model's classes"
            )
    for u, v, k, d in g.edges(keys=True, data=True):
        kind = "sees" if k == SEES else "transition"
        missing = _REQUIRED[kind] - d.keys()
        if missing:
            raise ModelFileError(
                path, f"edge {u!r}->{v!r}: missing attribute {sorted(missing)[0]!r}"
            )
        want = ("state", "object") if kind == "sees" else ("state", "state")
        if (g.nodes[u]["kind"], g.nodes[v]["kind"]) != want:
            raise ModelFileError(path, f"edge {u!r}->{v!r}: a {kind} edge must join {want}")
        d["kind"] = kind
        if kind == "sees":
            try:
                d["bbox"] = _floats(d["bbox"], 4, "bbox")
                d["obs"] = _floats(d["obs"], 3, "obs")
            except ValueError as exc:
                raise ModelFileError(path, f"edge {u!r}->{v!r}: {exc}") from None
            d["distance"] = float(d["distance"])
    return AbstractModel.from_graph(g)
