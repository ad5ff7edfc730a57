"""Questions asked of a whole store at once: every model, one answer.

Each function takes a :class:`~kgnav.memory.store.ModelStore`. On a graph database
(:mod:`kgnav.memory.graphdb`) it runs as one Cypher query and loads no model; on a directory of
GraphML files it is a networkx computation over the models, loaded one at a time. Both give the
same answer, in the same order (a property test compares them on random stores). Models that do
not load are left out, as ``load_all`` leaves them out.

>>> import tempfile, os, numpy as np
>>> from kgnav import AbstractModel, Detection, ModelStore
>>> m = AbstractModel(feature_dim=2, model_id="house-1")
>>> s = m.add_state(np.ones(2), pose=(0, 0, 0), detections=[
...     Detection("bed", (1.0, 0.0, 0.5), (0, 0, 9, 9), 1.0),
...     Detection("sofa", (2.5, 0.0, 0.4), (10, 0, 19, 9), 2.5)])
>>> for root in (tempfile.mkdtemp(), os.path.join(tempfile.mkdtemp(), "m.lbug")):
...     store = ModelStore(root); _ = store.save(m)
...     print(models_with_classes_near(store, "bed", "sofa", 2.0), class_inventories(store))
['house-1'] {'house-1': {'bed': 1, 'sofa': 1}}
['house-1'] {'house-1': {'bed': 1, 'sofa': 1}}
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

from kgnav.memory.constants import SEES
from kgnav.memory.model import AbstractModel

__all__ = [
    "StoredObject",
    "class_inventories",
    "find_objects",
    "models_with_classes_near",
    "objects_near_state",
    "states_that_saw",
]


@dataclass(frozen=True)
class StoredObject:
    """An object of a stored model with its evidence: how many states saw it (``n_views``),
    how many detections it merged (``n_obs``) and their summed confidence (``score``)."""

    model_id: str
    id: str
    cls: str
    position: tuple[float, float, float]
    n_views: int
    n_obs: int
    score: float


def _db(store):
    return store if hasattr(store, "cypher") else None


def _models(store) -> Iterator[AbstractModel]:
    for _, model, _ in store.each():
        if model is not None:
            yield model


def _object_nodes(m: AbstractModel) -> Iterator[tuple[str, dict]]:
    for n, d in m.graph.nodes(data=True):
        if d["kind"] == "object":
            yield n, d


def _sort_objects(objs: list[StoredObject]) -> list[StoredObject]:
    return sorted(objs, key=lambda o: (-o.n_views, o.model_id, o.id))


def find_objects(store, cls: str, min_views: int = 1) -> list[StoredObject]:
    """Every object of class ``cls`` in every model seen from at least ``min_views`` states,
    most seen first (ties by model and object id)."""
    if (db := _db(store)) is not None:
        _, rows = db.cypher(
            "MATCH (o:Object) WHERE o.cls = $cls AND o.n_views >= $v "
            "RETURN o.model, o.id, o.cls, o.x, o.y, o.z, o.n_views, o.n_obs, o.score",
            {"cls": cls, "v": int(min_views)})
        objs = [StoredObject(r[0], r[1], r[2], (r[3], r[4], r[5]), r[6], r[7], r[8])
                for r in rows]
    else:
        objs = [StoredObject(m.model_id, n, d["cls"], (d["x"], d["y"], d["z"]), d["n_views"],
                             d["n_obs"], d["score"])
                for m in _models(store) for n, d in _object_nodes(m)
                if d["cls"] == cls and d["n_views"] >= min_views]
    return _sort_objects(objs)


def models_with_classes_near(store, a: str, b: str, within: float) -> list[str]:
    """The models (houses) holding an object of class ``a`` and one of class ``b`` at most
    ``within`` metres apart on the floor, sorted. (The squared distance is compared, computed the
    same way in both backends, so a pair on the boundary answers the same.)"""
    w2 = float(within) * float(within)
    if (db := _db(store)) is not None:
        _, rows = db.cypher(
            "MATCH (m:Model)-[:HasObject]->(p:Object), (m)-[:HasObject]->(q:Object) "
            "WHERE p.cls = $a AND q.cls = $b AND p.key <> q.key "
            "AND (p.x - q.x) * (p.x - q.x) + (p.y - q.y) * (p.y - q.y) <= $w2 "
            "RETURN DISTINCT m.id", {"a": a, "b": b, "w2": w2})
        return sorted(r[0] for r in rows)
    out = []
    for m in _models(store):
        objs = list(_object_nodes(m))
        ps = [(n, d) for n, d in objs if d["cls"] == a]
        qs = [(n, d) for n, d in objs if d["cls"] == b]
        if any(pn != qn and (p["x"] - q["x"]) * (p["x"] - q["x"])
               + (p["y"] - q["y"]) * (p["y"] - q["y"]) <= w2
               for pn, p in ps for qn, q in qs):
            out.append(m.model_id)
    return sorted(out)


def states_that_saw(store, model_id: str, object_id: str) -> list[tuple[str, float]]:
    """The states of model ``model_id`` that saw object ``object_id``, nearest first:
    ``(state_id, distance)`` (ties by state id)."""
    if (db := _db(store)) is not None:
        _, rows = db.cypher(
            "MATCH (s:State)-[v:Sees]->(o:Object) WHERE o.key = $k RETURN s.id, v.distance",
            {"k": f"{model_id}/{object_id}"})
        pairs = [(r[0], r[1]) for r in rows]
    else:
        pairs = []
        for m in _models(store):
            if m.model_id == model_id and m.graph.has_node(object_id):
                pairs = [(s, d["distance"]) for s, _, k, d in
                         m.graph.in_edges(object_id, keys=True, data=True) if k == SEES]
    return sorted(pairs, key=lambda p: (p[1], p[0]))


def class_inventories(store) -> dict[str, dict[str, int]]:
    """Objects per class of every model: ``{model_id: {class: count}}``, both sorted by name (a
    model without objects maps to ``{}``)."""
    counts: dict[str, dict[str, int]] = {}
    if (db := _db(store)) is not None:
        counts = {r[0]: {} for r in db.cypher("MATCH (m:Model) RETURN m.id")[1]}
        _, rows = db.cypher("MATCH (o:Object) RETURN o.model, o.cls, count(*)")
        for model_id, cls, n in rows:
            counts.setdefault(model_id, {})[cls] = int(n)
    else:
        for m in _models(store):
            inv = counts.setdefault(m.model_id, {})
            for _, d in _object_nodes(m):
                inv[d["cls"]] = inv.get(d["cls"], 0) + 1
    return {k: dict(sorted(v.items())) for k, v in sorted(counts.items())}


def objects_near_state(store, model_id: str, state_id: str, hops: int) -> list[str]:
    """The objects seen from the states within ``hops`` transitions of ``state_id`` (following
    transitions forward; 0 is the state alone), sorted by id."""
    if hops < 0:
        raise ValueError(f"hops must be >= 0, got {hops}")
    if (db := _db(store)) is not None:
        key = f"{model_id}/{state_id}"
        found = {r[0] for r in db.cypher(
            "MATCH (s:State)-[:Sees]->(o:Object) WHERE s.key = $k RETURN o.id", {"k": key})[1]}
        if hops:
            found |= {r[0] for r in db.cypher(
                f"MATCH (s:State)-[:Transition*1..{int(hops)}]->(t:State)-[:Sees]->(o:Object) "
                "WHERE s.key = $k RETURN DISTINCT o.id", {"k": key})[1]}
        return sorted(found)
    import networkx as nx

    for m in _models(store):
        if m.model_id != model_id or not m.graph.has_node(state_id):
            continue
        moves = nx.DiGraph((u, v) for u, v, k in m.graph.edges(keys=True) if k != SEES)
        moves.add_node(state_id)
        near = nx.single_source_shortest_path_length(moves, state_id, cutoff=hops)
        return sorted({o for s in near for _, o, k in m.graph.out_edges(s, keys=True)
                       if k == SEES})
    return []
