"""Drift correction: an episode's pose chain bent onto a stored model by verified loop closures.

With a real robot's odometry an episode's poses drift with the distance it drives, so one rigid
transform (episode frame -> model frame) cannot lay the whole episode on the stored model: the
start fits and the end is off by the drift, and a merge would bend the memory. Each stretch of
the episode that verifies against the stored geometry on its own is a **loop closure**: an
:class:`Anchor` saying "chain node ``i`` is at ``pose`` in the model frame".

:func:`correct` then

1. keeps the largest set of anchors that agree pairwise with the odometry between them
   (pairwise consistency maximisation, as Kimera-RPGO does: two anchors are consistent when the
   relative pose they imply matches the odometry's within a bound that grows with the distance
   driven between them; the inliers are the maximum clique of the consistency graph, found
   with networkx), so that a wrong closure (a look-alike room, a rotated twin) cannot pull the
   chain;
2. optimises the chain as a pose graph with GTSAM (odometry between-factors whose noise grows
   with the motion, the kept anchors as robust priors) and returns every node's pose in the
   model frame, with the rejected anchors named in the :class:`Correction`.

:func:`bend` moves a model's states to corrected poses, and its objects with the states that saw
them.

:func:`straighten` optimises a whole stored model again: every episode that built it keeps its
raw odometry (:attr:`~kgnav.memory.model.AbstractModel.odometry`) and every kept loop closure
its link to the stored state it was measured against, so a merge solves one pose graph over all
of them, and each new episode's odometry straightens the model a little instead of being bent
onto it.

>>> chain = [(0.25 * i, 0.0, 0.0) for i in range(41)]         # odometry: a straight line
>>> truth = [(0.25 * i, 0.01 * i, 0.0) for i in range(41)]     # it veered 1 cm a step
>>> wrong = Anchor(30, (7.5, 1.3, 1.57))                        # a look-alike room, turned
>>> c = correct(chain, [Anchor(0, truth[0]), Anchor(40, truth[40]), wrong], DriftModel())
>>> c.rejected == [wrong], abs(c.poses[40][1] - truth[40][1]) < 0.05
(True, True)
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import networkx as nx
import numpy as np

from kgnav.common import se2

__all__ = ["Anchor", "Correction", "DriftModel", "bend", "consistent", "correct", "straighten",
           "travelled"]

# chi-square, 3 degrees of freedom, 99 %: the pairwise consistency bound (Mahalanobis squared)
CHI2_3_99 = 11.345


@dataclass(frozen=True)
class DriftModel:
    """How uncertain the odometry between two chain nodes is. Odometry errors are a random
    walk: their variance grows linearly with the distance driven and the angle turned, and a
    heading error accrued on the way turns into a lateral error that grows with the distance
    still driven after it.

    ``xy``: position standard deviation (m) after one metre driven; ``theta_per_m``: heading
    standard deviation (rad) after one metre driven; ``theta_per_rad``: after one radian
    turned; ``theta_bias``: a systematic heading error (rad per metre driven; a wheel a little
    larger than the other), which grows linearly rather than as a random walk; floors for
    nodes that did not move. ``anchor_xy`` / ``anchor_theta``: how
    precisely a verified scan alignment places a node. The defaults match
    ``--noise locobot``'s odometry in order of magnitude (a few cm and about a degree per
    0.25 m move, two degrees per 30-degree turn)."""

    xy: float = 0.04
    theta_per_m: float = 0.035
    theta_per_rad: float = 0.05
    theta_bias: float = math.radians(1.0)
    floor_xy: float = 0.01
    floor_theta: float = math.radians(0.5)
    anchor_xy: float = 0.05
    anchor_theta: float = math.radians(2.0)

    def sigmas(self, distance: float, turned: float) -> tuple[float, float]:
        """(sigma_xy, sigma_theta) of the odometry over ``distance`` m and ``turned`` rad."""
        s_theta = math.sqrt(self.floor_theta ** 2 + self.theta_per_m ** 2 * distance
                            + self.theta_per_rad ** 2 * turned) + self.theta_bias * distance
        var_theta = s_theta ** 2
        # a heading random walk integrated over the distance: variance theta * d^2 / 3
        var_xy = self.floor_xy ** 2 + self.xy ** 2 * distance + var_theta * distance ** 2 / 3
        return math.sqrt(var_xy), math.sqrt(var_theta)


@dataclass(frozen=True)
class Anchor:
    """A loop closure: chain node ``node`` lies at ``pose`` in the target (model) frame;
    ``source`` says what found it (for the record)."""

    node: int
    pose: tuple[float, float, float]
    source: str = "scan"


@dataclass
class Correction:
    """The outcome of :func:`correct`: every chain node's pose in the model frame, the anchors
    kept and those rejected as inconsistent, and how far the correction moved the nodes
    relative to the chain mapped rigidly by its first kept anchor."""

    poses: list[tuple[float, float, float]]
    kept: list[Anchor] = field(default_factory=list)
    rejected: list[Anchor] = field(default_factory=list)
    iterations: int = 0

    @property
    def summary(self) -> dict:
        return {"anchors": len(self.kept) + len(self.rejected), "kept": len(self.kept),
                "rejected": len(self.rejected)}


def travelled(chain: Sequence) -> tuple[np.ndarray, np.ndarray]:
    """Cumulative distance driven and angle turned along ``chain`` (both (n,))."""
    p = np.asarray(chain, np.float64).reshape(-1, 3)
    step = np.hypot(np.diff(p[:, 0]), np.diff(p[:, 1]))
    turn = np.abs([se2.angle_diff(b, a) for a, b in zip(p[:-1, 2], p[1:, 2], strict=True)])
    return (np.concatenate([[0.0], np.cumsum(step)]),
            np.concatenate([[0.0], np.cumsum(turn)]) if len(p) else np.zeros(0))


def _relative(a, b) -> tuple[float, float, float]:
    return se2.compose(se2.inverse(a), b)


def consistent(chain: Sequence, anchors: Sequence[Anchor], drift: DriftModel,
               bound: float = CHI2_3_99) -> list[int]:
    """Indices of the largest set of ``anchors`` pairwise consistent with the odometry
    ``chain`` (pairwise consistency maximisation). An anchor consistent with none of the others
    is kept only when it is the only one."""
    n = len(anchors)
    if n <= 1:
        return list(range(n))
    dist, turn = travelled(chain)
    g = nx.Graph()
    g.add_nodes_from(range(n))
    for a in range(n):
        for b in range(a + 1, n):
            i, k = anchors[a].node, anchors[b].node
            odo = _relative(chain[i], chain[k])
            seen = _relative(anchors[a].pose, anchors[b].pose)
            e = _relative(odo, seen)
            s_xy, s_th = drift.sigmas(abs(dist[k] - dist[i]), abs(turn[k] - turn[i]))
            s_xy = math.hypot(s_xy, math.sqrt(2) * drift.anchor_xy)
            s_th = math.hypot(s_th, math.sqrt(2) * drift.anchor_theta)
            m2 = (e[0] ** 2 + e[1] ** 2) / s_xy ** 2 + (e[2] / s_th) ** 2
            if m2 <= bound:
                g.add_edge(a, b)
    clique, _ = nx.max_weight_clique(g, weight=None)
    if len(clique) <= 1:
        # no two anchors agree: none can be trusted over the others
        return []
    return sorted(clique)


def correct(chain: Sequence, anchors: Sequence[Anchor], drift: DriftModel,
            bound: float = CHI2_3_99, max_iterations: int = 50) -> Correction | None:
    """The ``chain`` (odometry poses, any frame) laid on the model frame by the consistent
    ``anchors``; None when no anchor can be trusted (see :func:`consistent`).

    One kept anchor moves the chain rigidly; more bend it where the odometry drifted."""
    import gtsam  # a heavy import, needed only when an episode is corrected

    chain = [tuple(float(v) for v in p) for p in chain]
    for a in anchors:
        if not 0 <= a.node < len(chain):
            raise ValueError(f"anchor node {a.node} outside the chain of {len(chain)} poses")
    keep = consistent(chain, anchors, drift, bound)
    if not keep:
        return None
    kept = [anchors[i] for i in keep]
    rejected = [a for i, a in enumerate(anchors) if i not in set(keep)]
    first = kept[0]
    T = se2.compose(first.pose, se2.inverse(chain[first.node]))
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    for i, p in enumerate(chain):
        values.insert(i, gtsam.Pose2(*se2.compose(T, p)))
    for i in range(len(chain) - 1):
        d = _relative(chain[i], chain[i + 1])
        s_xy, s_th = drift.sigmas(math.hypot(d[0], d[1]), abs(d[2]))
        noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([s_xy, s_xy, s_th]))
        graph.add(gtsam.BetweenFactorPose2(i, i + 1, gtsam.Pose2(*d), noise))
    base = gtsam.noiseModel.Diagonal.Sigmas(
        np.array([drift.anchor_xy, drift.anchor_xy, drift.anchor_theta]))
    # robust even after the consistency check: a closure a few sigma off should bend little
    robust = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(1.345),
                                            base)
    for a in kept:
        graph.add(gtsam.PriorFactorPose2(a.node, gtsam.Pose2(*a.pose), robust))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(int(max_iterations))
    opt = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    result = opt.optimize()
    poses = []
    for i in range(len(chain)):
        p = result.atPose2(i)
        poses.append((float(p.x()), float(p.y()), float(se2.wrap_angle(p.theta()))))
    return Correction(poses, kept, rejected, int(opt.iterations()))


def bend(model, poses: Mapping[str, tuple[float, float, float]]):
    """Move ``model``'s states to ``poses`` (state id -> pose, same frame; states not named stay)
    and every object with the states that saw it: each view's observed position moves rigidly
    with its state, and an object by the mean of its views' moves. Changes ``model`` in place
    and returns it; a rigid ``poses`` (every state moved by one transform) equals
    :meth:`~kgnav.memory.model.AbstractModel.transform`."""
    g = model.graph
    moves: dict[str, tuple[float, float, float]] = {}
    for sid, new in poses.items():
        d = g.nodes[sid]
        old = (d["x"], d["y"], d["theta"])
        new = se2.as_pose(new)
        moves[sid] = se2.compose(new, se2.inverse(old))
        d["x"], d["y"], d["theta"] = float(new[0]), float(new[1]), se2.wrap_angle(new[2])
    shift: dict[str, list] = {}
    for sid, oid, d in g.edges(data=True):
        if d.get("kind") != "sees" or sid not in moves:
            continue
        ox, oy, oz = d["obs"]
        nx_, ny_ = se2.apply_to_point(moves[sid], ox, oy)
        d["obs"] = (nx_, ny_, oz)
        shift.setdefault(oid, []).append((nx_ - ox, ny_ - oy))
    for oid, ds in shift.items():
        # views of states that did not move count as zero moves
        views = sum(1 for _, _, k in g.in_edges(oid, keys=True) if k == "sees")
        dx, dy = np.sum(ds, axis=0) / max(views, len(ds))
        d = g.nodes[oid]
        d["x"], d["y"] = float(d["x"] + dx), float(d["y"] + dy)
    model._init_counters()  # the spatial index follows the moved nodes
    return model


def straighten(model, drift: DriftModel, rejected: list | None = None,
               bound: float = CHI2_3_99, max_iterations: int = 50
               ) -> dict[str, tuple[float, float, float]]:
    """The ``model``'s state poses optimised jointly over everything it recorded: each
    episode's raw odometry between its consecutive recorded states (a between-factor whose
    noise grows with the distance driven and the angle turned between them, ``drift``) and
    each kept loop closure's link (the closing state's pose relative to the stored state it
    was aligned on, a robust between-factor at the closure's precision). States that two
    episodes share (fused on merging) join their chains. Every connected part of the graph
    keeps its frame: its states without odometry stay where they are, and a part with none
    keeps its oldest state. A link that the optimised poses still contradict beyond
    ``bound`` (Mahalanobis squared) is dropped and the graph solved again without it (at
    most three rounds); dropped links are appended to ``rejected`` when given. Returns the
    states that moved (id -> pose, the model's frame; empty when the model recorded nothing
    to optimise); :func:`bend` applies them.

    >>> from kgnav import AbstractModel
    >>> m = AbstractModel(feature_dim=1, model_id="m")
    >>> f = np.ones(1, np.float32)
    >>> a, b = (m.add_state(f, (x, 0.0, 0.0), episode=0) for x in (0.0, 1.0))
    >>> m.add_odometry({"m/s0": [0, 0, 0, 0, 0, 0], "m/s1": [1, 1.2, 0, 0, 1.2, 0]})
    >>> round(straighten(m, DriftModel())["s1"][0], 3)    # the odometry said 1.2 m
    1.2
    """
    import gtsam

    odometry = model.odometry
    links = [c for c in model.loop_closures if c.get("kept") and "to" in c]
    if not odometry and not links:
        return {}
    g = model.graph

    def state_of(origin: str) -> str | None:
        s = model.known_node(origin)
        return s if s is not None and g.nodes[s]["kind"] == "state" else None

    chains: dict[str, list] = {}
    for origin, rec in odometry.items():
        sid = state_of(origin)
        if sid is not None:
            chains.setdefault(origin.rsplit("/", 1)[0], []).append((rec[0], sid, rec))
    factors = []  # (a, b, relative pose of b in a's frame, sigma_xy, sigma_theta, link or None)
    for items in chains.values():
        items.sort(key=lambda t: t[0])
        for (_, sa, ra), (_, sb, rb) in zip(items[:-1], items[1:], strict=True):
            if sa == sb:
                continue
            s_xy, s_th = drift.sigmas(abs(rb[4] - ra[4]), abs(rb[5] - ra[5]))
            factors.append((sa, sb, _relative(ra[1:4], rb[1:4]), s_xy, s_th, None))
    for c in links:
        sa, sb = state_of(c["to"]), state_of(c["state"])
        if sa is not None and sb is not None and sa != sb:
            factors.append((sa, sb, tuple(c["rel"]), drift.anchor_xy, drift.anchor_theta, c))
    if not factors:
        return {}
    recorded = {sid for items in chains.values() for _, sid, _ in items}
    start = {sid: (d["x"], d["y"], d["theta"]) for sid, d in
             ((s, g.nodes[s]) for f in factors for s in f[:2])}
    for _ in range(3):
        poses = _solve(gtsam, factors, start, recorded, max_iterations)
        worst = []
        for f in factors:
            if f[5] is not None:
                e = _relative(f[2], _relative(poses[f[0]], poses[f[1]]))
                m2 = (e[0] ** 2 + e[1] ** 2) / f[3] ** 2 + (e[2] / f[4]) ** 2
                if m2 > bound:
                    worst.append(f)
        if not worst:
            break
        drop = {id(f) for f in worst}
        factors = [f for f in factors if id(f) not in drop]
        if rejected is not None:
            rejected.extend(f[5] for f in worst)
    out = {}
    for sid, new in poses.items():
        old = start[sid]
        # below a micrometre is the solver's rounding, not a correction
        if (abs(new[0] - old[0]) > 1e-6 or abs(new[1] - old[1]) > 1e-6
                or se2.angle_diff(new[2], old[2]) > 1e-6):
            out[sid] = new
    return out


def _solve(gtsam, factors, start, recorded, max_iterations) -> dict:
    """The pose graph of ``factors`` solved from the ``start`` poses; every connected part
    held by its states without odometry, else by its oldest state."""
    parts = nx.Graph()
    parts.add_nodes_from(start)
    parts.add_edges_from((f[0], f[1]) for f in factors)
    key = {sid: i for i, sid in enumerate(parts.nodes)}
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    for sid, i in key.items():
        values.insert(i, gtsam.Pose2(*start[sid]))
    huber = gtsam.noiseModel.mEstimator.Huber.Create(1.345)
    for a, b, rel, s_xy, s_th, link in factors:
        noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([s_xy, s_xy, s_th]))
        if link is not None:
            noise = gtsam.noiseModel.Robust.Create(huber, noise)
        graph.add(gtsam.BetweenFactorPose2(key[a], key[b], gtsam.Pose2(*rel), noise))
    fixed = gtsam.noiseModel.Diagonal.Sigmas(np.array([1e-3, 1e-3, 1e-4]))
    for part in nx.connected_components(parts):
        hold = [s for s in part if s not in recorded] or [min(part, key=_state_order)]
        for sid in hold:
            graph.add(gtsam.PriorFactorPose2(key[sid], gtsam.Pose2(*start[sid]), fixed))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(int(max_iterations))
    result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    out = {}
    for sid, i in key.items():
        p = result.atPose2(i)
        out[sid] = (float(p.x()), float(p.y()), se2.wrap_angle(float(p.theta())))
    return out


def _state_order(sid: str) -> int:
    return int(sid[1:]) if sid[1:].isdigit() else 0
