"""What an Abstract Model file holds: the GraphML schema as a table, and the codec of each value.

:data:`ATTRIBUTES` has one row per attribute: where it lives (the graph, a state or object node, a
transition or sees edge), its codec — GraphML type, parsing from text and formatting back, range
and finiteness — whether it is required, and the schema version that introduced it. Reading
(:mod:`kgnav.memory.graphml.read`) checks every value of a file against the rows of the file's
version, writing (:mod:`kgnav.memory.graphml`) formats each with its codec, so adding an attribute
is adding a row.

Schema versions this release reads are :data:`READABLE_VERSIONS`; :func:`upgrade` is where a model
read from an older version gets what later versions added.

>>> Double(0.0, 5.0).parse("2.5", None)
2.5
>>> Double(0.0, 5.0).parse("nan", None)
Traceback (most recent call last):
...
ValueError: not a finite number (nan)
>>> sorted(schema(1)["sees"])
['bbox', 'distance', 'obs', 'pixels']
"""

from __future__ import annotations

import binascii
import itertools
import json
import math
import re
import sys
from dataclasses import dataclass
from functools import cache
from xml.sax.saxutils import escape

import networkx as nx
import numpy as np

from kgnav.memory.constants import MAX_COORD, SAFE_ID, SCHEMA_VERSION
from kgnav.memory.geometry import ScanGeometry

try:  # SIMD base64, several times faster than binascii on a model's 1e8 characters of features
    from pybase64 import b64decode as _pyb64decode
    from pybase64 import b64encode_as_string as _b64encode
except ImportError:  # pragma: no cover - pybase64 is a dependency; binascii does the same, slower
    _pyb64decode = None

    def _b64encode(raw: bytes) -> str:
        return binascii.b2a_base64(raw, newline=False).decode("ascii")


def b64decode_strict(data: bytes | str) -> bytes:
    """Decode base64 that is exactly that: the alphabet, padded, nothing else (no whitespace, no
    other character); ``ValueError`` otherwise. Where it accepts, it agrees with the lenient
    ``binascii.a2b_base64`` that :func:`decode_features` uses."""
    if _pyb64decode is not None:
        return _pyb64decode(data, validate=True)
    return binascii.a2b_base64(data, strict_mode=True)


def b64encode(raw: bytes) -> str:
    """Standard, padded base64 of ``raw`` as text."""
    return _b64encode(raw)


_DTYPE = np.dtype("<f4")
_BIG_ENDIAN = sys.byteorder != "little"
INT64 = (-(2**63), 2**63 - 1)

#: Schema versions this release reads. Version-1 files are accepted as they are; when a version
#: adds attributes, :func:`upgrade` is where an older file's model gets them.
READABLE_VERSIONS = (1, 2, 3, 4, 5)


# ---------------------------------------------------------------------------------------- codecs
# A codec turns the text of one <data> into the in-memory value (raising ValueError with the
# reason) and back. ``gtype`` is the GraphML attr.type written in the <key>.


def show(text: str, limit: int = 40) -> str:
    return repr(text if len(text) <= limit else text[: limit - 3] + "...")


def _range_error(v, lo, hi, unit: str = "") -> ValueError:
    if isinstance(v, float) and not math.isfinite(v):
        return ValueError(f"not a finite number ({v!r})")
    if hi == INT64[1] or hi == math.inf:
        return ValueError(f"{v!r} is below the minimum {lo:g}{unit}")
    if lo == INT64[0] or lo == -math.inf:
        return ValueError(f"{v!r} is above the maximum {hi:g}{unit}")
    return ValueError(f"{v!r} is outside [{lo:g}, {hi:g}]{unit}")


@dataclass(frozen=True)
class Long:
    """A 64-bit integer in ``[lo, hi]``."""

    lo: int = INT64[0]
    hi: int = INT64[1]
    gtype = "long"

    def parse(self, text: str, ctx) -> int:
        # int() alone would also take "1_000" and non-ASCII digits
        if text.isascii() and "_" not in text:
            try:
                v = int(text)
            except ValueError:
                pass
            else:
                if self.lo <= v <= self.hi:
                    return v
                raise _range_error(v, self.lo, self.hi)
        raise ValueError(f"not an integer ({show(text)})")

    def format(self, v) -> str:
        return str(int(v))

    def format_many(self, values) -> list[str]:
        """:meth:`format` of each value (one call for a whole column of a save)."""
        return list(map(str, map(int, values)))


@dataclass(frozen=True)
class Double:
    """A finite float in ``[lo, hi]``."""

    lo: float = -MAX_COORD
    hi: float = MAX_COORD
    unit: str = ""
    gtype = "double"

    def parse(self, text: str, ctx) -> float:
        if text.isascii() and "_" not in text:
            try:
                v = float(text)
            except ValueError:
                pass
            else:
                if self.lo <= v <= self.hi:  # False for NaN too
                    return v
                raise _range_error(v, self.lo, self.hi, self.unit)
        raise ValueError(f"not a number ({show(text)})")

    def format(self, v) -> str:
        return repr(float(v))

    def format_many(self, values) -> list[str]:
        return list(map(repr, map(float, values)))


@dataclass(frozen=True)
class Numbers:
    """``n`` space-separated finite floats, each within ``[-bound, bound]``; held as a tuple."""

    n: int
    bound: float = MAX_COORD
    gtype = "string"

    def parse(self, text: str, ctx) -> tuple[float, ...]:
        parts = text.split()
        if len(parts) != self.n:
            raise ValueError(f"{len(parts)} numbers, expected {self.n}")
        if text.isascii() and "_" not in text:
            try:
                values = tuple(map(float, parts))
            except ValueError:
                pass
            else:
                total = sum(values)  # NaN or inf anywhere makes it NaN or inf
                if total - total == 0.0 and max(map(abs, values)) <= self.bound:
                    return values
                bad = next(v for v in values if not -self.bound <= v <= self.bound)
                raise _range_error(bad, -self.bound, self.bound)
        raise ValueError(f"not numbers ({show(text)})")

    def __post_init__(self):
        object.__setattr__(self, "_template", " ".join(["%r"] * self.n))

    def format(self, v) -> str:
        if len(v) != self.n:
            raise ValueError(f"{len(v)} numbers, expected {self.n}")
        return self._template % tuple(map(float, v))

    def format_many(self, values) -> list[str]:
        values = list(values)
        if any(len(v) != self.n for v in values):
            raise ValueError(f"not {self.n} numbers")
        texts = map(repr, map(float, itertools.chain.from_iterable(values)))
        return list(map(" ".join, zip(*[texts] * self.n, strict=True)))


class _String:
    """A codec whose value is held as its text."""

    gtype = "string"

    def format(self, v) -> str:
        return xml_text(str(v))

    def format_many(self, values) -> list[str]:
        return list(map(xml_text, map(str, values)))


@dataclass(frozen=True)
class Text(_String):
    """A string, optionally matching ``pattern`` (described by ``what``) or one of ``choices``."""

    pattern: re.Pattern | None = None
    what: str = ""
    choices: tuple[str, ...] = ()

    def parse(self, text: str, ctx) -> str:
        if self.pattern is not None and not self.pattern.fullmatch(text):
            raise ValueError(f"{show(text)} is not {self.what}")
        if self.choices and text not in self.choices:
            raise ValueError(f"{show(text)} is not one of {', '.join(self.choices)}")
        return text


def _json(text: str, kind: type, name: str):
    """``text`` parsed as JSON of type ``kind`` (``name`` in the message), or a ValueError
    that shows it."""
    try:
        value = json.loads(text)
    except (ValueError, RecursionError):
        raise ValueError(f"not JSON ({show(text)})") from None
    if not isinstance(value, kind):
        raise ValueError(f"not a JSON {name} ({show(text)})")
    return value


def _json_list(text: str) -> list:
    """``text`` parsed as a JSON list, or a ValueError that shows it."""
    return _json(text, list, "list")


@dataclass(frozen=True)
class JsonList(_String):
    """A JSON list of integers (``item="int"``) or model ids (``item="id"``); held as the text."""

    item: str

    def parse(self, text: str, ctx) -> str:
        for x in _json_list(text):
            ok = (
                type(x) is int and INT64[0] <= x <= INT64[1]
                if self.item == "int"
                else isinstance(x, str) and SAFE_ID.match(x)
            )
            if not ok:
                want = "an integer" if self.item == "int" else "a model id"
                raise ValueError(f"item {show(json.dumps(x))} is not {want}")
        return text


def _finite_numbers(x, n: int, bound: float = MAX_COORD) -> bool:
    return (isinstance(x, list) and len(x) == n
            and all(type(v) in (int, float) and math.isfinite(v) and abs(v) <= bound
                    for v in x))


@dataclass(frozen=True)
class LoopClosures(_String):
    """A JSON list of loop closures: ``{"state": "<model_id>/s<n>", "episode": <int>,
    "kept": <bool>}`` each (:attr:`kgnav.memory.model.AbstractModel.loop_closures`); from
    schema 5 (``links``) a kept closure may also name the stored state it was measured against
    and the relative pose, ``"to": "<model_id>/s<n>", "rel": [dx, dy, dtheta]``."""

    links: bool = False

    def parse(self, text: str, ctx) -> str:
        for x in _json_list(text):
            ok = (isinstance(x, dict) and {"state", "episode", "kept"} <= set(x)
                  and isinstance(x["state"], str) and _STATE_ORIGIN.fullmatch(x["state"])
                  and type(x["episode"]) is int and INT64[0] <= x["episode"] <= INT64[1]
                  and type(x["kept"]) is bool)
            extra = set(x) - {"state", "episode", "kept"} if isinstance(x, dict) else set()
            if ok and extra:
                ok = (self.links and extra == {"to", "rel"} and isinstance(x["to"], str)
                      and _STATE_ORIGIN.fullmatch(x["to"]) is not None
                      and _finite_numbers(x["rel"], 3))
            if not ok:
                link = ', "to": "model/sN", "rel": [dx, dy, dtheta]' if self.links else ""
                raise ValueError(f"item {show(json.dumps(x))} is not a loop closure "
                                 f'({{"state": "model/sN", "episode": N, "kept": true|false'
                                 f'{link}}})')
        return text


@dataclass(frozen=True)
class OdometryRecords(_String):
    """A JSON object: recorded state (``"<model_id>/s<n>"``) -> ``[step, x, y, theta, driven,
    turned]``, the state's pose as its episode's odometry had it (that episode's own frame,
    never corrected) and the distance driven and angle turned since the episode began
    (:attr:`kgnav.memory.model.AbstractModel.odometry`)."""

    def parse(self, text: str, ctx) -> str:
        for k, v in _json(text, dict, "object").items():
            if not (_STATE_ORIGIN.fullmatch(k) and _finite_numbers(v, 6, 1e12)):
                raise ValueError(f"item {show(json.dumps({k: v}))} is not an odometry record "
                                 '("model/sN": [step, x, y, theta, driven, turned])')
        return text


_STATE_ORIGIN = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.+-]{0,127}/s[0-9]{1,18}")


@dataclass(frozen=True)
class Classes(_String):
    """Comma-separated, non-empty class names."""

    def parse(self, text: str, ctx) -> str:
        if not text or any(not c for c in text.split(",")):
            raise ValueError(f"{show(text)} is not a comma-separated list of class names")
        return text


@dataclass(frozen=True)
class Features:
    """Base64 of ``feature_dim`` little-endian float32, all finite; held as a read-only array."""

    gtype = "string"

    def parse(self, text: str, ctx) -> np.ndarray:
        return decode_features(text, ctx.dim)

    def format(self, v) -> str:
        return encode_features(v)

    def format_many(self, values) -> list[str]:
        return list(map(encode_features, values))


@dataclass(frozen=True)
class ScanText(_String):
    """The geometry of the states' range profiles (JSON of a
    :class:`~kgnav.memory.geometry.ScanGeometry`), or empty when they carry none."""

    def parse(self, text: str, ctx) -> str:
        if text:
            try:
                ScanGeometry.from_json(text)
            except (ValueError, KeyError, TypeError, RecursionError):
                raise ValueError(f"{show(text)} is not a scan geometry") from None
        return text


_F16 = np.dtype("<f2")


@dataclass(frozen=True)
class Ranges:
    """Base64 of a range profile: the scan's ``bins`` little-endian float16, finite, >= 0;
    held as a read-only array."""

    gtype = "string"

    def parse(self, text: str, ctx) -> np.ndarray:
        bins = getattr(ctx, "bins", None)
        if bins is None:
            raise ValueError("a range profile, but the graph has no scan geometry")
        return decode_ranges(text, bins)

    def format(self, v) -> str:
        return b64encode(np.ascontiguousarray(v, dtype=_F16).tobytes())

    def format_many(self, values) -> list[str]:
        return list(map(self.format, values))


# ---------------------------------------------------------------------------------------- schema


@dataclass(frozen=True)
class Attr:
    """One attribute of the schema: where it lives, how it is coded, since which version."""

    where: str  # "graph", "state", "object", "transition" or "sees"
    name: str
    codec: object
    required: bool = True
    since: int = 1


_ID = Text(SAFE_ID, "a model id (letters, digits, _ . + -; at most 128)")
_ORIGIN = Text(
    re.compile(r"[A-Za-z0-9][A-Za-z0-9_.+-]{0,127}/[so][0-9]+(?: [A-Za-z0-9][A-Za-z0-9_.+-]{0,127}"
               r"/[so][0-9]+)*"),
    "a list of model_id/node_id",
)
_TOL = Double(0.0, MAX_COORD)

#: The schema. Adding an attribute is adding a row (with ``since`` = the version it comes with).
ATTRIBUTES: tuple[Attr, ...] = (
    Attr("graph", "kgnav_schema", Long(1)),
    Attr("graph", "model_id", _ID),
    Attr("graph", "feature_dim", Long(1, 1 << 20)),
    Attr("graph", "feature_dtype", Text(choices=("float32",))),
    Attr("graph", "extractor", Text()),
    Attr("graph", "classes", Classes()),
    Attr("graph", "episodes", JsonList("int")),
    Attr("graph", "merged_from", JsonList("id")),
    Attr("graph", "pose_tol", _TOL),
    Attr("graph", "angle_tol", _TOL),
    Attr("graph", "feature_tol", _TOL),
    Attr("graph", "object_radius", _TOL),
    Attr("state", "x", Double(unit=" m")),
    Attr("state", "y", Double(unit=" m")),
    Attr("state", "theta", Double(-math.pi, math.pi, " rad")),
    Attr("state", "episode", Long()),
    Attr("state", "step", Long()),
    Attr("state", "features", Features()),
    Attr("state", "origin", _ORIGIN),
    Attr("object", "cls", Text()),
    Attr("object", "x", Double(unit=" m")),
    Attr("object", "y", Double(unit=" m")),
    Attr("object", "z", Double(unit=" m")),
    Attr("object", "n_obs", Long(1)),
    Attr("object", "n_views", Long(0)),
    Attr("object", "origin", _ORIGIN),
    Attr("transition", "count", Long(1)),
    Attr("sees", "bbox", Numbers(4)),
    Attr("sees", "distance", Double(0.0, MAX_COORD, " m")),
    Attr("sees", "pixels", Long(0)),
    Attr("sees", "obs", Numbers(3)),
    # version 2: what the states saw of the free space, and the objects' extent and evidence
    Attr("graph", "scan", ScanText(), since=2),
    Attr("state", "ranges", Ranges(), required=False, since=2),
    Attr("object", "radius", Double(0.0, MAX_COORD, " m"), since=2),
    Attr("object", "score", Double(0.0, MAX_COORD), since=2),
    Attr("sees", "radius", Double(0.0, MAX_COORD, " m"), since=2),
    Attr("sees", "score", Double(0.0, 1.0), since=2),
    # version 3: the relocation threshold (cosine distance) the model's states are matched at;
    # absent when none was recorded (a model built without a memory, or read from an older file)
    Attr("graph", "relocation_threshold", Double(0.0, 2.0), required=False, since=3),
    # version 4: the loop closures that bent episodes onto the model (absent: none recorded)
    Attr("graph", "loop_closures", LoopClosures(), required=False, since=4),
    # version 5: each state's raw odometry, and kept loop closures as links to stored states,
    # so that a model's pose graph can be optimised again at every merge (docs/drift.md)
    Attr("graph", "loop_closures", LoopClosures(links=True), required=False, since=5),
    Attr("graph", "odometry", OdometryRecords(), required=False, since=5),
)

DOMAIN = {
    "graph": "graph", "state": "node", "object": "node", "transition": "edge", "sees": "edge"
}
NODE_ID = {"state": re.compile(r"s[0-9]{1,18}"), "object": re.compile(r"o[0-9]{1,18}")}


@cache
def schema(version: int) -> dict[str, dict[str, Attr]]:
    """The attributes of each element kind in files of schema ``version``."""
    out: dict[str, dict[str, Attr]] = {w: {} for w in DOMAIN}
    for a in ATTRIBUTES:
        if a.since <= version:
            out[a.where][a.name] = a
    return out


def _domain_types() -> dict[tuple[str, str], str]:
    """(GraphML domain, name) -> GraphML type, over every version; a name has one type."""
    types: dict[tuple[str, str], str] = {("node", "kind"): "string"}
    for a in ATTRIBUTES:
        key = (DOMAIN[a.where], a.name)
        if types.setdefault(key, a.codec.gtype) != a.codec.gtype:
            raise AssertionError(f"{key} has two types in the schema")  # a bug in the table
    return types


#: (GraphML domain, attribute name) -> GraphML type of every attribute of every version, and
#: ``kind`` (written on nodes; an edge's kind is implied by its id).
KNOWN = _domain_types()
GRAPHML_TYPES = ("boolean", "int", "long", "float", "double", "string")
#: The declared types a known attribute is read from: its own, or any number type for a float.
COMPATIBLE = {
    "long": {"int", "long"},
    "double": {"int", "long", "float", "double"},
    "string": {"string"},
}


def upgrade(g: nx.MultiDiGraph, version: int) -> None:
    """Bring a model read from an older schema version up to :data:`SCHEMA_VERSION` in place.

    Version 1 files have no range profiles (``scan`` is empty), point-like objects (radius 0)
    and views of full confidence (score 1, an object's score its number of views). Files
    before version 3 recorded no relocation threshold: it stays absent (unknown), never guessed.
    """
    if version < 2:
        g.graph["scan"] = ""
        for _n, d in g.nodes(data=True):
            if d["kind"] == "object":
                d["radius"] = 0.0
                d["score"] = float(d["n_views"])
        for *_e, d in g.edges(data=True):
            if d["kind"] == "sees":
                d["radius"] = 0.0
                d["score"] = 1.0
    g.graph["kgnav_schema"] = SCHEMA_VERSION


# ---------------------------------------------------------------------------------------- values


def encode_features(f: np.ndarray) -> str:
    """Base64 of the vector's little-endian float32 bytes."""
    return b64encode(np.ascontiguousarray(f, dtype=_DTYPE).tobytes())


def _decode(text: str | bytes, strict: bool) -> bytes:
    # non-strict decoding is 3x faster in binascii; a damaged payload still fails the length
    # check. (a2b_base64 takes ASCII text as is; b64decode would copy it first.)
    try:
        return b64decode_strict(text) if strict else binascii.a2b_base64(text)
    except (ValueError, TypeError):
        raise ValueError("not base64") from None


def decode_features(text: str | bytes, dim: int, strict: bool = False) -> np.ndarray:
    """Inverse of :func:`encode_features`; raises ``ValueError`` on a bad payload or NaN/inf.

    ``strict``: refuse anything but plain padded base64 (see :func:`b64decode_strict`).
    """
    raw = _decode(text, strict)
    if len(raw) != dim * _DTYPE.itemsize:
        raise ValueError(f"{len(raw) // _DTYPE.itemsize} values, expected {dim}")
    f = np.frombuffer(raw, dtype=_DTYPE)  # read-only: it shares the bytes
    if _BIG_ENDIAN:
        f = f.astype(np.float32)
        f.setflags(write=False)
    # a float64 sum of float32 values cannot overflow: it is finite iff every value is
    if not math.isfinite(f.sum(dtype=np.float64)):
        raise ValueError("contains NaN or infinite values")
    return f


def decode_ranges(text: str | bytes, bins: int, strict: bool = False) -> np.ndarray:
    """A range profile of ``bins`` values (base64 of float16), each finite and >= 0."""
    raw = _decode(text, strict)
    if len(raw) != bins * _F16.itemsize:
        raise ValueError(f"{len(raw) // _F16.itemsize} values, the scan has {bins} bins")
    r = np.frombuffer(raw, dtype=_F16)
    if _BIG_ENDIAN:
        r = r.astype(np.float16)
        r.setflags(write=False)
    if not (np.isfinite(r).all() and (r >= 0).all()):
        raise ValueError("holds NaN, infinite or negative ranges")
    return r


_XML_BAD = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\ud800-\udfff\ufffe\uffff]")


def xml_text(s: str) -> str:
    """``s`` as XML character data; refuses characters XML 1.0 cannot hold."""
    bad = _XML_BAD.search(s)
    if bad:
        raise ValueError(f"{show(s)} holds {bad.group()!r}, which XML cannot store")
    if "&" in s or "<" in s or ">" in s or "\r" in s:  # \r would read back as \n
        s = escape(s, {"\r": "&#13;"})
    return s


# ---------------------------------------------------------------------------------------- others
# Attributes outside the schema are kept: read as their <key> declares, written back typed by
# their Python value.


def parse_other(gtype: str, text: str):
    """The value of an attribute outside the schema, declared ``gtype``; ``ValueError`` if bad."""
    if gtype == "boolean":
        t = text.strip().lower()
        if t not in ("true", "false", "1", "0"):
            raise ValueError(f"not a boolean ({show(text)})")
        return t in ("true", "1")
    if gtype in ("int", "long"):
        return Long().parse(text, None)
    if gtype in ("float", "double"):
        try:
            return float(text)
        except ValueError:
            raise ValueError(f"not a number ({show(text)})") from None
    return text


def other_type(v) -> str:
    """The GraphML type an attribute outside the schema is written as."""
    if isinstance(v, bool | np.bool_):
        return "boolean"
    if isinstance(v, int | np.integer):
        return "long"
    if isinstance(v, float | np.floating):
        return "double"
    if isinstance(v, str):
        return "string"
    raise ValueError(
        f"holds a {type(v).__name__}; GraphML holds booleans, integers, numbers and strings"
    )


def format_other(v, gtype: str) -> str:
    if gtype == "boolean":
        return "true" if v else "false"
    if gtype == "long":
        return str(int(v))
    if gtype == "double":
        return repr(float(v))
    return xml_text(v)
