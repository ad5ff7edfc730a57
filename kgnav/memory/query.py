"""Questions an agent (or a person) asks an Abstract Model.

* :func:`ranked_objects` — objects of a class ranked by the number of distinct states that see them;
* :func:`goal_point` — the paper's goal choice: the closest, to a given position, among the five
  most-seen objects of the goal class (seen from many states ⇒ unlikely a segmenter false positive);
* :func:`visible_from` — what a state sees; :func:`class_inventory` — which classes a model holds;
* :func:`action_path` — the shortest action sequence between two states along transitions;
* :func:`occupancy` / :func:`known_free` — what the model's states saw of the floor (from their
  range profiles, :mod:`kgnav.memory.geometry`): is this point known to be free?
* :func:`trusted_objects` — objects of a class with their evidence and belief
  (:mod:`kgnav.memory.evidence`).

And of a whole store at once (:mod:`kgnav.memory.store_query`; Cypher on a graph database):
:func:`find_objects`, :func:`models_with_classes_near`, :func:`states_that_saw`,
:func:`class_inventories`, :func:`objects_near_state`.

A class outside the model's vocabulary raises :class:`~kgnav.errors.UnknownClassError`; a class in
the vocabulary that the model has not seen simply has no objects.

>>> import numpy as np
>>> from kgnav import AbstractModel, Detection
>>> m = AbstractModel(feature_dim=2, model_id="q")
>>> chair = Detection("chair", (2.0, 0.0, 0.5))
>>> s0 = m.add_state(np.array([1.0, 0.0]), (0, 0, 0), [chair])
>>> s1 = m.add_state(np.array([0.0, 1.0]), (0.25, 0, 0), [chair])
>>> m.add_transition(s0, "move_forward", s1)
>>> g = goal_point(m, "chair", near=(0.0, 0.0))
>>> g.id, g.position, g.n_views
('o0', (2.0, 0.0, 0.5), 2)
>>> action_path(m, s0, s1)
['move_forward']
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Collection

import networkx as nx

from kgnav.memory.constants import JOIN_EPISODE
from kgnav.memory.model import SEES, AbstractModel, ObjectInfo
from kgnav.memory.store_query import (  # noqa: F401 - the store-wide questions, asked here too
    StoredObject,
    class_inventories,
    find_objects,
    models_with_classes_near,
    objects_near_state,
    states_that_saw,
)

#: The paper ranks candidate goal objects by views and picks the closest of this many.
TOP_K = 5


def ranked_objects(model: AbstractModel, cls: str) -> list[ObjectInfo]:
    """Objects of ``cls``, most-seen first (ties: more observations, then id)."""
    model.check_class(cls)
    objs = [model.object_info(o) for o in model._index.by_class.get(cls, ())]
    return sorted(objs, key=lambda o: (-o.n_views, -o.n_obs, _id_order(o.id)))


def _id_order(node: str) -> tuple[int, str]:
    return (int(node[1:]), node) if node[1:].isdigit() else (math.inf, node)


def goal_point(
    model: AbstractModel,
    cls: str,
    near: tuple[float, float] = (0.0, 0.0),
    top_k: int = TOP_K,
    exclude: Collection[str] = (),
    min_views: int = 1,
) -> ObjectInfo | None:
    """The object to head for: closest to ``near`` among the ``top_k`` most-seen of ``cls``.

    Objects in ``exclude`` (ids the caller has ruled out) or seen from fewer than ``min_views``
    states are skipped. Returns ``None`` when no candidate is left.
    """
    ranked = ranked_objects(model, cls)
    top = [o for o in ranked if o.id not in exclude and o.n_views >= min_views][:top_k]
    if not top:
        return None
    x, y = float(near[0]), float(near[1])
    return min(top, key=lambda o: (math.hypot(o.position[0] - x, o.position[1] - y), o.id))


def visible_from(model: AbstractModel, state: str) -> list[ObjectInfo]:
    """Objects seen from ``state`` (``C_s`` with positions), nearest view first."""
    model._check_state(state)
    g = model.graph
    edges = g.out_edges(state, keys=True, data=True)
    views = [(d["distance"], o) for _, o, k, d in edges if k == SEES]
    return [model.object_info(o) for _, o in sorted(views)]


def visible_classes(model: AbstractModel, state: str) -> list[str]:
    """The distinct classes seen from ``state``, sorted."""
    return sorted({o.cls for o in visible_from(model, state)})


def class_inventory(model: AbstractModel) -> dict[str, dict[str, int]]:
    """Per class present: number of objects, total views and the most views of one object."""
    out: dict[str, dict[str, int]] = {}
    for cls, objs in sorted(model._index.by_class.items()):
        if not objs:
            continue
        views = [model.graph.nodes[o]["n_views"] for o in objs]
        out[cls] = {"objects": len(objs), "views": sum(views), "max_views": max(views)}
    return out


def seen_classes(model: AbstractModel) -> Counter:
    """How many states see each class (a state counts once per class)."""
    counts: Counter = Counter()
    for s in model.states():
        counts.update(visible_classes(model, s))
    return counts


def _transition_graph(model: AbstractModel) -> nx.DiGraph:
    """States joined by transitions; parallel actions collapsed to the most frequent one."""
    g = nx.DiGraph()
    g.add_nodes_from(model.states())
    for u, v, k, d in model.graph.edges(keys=True, data=True):
        if d["kind"] != "transition":
            continue
        best = g.get_edge_data(u, v)
        if best is None or (-d["count"], k) < (-best["count"], best["action"]):
            g.add_edge(u, v, action=k, count=d["count"])
    return g


def action_path(model: AbstractModel, start: str, goal: str) -> list[str] | None:
    """Fewest actions leading from ``start`` to ``goal`` along recorded transitions.

    Returns the action names (``[]`` when ``start == goal``) or ``None`` if no path exists.
    """
    model._check_state(start)
    model._check_state(goal)
    g = _transition_graph(model)
    try:
        nodes = nx.shortest_path(g, start, goal)
    except nx.NetworkXNoPath:
        return None
    return [g.edges[u, v]["action"] for u, v in zip(nodes, nodes[1:], strict=False)]


def summary(model: AbstractModel) -> dict:
    """A JSON-ready description of the model (what ``kgnav inspect`` prints)."""
    xs = [d["x"] for _, d in model.graph.nodes(data=True) if d["kind"] == "state"]
    ys = [d["y"] for _, d in model.graph.nodes(data=True) if d["kind"] == "state"]
    actions = Counter(
        k for _, _, k, d in model.graph.edges(keys=True, data=True) if d["kind"] == "transition"
    )
    closures = model.loop_closures  # parsed once: a JSON list held in the graph attributes
    return {
        "model_id": model.model_id,
        "schema_version": model.graph.graph["kgnav_schema"],
        "feature_dim": model.feature_dim,
        "extractor": model.extractor,
        "relocation_threshold": model.relocation_threshold,
        "states": model.n_states,
        "objects": model.n_objects,
        "transitions": model.n_transitions,
        "views": sum(1 for _, _, k in model.graph.edges(keys=True) if k == SEES),
        "actions": dict(sorted(actions.items())),
        "episodes": model.episodes,
        "merged_from": model.merged_from,
        "loop_closures": {"kept": sum(c["kept"] for c in closures),
                          "rejected": sum(not c["kept"] for c in closures),
                          "linked": sum(c["kept"] and "to" in c for c in closures),
                          "joins": sum(c["kept"] and c["episode"] == JOIN_EPISODE
                                       for c in closures)},
        "odometry_states": len(model.odometry),
        "extent": (
            {"x": [min(xs), max(xs)], "y": [min(ys), max(ys)]} if xs else None
        ),
        "classes": class_inventory(model),
    }


def occupancy(model: AbstractModel, resolution: float = 0.05):
    """The :class:`~kgnav.memory.geometry.OccupancyGrid` of the model's range profiles (model
    frame), or None when its states carry none."""
    from kgnav.memory.geometry import occupancy_from_scans

    scan = model.scan
    g = model.graph
    poses, ranges = [], []
    for s in model.states():
        d = g.nodes[s]
        if "ranges" in d:
            poses.append((d["x"], d["y"], d["theta"]))
            ranges.append(d["ranges"])
    if scan is None or not poses:
        return None
    return occupancy_from_scans(scan, poses, ranges, resolution)


def known_free(model: AbstractModel, x: float, y: float, grid=None) -> bool:
    """Whether some state of the model saw the point (x, y) as free floor (no obstacle there).
    Pass ``grid`` (:func:`occupancy`) when asking many times."""
    grid = grid if grid is not None else occupancy(model)
    return grid is not None and grid.state_at(x, y) == "free"


def trusted_objects(model: AbstractModel, cls: str, min_belief: float = 0.0) -> list[dict]:
    """Objects of ``cls`` with their evidence and belief, most believed first."""
    from kgnav.memory.evidence import belief, object_evidence

    objs = ranked_objects(model, cls)
    ev = object_evidence(model, [o.id for o in objs])
    rows = [{"id": o.id, "position": o.position, "belief": round(belief(ev[o.id]), 4),
             "views": ev[o.id].n_views, "episodes": ev[o.id].n_episodes,
             "missed": ev[o.id].n_missed, "score": round(ev[o.id].score, 3)} for o in objs]
    rows = [r for r in rows if r["belief"] >= min_belief]
    return sorted(rows, key=lambda r: (-r["belief"], -r["views"], _id_order(r["id"])))
