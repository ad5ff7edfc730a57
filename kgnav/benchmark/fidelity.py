"""How faithful a stored memory is to the house it describes, scored against ground truth.

A change to association, evidence or merging should show on the memory itself, not only in
navigation scores. For the models of one house (each in the start frame of the episode that
created it, mapped to the world with ``frame``):

* **precision**: share of model objects within ``tolerance`` (0.5 m) of the footprint of a real
  instance of their class; ``trusted_precision``: the same over the objects the agent would
  trust as goals (belief at least 0.5, :mod:`kgnav.memory.evidence`);
* **copies**: model objects per real instance they stand for (each object counts for its
  nearest instance), averaged over the instances represented; 1.0 is one node per object;
* **recall**: share of the real instances the episodes *saw* (ground truth: visible in some
  frame, large enough and near enough to be segmented) that some model object stands for;
* **models**: how many separate models the house's memory is made of;
* **goal held** (:func:`holds_true_instance`): whether the models hold a true instance of a
  class, the benchmark's ``goal_in_memory`` at an episode's start;
* **pose error** (:func:`pose_residuals`, :func:`error_summary`): the absolute trajectory
  error of the stored states. Each state's stored position (model frame) is paired with the
  true world position the agent had when the state was recorded (keyed by the state's
  creator in ``origin``, ``model_id/node_id``); each model is aligned to the truth by one
  rigid 2-D fit (:func:`kgnav.common.se2.fit_points`), and the residuals' median and 95th
  percentile (m) are reported with the number of states. 0 with a perfect pose sensor and
  exact merges; odometry drift and wrong merge transforms raise it. The stored headings'
  error after the same fit (:func:`residuals`, degrees) beside it: what places the
  objects a state saw;
* **in the map's own frame** (:func:`alignment`, :func:`aligned_frames`): the object scores
  again with each model placed by that same fit instead of its creating episode's start
  (where that episode's odometry drifted, the two differ by the drift: a model turned 5°
  puts every object 10 m from its start 0.9 m off, though each is where the map has it
  relative to the rest); :func:`frame_error` says how far apart the two frames are.

>>> from kgnav.sim.house import ObjectInstance
>>> chair = ObjectInstance(1, "chair", 0, 0.0, 0.0, 0.5, 0.5, 0.0, 0.9, (0, 0, 0))
>>> s = score_objects([("chair", 0.6, 0.2, 1.0), ("chair", 0.3, 0.9, 1.0),
...                    ("bed", 5.0, 5.0, 0.1)], [chair], seen={1})
>>> s["objects"], s["precision"], s["copies"], s["recall"], s["trusted_precision"]
(3, 0.667, 2.0, 1.0, 1.0)
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterable, Mapping

import numpy as np

from kgnav.common import se2
from kgnav.memory.evidence import DEFAULT_BELIEF, BeliefModel, belief, object_evidence
from kgnav.memory.model import AbstractModel

TOLERANCE = 0.5  # m from a real instance's footprint
MIN_ALIGNED = 3  # states of known truth a model needs before it is scored in its own frame


def score_objects(objects: Iterable[tuple], instances,
                  seen: set[int] | None = None, tolerance: float = TOLERANCE) -> dict:
    """Score ``objects`` — (class, world x, world y, belief[, views]) — against real
    ``instances`` (:class:`~kgnav.sim.house.ObjectInstance`). ``seen``: ids of the instances
    the episodes saw (recall is over those; None: all). ``false_by_views``: how many objects
    stand for no real instance, by how many states saw them."""
    objects = list(objects)
    by_cls = _by_class(instances)
    matched, trusted, trusted_ok = 0, 0, 0
    stands_for: Counter = Counter()
    false: Counter = Counter()
    for cls, x, y, b, *views in objects:
        inst = stands_for_instance(cls, x, y, by_cls, tolerance)
        ok = inst is not None
        matched += ok
        if ok:
            stands_for[inst] += 1
        elif views:
            false["1" if views[0] <= 1 else "2-3" if views[0] <= 3 else "4+"] += 1
        if b >= 0.5:
            trusted += 1
            trusted_ok += ok
    pool = set(seen) if seen is not None else {i.id for i in instances}
    found = len(pool & set(stands_for))
    return {
        "objects": len(objects),
        "trusted_objects": trusted,
        "precision": _ratio(matched, len(objects)),
        "trusted_precision": _ratio(trusted_ok, trusted),
        "copies": _ratio(sum(stands_for.values()), len(stands_for)),
        "instances_seen": len(pool),
        "represented": len(stands_for),
        "recall": _ratio(found, len(pool)),
        "false_by_views": {k: false[k] for k in ("1", "2-3", "4+")},
    }


def _by_class(instances) -> dict[str, list]:
    by_cls: dict[str, list] = {}
    for inst in instances:
        by_cls.setdefault(inst.cls, []).append(inst)
    return by_cls


def stands_for_instance(cls: str, x: float, y: float, by_cls: dict[str, list],
                        tolerance: float = TOLERANCE) -> int | None:
    """The id of the real instance a model object of class ``cls`` at world ``(x, y)`` stands
    for: the nearest footprint of its class (``by_cls``: instances by class), if within
    ``tolerance``; None for a phantom. Every score here matches objects this one way."""
    dist, inst = min(((i.distance_to(x, y), i.id) for i in by_cls.get(cls, ())),
                     default=(math.inf, None))
    return inst if dist <= tolerance else None


def holds_true_instance(models: Iterable[tuple[AbstractModel, tuple]], cls: str, instances,
                        tolerance: float = TOLERANCE) -> bool:
    """Whether some object of class ``cls`` in ``models`` (each with its world frame, as for
    :func:`score_memory`) stands for a real instance of ``cls``: the memory held the goal,
    whatever the agent believed of it (a phantom of the class does not count)."""
    by_cls = _by_class(i for i in instances if i.cls == cls)
    for model, frame in models:
        nodes = model.graph.nodes
        for o in model.objects():
            if nodes[o]["cls"] != cls:
                continue
            x, y = se2.apply_to_point(frame, nodes[o]["x"], nodes[o]["y"])
            if stands_for_instance(cls, x, y, by_cls, tolerance) is not None:
                return True
    return False


def _ratio(a: float, b: float) -> float | None:
    return round(a / b, 3) if b else None


def model_objects(model: AbstractModel, frame, belief_model: BeliefModel = DEFAULT_BELIEF
                  ) -> list[tuple[str, float, float, float, int]]:
    """Every object of ``model`` as (class, world x, world y, belief, views); ``frame`` is the
    world pose of the model's frame origin (the start of the episode that created it);
    ``belief_model``: the agent's (:func:`kgnav.memory.evidence.belief`)."""
    ev = object_evidence(model, weak_below=belief_model.weak_below)
    out = []
    for o in model.objects():
        d = model.graph.nodes[o]
        x, y = se2.apply_to_point(frame, d["x"], d["y"])
        out.append((d["cls"], x, y, belief(ev[o], belief_model), d["n_views"]))
    return out


def score_memory(models: Iterable[tuple[AbstractModel, tuple]], instances,
                 seen: set[int] | None = None, belief_model: BeliefModel = DEFAULT_BELIEF
                 ) -> dict:
    """Score the models of one house together (each with its world frame)."""
    models = list(models)
    objs = [o for m, frame in models for o in model_objects(m, frame, belief_model)]
    return {"models": len(models), **score_objects(objs, instances, seen)}


def pooled(per_house: dict[str, dict]) -> dict:
    """Object-weighted averages over houses, and the spread of models per house."""
    def wavg(key, weight):
        num = sum(h[key] * h[weight] for h in per_house.values() if h[key] is not None)
        den = sum(h[weight] for h in per_house.values() if h[key] is not None)
        return _ratio(num, den)

    models = [h["models"] for h in per_house.values()]
    return {
        "houses": len(per_house),
        "precision": wavg("precision", "objects"),
        "trusted_precision": wavg("trusted_precision", "trusted_objects"),
        "recall": wavg("recall", "instances_seen"),
        "copies": _ratio(sum((h["copies"] or 0) * h["represented"] for h in per_house.values()),
                         sum(h["represented"] for h in per_house.values())),
        "false_by_views": dict(sum((Counter(h["false_by_views"]) for h in per_house.values()),
                                   Counter())),
        "models_per_house": dict(sorted(Counter(models).items())),
        "houses_with_one_model": sum(m == 1 for m in models),
        "objects": sum(h["objects"] for h in per_house.values()),
    }


def _paired(model: AbstractModel, truth: Mapping[str, tuple]) -> tuple[np.ndarray, np.ndarray]:
    """The stored (x, y, θ) of ``model``'s states with a known truth, and their true world
    (x, y, θ) (θ NaN where the truth has none)."""
    p, q = [], []
    for sid in model.states():
        d = model.graph.nodes[sid]
        t = truth.get(d["origin"].split(" ", 1)[0])
        if t is not None:
            p.append((d["x"], d["y"], d["theta"]))
            q.append((*t[:3], math.nan)[:3])  # NaN: no true heading
    return np.array(p, np.float64).reshape(-1, 3), np.array(q, np.float64).reshape(-1, 3)


def alignment(model: AbstractModel, truth: Mapping[str, tuple],
              min_states: int = MIN_ALIGNED) -> se2.Pose | None:
    """The world pose of ``model``'s frame that lays its stored states best on where they
    truly were: the rigid 2-D fit of :func:`residuals` (``truth`` as there). None with fewer
    than ``min_states`` states of known truth.

    A map's frame is its creating episode's start only as far as that episode's odometry
    was right: a few degrees of heading lost in the first turns rotate all the rest, which
    the memory cannot know and which no use of the memory depends on (every episode is laid
    on it by its own relocation). Scoring the memory in this frame (as trajectory error is
    scored after an alignment) says how true the map is in itself; in the start frame, also
    how far that first episode's odometry drifted.

    >>> from kgnav import AbstractModel
    >>> m = AbstractModel(2, model_id="h-e000")
    >>> for k in range(3):
    ...     _ = m.add_state([1.0, 0.0], (float(k), 0.0, 0.0))
    >>> truth = {f"h-e000/s{k}": (5.0, 1.0 + k) for k in range(3)}   # turned 90° and moved
    >>> [round(v, 3) for v in alignment(m, truth)]
    [5.0, 1.0, 1.571]
    """
    p, q = _paired(model, truth)
    if len(p) < max(min_states, 1):
        return None
    return se2.fit_points(p[:, :2], q[:, :2])


def residuals(models: Iterable[AbstractModel], truth: Mapping[str, tuple]
              ) -> tuple[np.ndarray, np.ndarray]:
    """The stored states' position residuals (m) and heading residuals (degrees, absolute),
    each model aligned to the truth by one rigid 2-D fit of its positions (:func:`alignment`).
    ``truth``: the true world (x, y) or (x, y, θ) of every recorded state, keyed
    ``model_id/node_id`` (the first entry of a state's ``origin``: its creator); states
    without one are left out, and from the headings also those whose truth has none. A
    heading a few degrees off moves everything the state saw sideways by its range times the
    angle: an object seen from 4 m by a state 5° off lands 0.35 m away, though the state's
    own position may be exact."""
    dist, deg = [], []
    for model in models:
        p, q = _paired(model, truth)
        if not len(p):
            continue
        T = se2.fit_points(p[:, :2], q[:, :2])
        dist.append(np.linalg.norm(se2.apply_to_points(T, p[:, :2]) - q[:, :2], axis=1))
        deg.append(np.degrees([se2.angle_diff(a + T[2], b)
                               for a, b in zip(p[:, 2], q[:, 2], strict=True)
                               if not math.isnan(b)]))
    return (np.concatenate(dist) if dist else np.zeros(0),
            np.concatenate(deg) if deg else np.zeros(0))


def aligned_frames(models: Iterable[tuple[AbstractModel, tuple]], truth: Mapping[str, tuple]
                   ) -> list[tuple[AbstractModel, tuple]]:
    """``models`` (each with its start frame) each with its :func:`alignment` instead, where
    the truth allows one (else the start frame stays)."""
    out = []
    for model, frame in models:
        T = alignment(model, truth)
        out.append((model, frame if T is None else T))
    return out


def frame_error(model: AbstractModel, frame, aligned) -> dict:
    """How far a model's start frame is from its :func:`alignment` ``aligned``: the distance
    (m) between where the two put the model's states' centroid, and the angle (degrees)."""
    xy = np.array([(model.graph.nodes[s]["x"], model.graph.nodes[s]["y"])
                   for s in model.states()], np.float64).reshape(-1, 2)
    c = xy.mean(axis=0) if len(xy) else np.zeros(2)
    ax, ay = se2.apply_to_point(frame, float(c[0]), float(c[1]))
    bx, by = se2.apply_to_point(aligned, float(c[0]), float(c[1]))
    return {"error_m": round(math.hypot(ax - bx, ay - by), 3),
            "error_deg": round(abs(math.degrees(se2.angle_diff(frame[2], aligned[2]))), 2)}


def pose_residuals(models: Iterable[AbstractModel],
                   truth: Mapping[str, tuple[float, float]]) -> np.ndarray:
    """Per stored state with a known true pose, the distance (m) between its stored position
    and its true world position after one rigid 2-D fit of each model to the truth (the
    positions of :func:`residuals`)."""
    return residuals(models, truth)[0]


def heading_residuals(models: Iterable[AbstractModel],
                      truth: Mapping[str, tuple]) -> np.ndarray:
    """Per stored state whose truth has a heading, the error (degrees, absolute) of its stored
    heading after the same rigid fit as :func:`pose_residuals` (the headings of
    :func:`residuals`)."""
    return residuals(models, truth)[1]


def error_summary(residuals) -> dict:
    """``{"median", "p95", "states"}`` of pose residuals (m); None for no states."""
    r = np.asarray(residuals, np.float64)
    if r.size == 0:
        return {"median": None, "p95": None, "states": 0}
    return {"median": round(float(np.median(r)), 6),
            "p95": round(float(np.percentile(r, 95)), 6), "states": int(r.size)}


def confidence_by_class(models: Iterable[tuple[AbstractModel, tuple]], instances,
                        min_views: int = 3, tolerance: float = TOLERANCE
                        ) -> dict[str, dict[str, list[float]]]:
    """The mean detection confidence (:attr:`~kgnav.memory.evidence.Evidence.mean_score`) of
    every object seen from at least ``min_views`` states, by class, split into those that
    stand for a real instance and phantoms: ``{cls: {"real": [...], "phantom": [...]}}``.
    What a per-class confidence floor for remembered goals is calibrated on
    (:func:`suggest_floors`, ``GoalConfig.remembered_floor``)."""
    by_cls = _by_class(instances)
    out: dict[str, dict[str, list[float]]] = {}
    for model, frame in models:
        ev = object_evidence(model)
        nodes = model.graph.nodes
        for o in model.objects():
            if ev[o].n_views < min_views:
                continue
            cls = nodes[o]["cls"]
            x, y = se2.apply_to_point(frame, nodes[o]["x"], nodes[o]["y"])
            real = stands_for_instance(cls, x, y, by_cls, tolerance) is not None
            part = out.setdefault(cls, {"real": [], "phantom": []})
            part["real" if real else "phantom"].append(ev[o].mean_score)
    return out


def suggest_floors(stats: Mapping[str, Mapping[str, list[float]]], quantile: float = 0.1,
                   min_objects: int = 3) -> dict[str, float]:
    """Per class, a confidence floor for remembered goal candidates: the ``quantile`` of its
    real objects' confidence (rounded down to 0.01), where that lies above the median of its
    phantoms; none where the two overlap (the floor would drop real objects with the
    phantoms), nor for a class with fewer than ``min_objects`` of either.

    >>> stats = {"bed": {"real": [0.85, 0.88, 0.9, 0.9, 0.92, 0.95], "phantom": [0.7] * 3},
    ...          "chair": {"real": [0.7] * 10, "phantom": [0.72] * 5}}
    >>> suggest_floors(stats)
    {'bed': 0.86}
    """
    out = {}
    for cls, part in sorted(stats.items()):
        real, phantom = part.get("real", []), part.get("phantom", [])
        if len(real) < min_objects or len(phantom) < min_objects:
            continue
        floor = math.floor(float(np.quantile(real, quantile)) * 100 + 1e-9) / 100
        if floor > float(np.median(phantom)):
            out[cls] = floor
    return out
