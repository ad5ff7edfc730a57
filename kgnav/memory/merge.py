"""Merge one Abstract Model into another through an anchor pair of matching states.

The source is mapped into the target frame by ``T = pose(target_state) ∘ pose(source_state)⁻¹``
(DESIGN.md §4), then:

* states are unioned; a source state coincident with a target state (pose and features within the
  target's tolerances) becomes that state;
* objects are re-associated: a source object joins the nearest target object of its class within
  ``object_radius`` (positions averaged by observation count, views counted per distinct state);
* transitions are unioned, counts added;
* provenance is kept: every node lists in ``origin`` the recorded nodes (``model_id/node_id``)
  folded into it, and the result lists the merged models in ``merged_from``.

Nodes are matched by ``origin`` first, so merging observations that are already in the target adds
nothing: merging a model with itself through an identity anchor returns an equal model, and so
does merging a model again into the result of an earlier merge.

>>> import numpy as np
>>> from kgnav import AbstractModel
>>> a = AbstractModel(feature_dim=2, model_id="a"); b = AbstractModel(feature_dim=2, model_id="b")
>>> ta = a.add_state(np.array([1.0, 0.0]), pose=(2.0, 0.0, 0.0))
>>> sb = b.add_state(np.array([1.0, 0.0]), pose=(0.0, 0.0, 0.0))
>>> sb2 = b.add_state(np.array([0.0, 1.0]), pose=(1.0, 0.0, 0.0))
>>> m = merge(a, b, anchor=(ta, sb))
>>> m.n_states, m.pose("s1")
(2, (3.0, 0.0, 0.0))
"""

from __future__ import annotations

import json

import numpy as np

from kgnav.common import se2
from kgnav.errors import KgnavError
from kgnav.memory.model import SEES, AbstractModel
from kgnav.memory.relocator import unit_rows


def _check_compatible(target: AbstractModel, source: AbstractModel) -> None:
    if target.feature_dim != source.feature_dim:
        raise KgnavError(
            f"cannot merge model {source.model_id!r} (feature_dim {source.feature_dim}) into "
            f"{target.model_id!r} (feature_dim {target.feature_dim})"
        )
    if target.extractor != source.extractor:
        raise KgnavError(
            f"cannot merge model {source.model_id!r} (features from {source.extractor!r}) into "
            f"{target.model_id!r} (features from {target.extractor!r})"
        )


def best_anchor(
    target: AbstractModel, source: AbstractModel, chunk: int = 4096
) -> tuple[str, str, float]:
    """The pair ``(target_state, source_state, cosine_distance)`` with the closest features."""
    t_ids, t_f = target.state_features()
    s_ids, s_f = source.state_features()
    if not t_ids or not s_ids:
        raise KgnavError("cannot choose an anchor: a model has no states")
    t_n, s_n = unit_rows(t_f), unit_rows(s_f)
    best = (-np.inf, 0, 0)
    for start in range(0, len(s_ids), chunk):
        sim = t_n @ s_n[start : start + chunk].T
        i, j = np.unravel_index(int(np.argmax(sim)), sim.shape)
        if sim[i, j] > best[0]:
            best = (float(sim[i, j]), int(i), start + int(j))
    return t_ids[best[1]], s_ids[best[2]], 1.0 - best[0]


def _has_ranges(m: AbstractModel) -> bool:
    return any("ranges" in m.graph.nodes[s] for s in m.states())


def merge(
    target: AbstractModel,
    source: AbstractModel,
    anchor: tuple[str, str] | None = None,
    *,
    transform: se2.Pose | None = None,
) -> AbstractModel:
    """Return a new model: ``target`` plus ``source`` mapped into the target frame.

    Give either ``anchor=(target_state, source_state)`` or an explicit ``transform``; with
    neither, the source is assumed to be in the target frame already. The inputs are not modified.
    The result keeps the target's id, frame, tolerances, relocation threshold (the source's when
    the target records none) and vocabulary (extended by any class only the source knows).
    """
    _check_compatible(target, source)
    if anchor is not None and transform is not None:
        raise ValueError("give anchor or transform, not both")
    if anchor is not None:
        t_state, s_state = anchor
        T = se2.anchor_transform(target.pose(t_state), source.pose(s_state))
    else:
        T = se2.as_pose(transform) if transform is not None else se2.IDENTITY

    out = target.copy()
    src = source.copy().transform(T)
    if out.scan is None and src.scan is not None and not _has_ranges(out):
        out.graph.graph["scan"] = src.graph.graph["scan"]
    if out.relocation_threshold is None:  # the target's stands; else the source's is all we know
        out.relocation_threshold = src.relocation_threshold
    keep_ranges = src.scan is not None and src.scan == out.scan  # else another camera's
    extra = [c for c in src.classes if c not in out.classes]
    if extra:
        out.graph.graph["classes"] = ",".join(out.classes + tuple(extra))

    g = out.graph
    node_map: dict[str, str] = {}
    same_record: set[str] = set()  # source states that are the very observation already in target

    for s, d in src.graph.nodes(data=True):
        if d["kind"] != "state":
            continue
        hit = out.known_node(d["origin"])
        if hit is not None:
            same_record.add(s)
        else:
            pose = (d["x"], d["y"], d["theta"])
            hit = out.find_state(pose, d["features"])
            if hit is None:
                hit = out._new_state_node(
                    pose, d["features"], episode=d["episode"], step=d["step"], origin=d["origin"],
                    ranges=d.get("ranges") if keep_ranges else None,
                )
        out._add_origins(hit, d["origin"])
        node_map[s] = hit

    for o, d in src.graph.nodes(data=True):
        if d["kind"] != "object":
            continue
        hit = out.known_node(d["origin"])
        if hit is None:
            xyz = (d["x"], d["y"], d["z"])
            hit = out._nearest_object(d["cls"], d["x"], d["y"], d["radius"])
            if hit is None:
                hit = out._new_object_node(d["cls"], xyz, d["n_obs"], d["origin"], d["radius"])
            else:
                out._add_origins(hit, d["origin"])
                out._absorb_into_object(hit, xyz, d["n_obs"], d["radius"])
                hit = out.resolve(hit)
        out._add_origins(hit, d["origin"])
        node_map[o] = hit

    for u, v, k, d in src.graph.edges(keys=True, data=True):
        mu, mv = out.resolve(node_map[u]), out.resolve(node_map[v])
        if k == SEES:
            out._link_view(mu, mv, {a: val for a, val in d.items() if a != "kind"})
        elif g.has_edge(mu, mv, k) and u in same_record and v in same_record:
            e = g.edges[mu, mv, k]
            e["count"] = max(e["count"], d["count"])
        else:
            out.add_transition(mu, k, mv, count=d["count"])

    lineage = out.merged_from
    for mid in [source.model_id, *source.merged_from]:
        if mid != out.model_id and mid not in lineage:
            lineage.append(mid)
    g.graph["merged_from"] = json.dumps(lineage)
    out.add_loop_closures(src.loop_closures)
    out.add_odometry(src.odometry)
    episodes = out.episodes
    episodes += [e for e in src.episodes if e not in episodes]
    g.graph["episodes"] = json.dumps(episodes)
    return out
