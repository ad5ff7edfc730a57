"""The Abstract Model: a finite state machine grounded in perception, as a NetworkX multi-digraph.

Schema (version :data:`SCHEMA_VERSION`, DESIGN.md §3):

============== ========================= ====================================================
element        kind                      attributes
============== ========================= ====================================================
state node     ``kind="state"``          ``x, y, theta`` (model frame), ``episode``, ``step``,
                                         ``features`` (float32 vector), ``origin``; optional
                                         ``ranges`` (float16 range profile, see
                                         :mod:`kgnav.memory.geometry`)
object node    ``kind="object"``         ``cls``, ``x, y, z`` (mean of observations),
                                         ``radius`` (mean extent of the observed surface),
                                         ``n_obs``, ``n_views``, ``score`` (summed detection
                                         scores of its views), ``origin``
transition     state → state, key=action ``kind="transition"``, ``count``
sees edge      state → object, key=sees  ``kind="sees"``, ``bbox`` (u0, v0, u1, v1 px),
                                         ``distance`` (m), ``pixels``, ``obs`` (x, y, z of
                                         this observation, model frame), ``radius``, ``score``
graph          —                         ``kgnav_schema``, ``model_id``, ``feature_dim``,
                                         ``extractor``, ``classes``, ``episodes``,
                                         ``merged_from``, ``scan`` (range profile geometry,
                                         JSON, or empty), tolerances; optional
                                         ``relocation_threshold``, ``loop_closures``
============== ========================= ====================================================

``origin`` is provenance: the space-separated ``"<model_id>/<node_id>"`` of every recorded node
folded into this one, the creator first. Merging keys on it, so merging observations that are
already in a model adds nothing (see :func:`kgnav.memory.merge.merge`).

>>> import numpy as np
>>> from kgnav import AbstractModel, Detection
>>> m = AbstractModel(feature_dim=4, model_id="demo")
>>> f = np.array([1, 0, 0, 0], dtype=np.float32)
>>> s0 = m.add_state(f, pose=(0, 0, 0), detections=[Detection("chair", (1.0, 0.0, 0.4))])
>>> s1 = m.add_state(f[::-1].copy(), pose=(0.25, 0, 0))
>>> m.add_transition(s0, "move_forward", s1)
>>> m.n_states, m.n_objects, m.n_transitions
(2, 1, 1)
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field

import networkx as nx
import numpy as np

from kgnav.common import se2
from kgnav.common.classes import OBJECT_CLASSES
from kgnav.errors import FeatureDimError, UnknownClassError, UnknownStateError
from kgnav.memory.constants import ACTIONS, MAX_COORD, SAFE_ID, SCHEMA_VERSION, SEES
from kgnav.memory.geometry import ScanGeometry
from kgnav.memory.graphml import read_graph, write_model


@dataclass(frozen=True)
class Detection:
    """One object seen from a state: ``F_{s,c}`` in the paper.

    ``position`` is in the model frame (bbox-centroid depth + pose); ``bbox`` is
    ``(u0, v0, u1, v1)`` in pixels; ``distance`` is metres from the agent; ``radius`` how far
    (m, in the floor plane) the visible surface extends around ``position`` (0: a point);
    ``score`` the segmenter's confidence.
    """

    cls: str
    position: tuple[float, float, float]
    bbox: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    distance: float = 0.0
    pixels: int = 0
    radius: float = 0.0
    score: float = 1.0


@dataclass(frozen=True)
class ObjectInfo:
    """A read-only view of an object node (its evidence beyond views:
    :mod:`kgnav.memory.evidence`)."""

    id: str
    cls: str
    position: tuple[float, float, float]
    n_views: int
    n_obs: int
    radius: float = 0.0
    score: float = 0.0


@dataclass
class _Index:
    """Lookup structures derived from the graph, rebuilt after bulk changes."""

    cells: dict[tuple[int, int], list[str]] = field(default_factory=dict)
    object_cells: dict[tuple[str, int, int], list[str]] = field(default_factory=dict)
    by_class: dict[str, list[str]] = field(default_factory=dict)
    by_origin: dict[str, str] = field(default_factory=dict)


def cosine_distance(a: np.ndarray, b: np.ndarray) -> float:
    """``1 - cos(a, b)``; two zero vectors are at distance 0, a zero and a non-zero at 1."""
    na, nb = float(np.linalg.norm(a)), float(np.linalg.norm(b))
    if na == 0.0 or nb == 0.0:
        return 0.0 if na == nb else 1.0
    return 1.0 - float(np.dot(a, b)) / (na * nb)


class AbstractModel:
    """An Abstract Model ``D = <S, A, delta>`` whose states carry features and object views.

    Parameters
    ----------
    feature_dim:
        Length of every state's feature vector ``F_s`` (2048 in the paper).
    model_id:
        Identifier used in the store and in provenance. Pass one for reproducible files;
        by default a random hex id is drawn.
    classes:
        Object-class vocabulary; a detection of another class raises :class:`UnknownClassError`.
    extractor:
        Name of the feature extractor, recorded so models from different extractors are not mixed.
    relocation_threshold:
        The cosine distance below which states are matched for relocation, recorded with the
        extractor: a threshold belongs to one extractor on one visual domain (None: not
        recorded).
    pose_tol, angle_tol, feature_tol:
        A new state is "already present" when a state lies within ``pose_tol`` metres and
        ``angle_tol`` radians and its features are within cosine distance ``feature_tol``.
    object_radius:
        Detections of a class within this distance (metres, in the floor plane) of an object of
        the same class are views of that object; for large objects the distance grows with
        their observed extent (see :meth:`association_distance`), so a bed seen from its foot
        and from its side stays one object.
    scan:
        The geometry of the states' range profiles (:class:`kgnav.memory.geometry.ScanGeometry`), or
        None when states carry none.
    """

    def __init__(
        self,
        feature_dim: int = 2048,
        *,
        model_id: str | None = None,
        classes: Sequence[str] = OBJECT_CLASSES,
        extractor: str = "unspecified",
        relocation_threshold: float | None = None,
        pose_tol: float = 0.05,
        angle_tol: float = math.radians(2.0),
        feature_tol: float = 1e-3,
        object_radius: float = 0.5,
        scan: ScanGeometry | None = None,
    ):
        if int(feature_dim) <= 0:
            raise ValueError(f"feature_dim must be positive, got {feature_dim}")
        if model_id is not None and not SAFE_ID.match(str(model_id)):
            raise ValueError(
                f"invalid model id {model_id!r}: use letters, digits and _ . + - (max 128)"
            )
        classes = tuple(classes)
        if not classes or any((not c) or ("," in c) for c in classes):
            raise ValueError("classes must be non-empty names without commas")
        for name, tol in (("pose_tol", pose_tol), ("angle_tol", angle_tol),
                          ("feature_tol", feature_tol), ("object_radius", object_radius)):
            if not 0.0 <= float(tol) <= MAX_COORD:
                raise ValueError(f"{name} must be a number in [0, {MAX_COORD:g}], got {tol!r}")
        self.graph = nx.MultiDiGraph()
        self.graph.graph.update(
            kgnav_schema=SCHEMA_VERSION,
            model_id=model_id if model_id is not None else os.urandom(8).hex(),
            feature_dim=int(feature_dim),
            feature_dtype="float32",
            extractor=str(extractor),
            classes=",".join(classes),
            episodes="[]",
            merged_from="[]",
            pose_tol=float(pose_tol),
            angle_tol=float(angle_tol),
            feature_tol=float(feature_tol),
            object_radius=float(object_radius),
            scan=scan.to_json() if scan is not None else "",
        )
        self.relocation_threshold = relocation_threshold
        self._init_counters()

    # ------------------------------------------------------------------ properties
    @property
    def model_id(self) -> str:
        return self.graph.graph["model_id"]

    @model_id.setter
    def model_id(self, value: str) -> None:
        if not SAFE_ID.match(str(value)):
            raise ValueError(f"invalid model id {value!r}: use letters, digits and _ . + -")
        self.graph.graph["model_id"] = str(value)

    @property
    def feature_dim(self) -> int:
        return int(self.graph.graph["feature_dim"])

    @property
    def classes(self) -> tuple[str, ...]:
        return tuple(self.graph.graph["classes"].split(","))

    @property
    def extractor(self) -> str:
        return self.graph.graph["extractor"]

    @property
    def relocation_threshold(self) -> float | None:
        """The relocation threshold the model was built with (None: not recorded)."""
        t = self.graph.graph.get("relocation_threshold")
        return None if t is None else float(t)

    @relocation_threshold.setter
    def relocation_threshold(self, value: float | None) -> None:
        if value is None:
            self.graph.graph.pop("relocation_threshold", None)
            return
        if not 0.0 < float(value) <= 2.0:
            raise ValueError(f"relocation_threshold must be a cosine distance in (0, 2], "
                             f"got {value!r}")
        self.graph.graph["relocation_threshold"] = float(value)

    @property
    def loop_closures(self) -> list[dict]:
        """The loop closures that laid drifting episodes onto this model
        (:mod:`kgnav.memory.posegraph`): ``{"state": origin, "episode": e, "kept": bool}``
        each, ``state`` the recorded node (``model_id/node_id``) the closure placed; rejected
        closures are kept too, so that a wrong one can be looked at."""
        return json.loads(self.graph.graph.get("loop_closures", "[]"))

    def add_loop_closures(self, closures: Iterable[dict]) -> None:
        """Record ``closures`` (see :attr:`loop_closures`); one already recorded is skipped.
        A kept closure may link its state to the stored state it was measured against:
        ``"to": "model_id/sN", "rel": (dx, dy, dtheta)`` (the state's pose in the frame of
        ``to``), which :func:`kgnav.memory.posegraph.straighten` uses again at later merges."""
        have = self.loop_closures
        seen = {(c["state"], c["episode"]) for c in have}
        for c in closures:
            link = {}
            if c.get("to") is not None:
                link = {"to": str(c["to"]), "rel": [float(v) for v in se2.as_pose(c["rel"])]}
            c = {"state": str(c["state"]), "episode": int(c["episode"]), "kept": bool(c["kept"]),
                 **link}
            if (c["state"], c["episode"]) not in seen:
                seen.add((c["state"], c["episode"]))
                have.append(c)
        self._set_loop_closures(have)

    def _set_loop_closures(self, closures: list[dict]) -> None:
        if closures:
            self.graph.graph["loop_closures"] = json.dumps(closures, separators=(",", ":"))

    def reject_loop_closures(self, closures: Iterable[dict]) -> None:
        """Mark recorded ``closures`` (matched by state and episode) as rejected: a link that
        a later optimisation of the model found contradicted stays on record, unused."""
        drop = {(str(c["state"]), int(c["episode"])) for c in closures}
        have = self.loop_closures
        if drop:
            for c in have:
                if (c["state"], c["episode"]) in drop:
                    c["kept"] = False
            self._set_loop_closures(have)

    @property
    def odometry(self) -> dict[str, tuple[float, ...]]:
        """Each recorded state's raw odometry (docs/drift.md): ``"model_id/sN" -> (step, x, y,
        theta, driven, turned)``, its pose in its episode's own odometry frame, never corrected,
        with the distance driven and angle turned since that episode began. Recorded only for
        episodes whose odometry drifts; merges keep every record."""
        text = self.graph.graph.get("odometry", "")
        return {k: tuple(v) for k, v in json.loads(text).items()} if text else {}

    def add_odometry(self, records: Mapping[str, Sequence[float]]) -> None:
        """Record raw odometry (see :attr:`odometry`); a state already recorded keeps its own."""
        if not records:
            return
        have = self.odometry
        for k, v in records.items():
            v = [float(x) for x in v]
            if len(v) != 6 or not all(math.isfinite(x) for x in v):
                raise ValueError(f"odometry of {k!r} must be 6 finite numbers, got {v!r}")
            have.setdefault(str(k), tuple(v))
        # rounded: micrometres and microradians are far below any odometry's error
        self.graph.graph["odometry"] = json.dumps(
            {k: [round(x, 6) for x in v] for k, v in have.items()}, separators=(",", ":"))

    @property
    def scan(self) -> ScanGeometry | None:
        """The geometry of the states' range profiles, or None."""
        text = self.graph.graph.get("scan", "")
        return ScanGeometry.from_json(text) if text else None

    def ranges(self, state: str) -> np.ndarray | None:
        """The state's range profile (read-only float16), or None if it has none."""
        return self._check_state(state).get("ranges")

    @property
    def episodes(self) -> list:
        """Episode identifiers that contributed states, in order of first appearance."""
        return json.loads(self.graph.graph["episodes"])

    @property
    def merged_from(self) -> list[str]:
        """Ids of the models merged into this one (provenance)."""
        return json.loads(self.graph.graph["merged_from"])

    def _tol(self, name: str) -> float:
        return float(self.graph.graph[name])

    @property
    def n_states(self) -> int:
        return self._n_states

    @property
    def n_objects(self) -> int:
        return self.graph.number_of_nodes() - self._n_states

    @property
    def n_transitions(self) -> int:
        return sum(1 for *_, d in self.graph.edges(data="kind") if d == "transition")

    def states(self) -> Iterator[str]:
        """State ids in insertion order."""
        return (n for n, k in self.graph.nodes(data="kind") if k == "state")

    def objects(self) -> Iterator[str]:
        """Object ids in insertion order."""
        return (n for n, k in self.graph.nodes(data="kind") if k == "object")

    def has_state(self, state: str) -> bool:
        return self.graph.nodes.get(state, {}).get("kind") == "state"

    def _check_state(self, state: str) -> dict:
        data = self.graph.nodes.get(state)
        if data is None or data.get("kind") != "state":
            raise UnknownStateError(state, self.model_id)
        return data

    def pose(self, state: str) -> se2.Pose:
        """The ``(x, y, theta)`` of a state in the model frame."""
        d = self._check_state(state)
        return (d["x"], d["y"], d["theta"])

    def features(self, state: str) -> np.ndarray:
        """The state's feature vector (read-only float32)."""
        return self._check_state(state)["features"]

    def state_features(self) -> tuple[list[str], np.ndarray]:
        """All state ids and their features as an ``(n_states, feature_dim)`` float32 matrix."""
        ids = list(self.states())
        if not ids:
            return ids, np.zeros((0, self.feature_dim), dtype=np.float32)
        return ids, np.stack([self.graph.nodes[s]["features"] for s in ids])

    def object_info(self, obj: str) -> ObjectInfo:
        d = self.graph.nodes[obj]
        return ObjectInfo(obj, d["cls"], (d["x"], d["y"], d["z"]), d["n_views"], d["n_obs"],
                          d["radius"], d["score"])

    def check_class(self, cls: str) -> str:
        if cls not in self.classes:
            raise UnknownClassError(cls, self.classes)
        return cls

    # ------------------------------------------------------------------ building
    def _init_counters(self) -> None:
        """Derive id counters and indexes from the graph (after construction, load or transform)."""
        self._n_states = 0
        next_s = next_o = 0
        for n, k in self.graph.nodes(data="kind"):
            num = int(n[1:]) if n[1:].isdigit() else -1
            if k == "state":
                self._n_states += 1
                next_s = max(next_s, num + 1)
            else:
                next_o = max(next_o, num + 1)
        self._next_state, self._next_object = next_s, next_o
        self._folded: dict[str, str] = {}  # object ids folded into another, and into which
        self._index = _Index()
        for n in self.graph.nodes:
            self._index_node(n)

    def _index_node(self, n: str) -> None:
        """Enter a node (as it is now) into the lookup structures."""
        d = self.graph.nodes[n]
        if d["kind"] == "state":
            self._index.cells.setdefault(self._cell(d["x"], d["y"]), []).append(n)
        else:
            self._index.by_class.setdefault(d["cls"], []).append(n)
            self._index.object_cells.setdefault(self._object_cell(n), []).append(n)
        for origin in d["origin"].split():
            self._index.by_origin[origin] = n

    @staticmethod
    def _grid(x: float, y: float, size: float) -> tuple[int, int]:
        """Grid cell of side ``size``: neighbours within ``size`` lie in the 3×3 block around it.

        Below a nanometre everything shares one cell, and cell numbers are clamped, so the index
        never meets an infinite quotient; neither changes which neighbours a search finds.
        """
        if not size >= 1e-9:
            return (0, 0)
        qx = min(max(x / size, -1e300), 1e300)
        qy = min(max(y / size, -1e300), 1e300)
        if qx != qx or qy != qy:  # NaN: only a caller bypassing add_state's checks gets here
            raise ValueError(f"non-finite position ({x}, {y})")
        return (math.floor(qx), math.floor(qy))

    def _cell(self, x: float, y: float) -> tuple[int, int]:
        return self._grid(x, y, self._tol("pose_tol"))

    def known_node(self, origins: str) -> str | None:
        """The node that already holds any of the space-separated ``origins``, if one does."""
        for origin in origins.split():
            hit = self._index.by_origin.get(origin)
            if hit is not None:
                return hit
        return None

    def _add_origins(self, node: str, origins: str) -> None:
        d = self.graph.nodes[node]
        have = set(d["origin"].split())
        new = [o for o in origins.split() if o not in have]
        if new:
            d["origin"] = " ".join([d["origin"], *new])
            for o in new:
                self._index.by_origin[o] = node

    def _object_cell(self, oid: str) -> tuple[str, int, int]:
        d = self.graph.nodes[oid]
        return (d["cls"], *self._grid(d["x"], d["y"], self._tol("object_radius")))

    def _validate_features(self, features) -> np.ndarray:
        f = np.asarray(features)
        if f.ndim != 1 or f.shape[0] != self.feature_dim:
            raise FeatureDimError(tuple(f.shape), self.feature_dim)
        f = np.array(f, dtype=np.float32, copy=True)
        if not np.all(np.isfinite(f)):
            raise ValueError("feature vector contains NaN or infinite values")
        f.setflags(write=False)
        return f

    def find_state(self, pose, features) -> str | None:
        """An existing state coincident with ``pose`` and ``features`` (tolerances), else None."""
        x, y, theta = se2.as_pose(pose)
        f = features if isinstance(features, np.ndarray) else np.asarray(features, np.float32)
        cx, cy = self._cell(x, y)
        pose_tol, angle_tol = self._tol("pose_tol"), self._tol("angle_tol")
        feature_tol = self._tol("feature_tol")
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                for s in self._index.cells.get((cx + dx, cy + dy), ()):
                    d = self.graph.nodes[s]
                    if (
                        math.hypot(d["x"] - x, d["y"] - y) <= pose_tol
                        and se2.angle_diff(d["theta"], theta) <= angle_tol
                        and cosine_distance(d["features"], f) <= feature_tol
                    ):
                        return s
        return None

    def add_state(
        self,
        features,
        pose,
        detections: Iterable[Detection] = (),
        *,
        episode: int = 0,
        step: int = 0,
        ranges=None,
    ) -> str:
        """Add the state ``s = <F_s, C_s, {F_s,c}>`` and return its id.

        If a coincident state is already present (see the class tolerances) its id is returned and
        the model is unchanged: the caller then only adds the transition, as the paper does.
        ``ranges`` is the state's range profile (one value per bin of the model's ``scan``).
        """
        f = self._validate_features(features)
        r = self._validate_ranges(ranges)
        pose = se2.as_pose(pose)
        if not all(abs(v) <= MAX_COORD for v in pose):
            raise ValueError(f"pose must be finite, within {MAX_COORD:g} m: got {pose}")
        detections = list(detections)
        for det in detections:
            self.check_class(det.cls)
            if len(det.position) != 3 or len(det.bbox) != 4:
                raise ValueError(
                    f"a {det.cls} detection needs position (x, y, z) and bbox (u0, v0, u1, v1)"
                )
            if not (
                all(abs(float(v)) <= MAX_COORD for v in (*det.position, *det.bbox))
                and 0.0 <= float(det.distance) <= MAX_COORD
                and int(det.pixels) >= 0
            ):
                raise ValueError(
                    f"a {det.cls} detection needs finite position and bbox within {MAX_COORD:g}, "
                    f"distance >= 0 and pixels >= 0, got {det}"
                )
        existing = self.find_state(pose, f)
        if existing is not None:
            return existing
        sid = self._new_state_node(pose, f, episode=episode, step=step, origin=None, ranges=r)
        for det in detections:
            self._add_view(
                sid,
                det.cls,
                tuple(float(v) for v in det.position),
                dict(
                    bbox=tuple(float(v) for v in det.bbox),
                    distance=float(det.distance),
                    pixels=int(det.pixels),
                    radius=max(float(det.radius), 0.0),
                    score=float(det.score),
                ),
            )
        return sid

    def _validate_ranges(self, ranges) -> np.ndarray | None:
        if ranges is None:
            return None
        scan = self.scan
        if scan is None:
            raise ValueError("this model has no scan geometry: create it with scan=... to "
                             "store range profiles")
        r = np.array(ranges, dtype=np.float16, copy=True).reshape(-1)
        if r.shape != (scan.bins,):
            raise ValueError(f"range profile has {r.size} values, the model's scan has "
                             f"{scan.bins} bins")
        if not np.all(np.isfinite(r)) or (r < 0).any():
            raise ValueError("range profile values must be finite and >= 0")
        r.setflags(write=False)
        return r

    def _new_state_node(self, pose, f, *, episode, step, origin, ranges=None) -> str:
        sid = f"s{self._next_state}"
        self._next_state += 1
        x, y, theta = (float(v) for v in pose)
        self.graph.add_node(
            sid,
            kind="state",
            x=x,
            y=y,
            theta=se2.wrap_angle(theta),
            episode=int(episode),
            step=int(step),
            features=f,
            origin=origin or f"{self.model_id}/{sid}",
        )
        if ranges is not None:
            self.graph.nodes[sid]["ranges"] = ranges
        self._n_states += 1
        self._index_node(sid)
        episodes = self.episodes
        if episode not in episodes:
            episodes.append(episode)
            self.graph.graph["episodes"] = json.dumps(episodes)
        return sid

    #: Largest association distance (m) however large the objects: two beds side by side stay two.
    MAX_ASSOCIATION = 1.2

    def association_distance(self, r_a: float, r_b: float) -> float:
        """Two same-class observations whose observed surfaces extend ``r_a`` and ``r_b``
        metres around their centres belong to one object when their centres are at most this
        far apart: the two extents touching (10 cm of slack), at least ``object_radius`` (what
        point-like observations use), at most :attr:`MAX_ASSOCIATION`."""
        return min(max(self._tol("object_radius"), r_a + r_b + 0.1), self.MAX_ASSOCIATION)

    def _nearest_object(self, cls: str, x: float, y: float, radius: float = 0.0,
                        skip: str | None = None) -> str | None:
        """The nearest ``cls`` object that an observation at (x, y) extending ``radius``
        associates with (see :meth:`association_distance`), if any."""
        cell = self._tol("object_radius")
        k = max(1, math.ceil(self.MAX_ASSOCIATION / cell)) if cell > 0 else 1
        best, best_d = None, math.inf
        cx, cy = self._grid(x, y, cell)
        for dx in range(-k, k + 1):
            for dy in range(-k, k + 1):
                for o in self._index.object_cells.get((cls, cx + dx, cy + dy), ()):
                    if o == skip:
                        continue
                    d = self.graph.nodes[o]
                    dist = math.hypot(d["x"] - x, d["y"] - y)
                    if dist > self.association_distance(d["radius"], radius):
                        continue
                    if dist < best_d or (dist == best_d and (best is None or o < best)):
                        best, best_d = o, dist
        return best

    def nearest_object(self, cls: str | None, x: float, y: float, radius: float) -> str | None:
        """The ``cls`` object (``None``: of any class) nearest to (x, y) in the plane, if within
        ``radius`` metres."""
        best, best_d = None, float(radius)
        for o in sorted(self.objects() if cls is None else self._index.by_class.get(cls, ())):
            d = self.graph.nodes[o]
            dist = math.hypot(d["x"] - x, d["y"] - y)
            if dist <= best_d:
                best, best_d = o, dist
        return best

    def _new_object_node(self, cls, xyz, n_obs: int, origin: str | None, radius: float = 0.0
                         ) -> str:
        oid = f"o{self._next_object}"
        self._next_object += 1
        self.graph.add_node(
            oid,
            kind="object",
            cls=cls,
            x=float(xyz[0]),
            y=float(xyz[1]),
            z=float(xyz[2]),
            radius=float(radius),
            n_obs=int(n_obs),
            n_views=0,
            score=0.0,
            origin=origin or f"{self.model_id}/{oid}",
        )
        self._index_node(oid)
        return oid

    def _absorb_into_object(self, oid: str, xyz, n_obs: int, radius: float = 0.0) -> None:
        """Fold ``n_obs`` observations with mean ``xyz`` and extent ``radius`` into the
        object's running means, then fold in any same-class object it now associates with."""
        d = self.graph.nodes[oid]
        old_cell = self._object_cell(oid)
        total = d["n_obs"] + n_obs
        for axis, v in zip("xyz", xyz, strict=True):
            d[axis] = float(d[axis] + (v - d[axis]) * n_obs / total)
        d["radius"] = float(d["radius"] + (radius - d["radius"]) * n_obs / total)
        d["n_obs"] = total
        self._reindex_object(oid, old_cell)
        self._fold_neighbours(oid)

    def _reindex_object(self, oid: str, old_cell) -> None:
        new_cell = self._object_cell(oid)
        if new_cell != old_cell:
            self._index.object_cells[old_cell].remove(oid)
            self._index.object_cells.setdefault(new_cell, []).append(oid)

    def _fold_neighbours(self, oid: str) -> None:
        """Keep one node per object: a moved or grown object swallows any same-class object
        it now associates with (views, observations, evidence and provenance combined)."""
        d = self.graph.nodes[oid]
        while True:
            other = self._nearest_object(d["cls"], d["x"], d["y"], d["radius"], skip=oid)
            if other is None:
                return
            o = self.graph.nodes[other]
            old_cell = self._object_cell(oid)
            total = d["n_obs"] + o["n_obs"]
            for axis in ("x", "y", "z", "radius"):
                d[axis] = float(d[axis] + (o[axis] - d[axis]) * o["n_obs"] / total)
            d["n_obs"] = total
            for sid, _, data in list(self.graph.in_edges(other, data=True)):  # score follows
                if data["kind"] == "sees":
                    self._link_view(sid, oid, {a: v for a, v in data.items() if a != "kind"})
            self._index.object_cells[self._object_cell(other)].remove(other)
            self._index.by_class[o["cls"]].remove(other)
            origins = o["origin"]
            self.graph.remove_node(other)
            self._folded[other] = oid
            self._add_origins(oid, origins)
            self._reindex_object(oid, old_cell)

    def remove_objects(self, ids) -> int:
        """Remove object nodes (and the views of them); returns how many were removed."""
        n = 0
        for oid in list(ids):
            d = self.graph.nodes.get(oid)
            if d is None or d["kind"] != "object":
                continue
            self._index.object_cells[self._object_cell(oid)].remove(oid)
            self._index.by_class[d["cls"]].remove(oid)
            for origin in d["origin"].split():
                if self._index.by_origin.get(origin) == oid:
                    del self._index.by_origin[origin]
            self.graph.remove_node(oid)
            n += 1
        return n

    def resolve(self, node: str) -> str:
        """The node that now holds ``node`` (an object may have been folded into another)."""
        while node in self._folded:
            node = self._folded[node]
        return node

    def _link_view(self, sid: str, oid: str, view: dict) -> None:
        if not self.graph.has_edge(sid, oid, SEES):
            self.graph.add_edge(sid, oid, key=SEES, kind="sees", **view)
            d = self.graph.nodes[oid]
            d["n_views"] += 1
            d["score"] = float(d["score"] + view.get("score", 1.0))

    def _add_view(self, sid: str, cls: str, xyz, view: dict) -> str:
        radius = view.get("radius", 0.0)
        oid = self._nearest_object(cls, xyz[0], xyz[1], radius)
        if oid is None:
            oid = self._new_object_node(cls, xyz, 1, None, radius)
            self._link_view(sid, oid, dict(view, obs=tuple(xyz)))
        else:
            # link first: the fold that absorbing may trigger must see this view
            self._link_view(sid, oid, dict(view, obs=tuple(xyz)))
            self._absorb_into_object(oid, xyz, 1, radius)
        return oid

    def add_transition(self, src: str, action: str, dst: str, count: int = 1) -> None:
        """Record ``delta(src, action) = dst``; repeated transitions increase ``count``."""
        self._check_state(src)
        self._check_state(dst)
        if action not in ACTIONS:
            raise ValueError(f"action must be one of {', '.join(ACTIONS)}, got {action!r}")
        if int(count) < 1:
            raise ValueError(f"a transition count must be >= 1, got {count!r}")
        if self.graph.has_edge(src, dst, action):
            self.graph.edges[src, dst, action]["count"] += int(count)
        else:
            self.graph.add_edge(src, dst, key=action, kind="transition", count=int(count))

    # ------------------------------------------------------------------ frames
    def transform(self, T) -> AbstractModel:
        """Apply the SE(2) transform ``T`` (``(x, y, theta)`` or 3×3) to every pose and position.

        Modifies the model in place and returns it.
        """
        T = se2.as_pose(T)
        for _, d in self.graph.nodes(data=True):
            if d["kind"] == "state":
                d["x"], d["y"], d["theta"] = se2.compose(T, (d["x"], d["y"], d["theta"]))
            else:
                d["x"], d["y"] = se2.apply_to_point(T, d["x"], d["y"])
        for *_, d in self.graph.edges(data=True):
            if d["kind"] == "sees":
                ox, oy, oz = d["obs"]
                d["obs"] = (*se2.apply_to_point(T, ox, oy), oz)
        self._init_counters()
        return self

    # ------------------------------------------------------------------ io & comparison
    def save(self, path: str | os.PathLike[str]) -> None:
        """Write the model to ``path`` as GraphML, atomically (see :mod:`kgnav.memory.graphml`)."""
        write_model(self, path)

    @classmethod
    def load(cls, path: str | os.PathLike[str], *, max_bytes: int | None = None) -> AbstractModel:
        """Read a model written by :meth:`save`; raises :class:`kgnav.errors.ModelFileError`.

        ``max_bytes`` bounds the file size (see :func:`kgnav.memory.graphml.read_graph`).
        """
        return cls.from_graph(read_graph(path, max_bytes=max_bytes))

    @classmethod
    def from_graph(cls, graph: nx.MultiDiGraph) -> AbstractModel:
        """Wrap a graph that follows the schema (no validation: see :mod:`kgnav.memory.graphml`)."""
        m = cls.__new__(cls)
        m.graph = graph
        m._init_counters()
        return m

    def copy(self) -> AbstractModel:
        """A deep copy (feature arrays are shared: they are read-only)."""
        return AbstractModel.from_graph(self.graph.copy())

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, AbstractModel):
            return NotImplemented
        return graphs_equal(self.graph, other.graph)

    __hash__ = None  # mutable

    def __repr__(self) -> str:
        return (
            f"AbstractModel(model_id={self.model_id!r}, states={self.n_states}, "
            f"objects={self.n_objects}, transitions={self.n_transitions}, "
            f"feature_dim={self.feature_dim})"
        )


def _attrs_equal(a: dict, b: dict) -> bool:
    if a.keys() != b.keys():
        return False
    for k, va in a.items():
        vb = b[k]
        if isinstance(va, np.ndarray) or isinstance(vb, np.ndarray):
            if not (
                isinstance(va, np.ndarray)
                and isinstance(vb, np.ndarray)
                and va.dtype == vb.dtype
                and va.tobytes() == vb.tobytes()
            ):
                return False
        elif type(va) is not type(vb) or va != vb:
            return False
    return True


def graphs_equal(g: nx.MultiDiGraph, h: nx.MultiDiGraph) -> bool:
    """Exact equality of two model graphs: attributes, node ids, edge keys, features bit for bit."""
    if not _attrs_equal(g.graph, h.graph) or g.number_of_nodes() != h.number_of_nodes():
        return False
    for n, d in g.nodes(data=True):
        if n not in h or not _attrs_equal(d, h.nodes[n]):
            return False
    if g.number_of_edges() != h.number_of_edges():
        return False
    for u, v, k, d in g.edges(keys=True, data=True):
        if not h.has_edge(u, v, k) or not _attrs_equal(d, h.edges[u, v, k]):
            return False
    return True
