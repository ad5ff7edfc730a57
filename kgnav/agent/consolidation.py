"""One memory per house: joining stored models between episodes when verification allows it.

An episode that never recognised a stored model is stored as a new one, so a house can end up
with several models that cover the same rooms and were never joined (issue 28: four in one
house, 1.59 copies of every real object). The episode's own late match
(:meth:`~kgnav.agent.relocation.Relocalizer.mergeable`) compares one episode with the memory
once, at its end; after a later episode has grown another model, the two may well fit.
:func:`consolidate` therefore judges each model a memory update changed against the other
stored models **as a whole**, exactly as the late match judges an episode: the feature matches
of its states propose frame transforms per model, and each is verified against the whole
model's range profiles (inliers, conflicts, an alternative alignment that fits about as well
makes it ambiguous: a rotated twin) and its objects (those seen twice must mostly find their
class where the other model has objects). A join that passes is a merge of the smaller model
into the larger; nothing is joined on a feature match alone, so a look-alike room of another
house, or the same room turned round, stays refused.

>>> from kgnav.memory.synthetic import SyntheticWorld
>>> w = SyntheticWorld(seed=1, size=(8.0, 8.0), n_objects=12, feature_dim=32)
>>> a = w.explore(200, seed=0, model_id="house-e000")
>>> models = {"house-e000": a}
>>> consolidate(models, ["house-e000"], threshold=0.3)   # nothing else to join
[]
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, replace

import numpy as np

from kgnav.common import se2
from kgnav.memory.evidence import forget
from kgnav.memory.merge import merge
from kgnav.memory.model import AbstractModel
from kgnav.memory.posegraph import bend, straighten

__all__ = ["Join", "consolidate", "find_join"]


@dataclass(frozen=True)
class Join:
    """Model ``model_id`` folded into ``into``; ``transform`` maps ``model_id``'s frame into
    ``into``'s (before the fold; the joined model keeps ``into``'s frame and id)."""

    model_id: str
    into: str
    transform: tuple[float, float, float]
    inliers: float
    conflicts: float
    points: int
    centre: tuple[float, float] = (0.0, 0.0)  # the mean of ``model_id``'s state positions
    # loop closures linking ``model_id``'s states to ``into``'s, where stretches of them fit
    # on their own (Relocalizer.model_links; only asked for with a drift model)
    links: tuple = ()


def find_join(models: dict[str, AbstractModel], model_id: str, *, threshold: float,
              config=None, memory=None, links: bool = False) -> Join | None:
    """Whether the stored model ``model_id`` verifiably fits another of ``models`` as a
    whole (see the module docstring): the best such fit, as a :class:`Join` of ``model_id``
    into that model, or None. ``threshold``: the relocation feature-distance threshold;
    ``config``: a :class:`~kgnav.agent.relocation.RelocationConfig` (its verification
    settings; the whole-model check is always made). ``memory``: a
    :class:`~kgnav.agent.memory.Memory` over ``models`` to reuse (its relocator and the
    occupancy it has built; ``model_id`` is taken out of it while judged and put back), else
    one is built. ``links``: also find the join's links (:attr:`Join.links`)."""
    from kgnav.agent.memory import Memory
    from kgnav.agent.relocation import Relocalizer, RelocationConfig

    model = models[model_id]
    kind = (model.feature_dim, model.extractor)
    if model.scan is None or model.n_states == 0:
        return None
    # stored models are already as straight as their own loop closures made them: no bend
    cfg = replace(config or RelocationConfig(), merge_check=True, late_match=True, drift=None)
    if not cfg.geometry:
        return None  # a feature match alone never joins two memories
    if memory is None:
        others = {k: m for k, m in models.items()
                  if k != model_id and (m.feature_dim, m.extractor) == kind}
        if not others:
            return None
        return _judge(Relocalizer(Memory(others, threshold=threshold), cfg), model, links)
    if len(memory.models) < 2:
        return None
    with memory.without(model_id):
        return _judge(Relocalizer(memory, cfg), model, links)


def _judge(rel, model: AbstractModel, links: bool = False) -> Join | None:
    rel.take_model(model)
    r = rel.mergeable(model)
    if r is None:
        return None
    T = tuple(float(v) for v in r.transform)
    return Join(model.model_id, r.model_id, T, float(r.inliers or 0.0),
                float(r.conflicts or 0.0), int(r.points),
                links=tuple(rel.model_links(model, r.model_id, T)) if links else ())


def consolidate(models: dict[str, AbstractModel], changed: Iterable[str], *, threshold: float,
                config=None, forget_below: float = 0.0,
                forget_label_share: float = 0.0, drift=None) -> list[Join]:
    """Join each model of ``changed`` (in that order) with the stored model it verifiably fits
    (:func:`find_join`), again with the joined model until it fits none; ``models`` (id ->
    model) changes in place. The smaller of two (fewer states) is folded into the larger,
    which keeps its id and frame. Objects are then forgotten as the memory update forgets
    them (``forget_below``, ``forget_label_share``). Returns the joins made, in order.

    With ``drift`` (the odometry's :class:`~kgnav.memory.posegraph.DriftModel`), a join is not
    only one rigid transform: stretches of the folded model that fit the other on their own
    are recorded as links (:attr:`Join.links`, loop closures of episode
    :data:`~kgnav.memory.constants.JOIN_EPISODE`), and the joined model's pose graph is
    optimised again (:func:`~kgnav.memory.posegraph.straighten`), as after a merge.

    One relocator and one occupancy cache serve every model judged (the models of the first
    changed one's extractor and feature size; another kind is judged on its own)."""
    from kgnav.agent.memory import Memory

    joins: list[Join] = []
    queue = [m for m in changed if m in models]
    if not queue:
        return joins
    kind = (models[queue[0]].feature_dim, models[queue[0]].extractor)
    pool = Memory({k: m for k, m in models.items() if (m.feature_dim, m.extractor) == kind},
                  threshold=threshold)
    while queue:
        mid = queue.pop(0)
        if mid not in models:
            continue
        same = (models[mid].feature_dim, models[mid].extractor) == kind
        j = find_join(models, mid, threshold=threshold, config=config,
                      memory=pool if same else None, links=drift is not None)
        if j is None:
            continue
        small, big = models[j.model_id], models[j.into]
        if small.n_states > big.n_states:  # fold the other way: the larger keeps its frame
            j = Join(j.into, j.model_id, se2.inverse(j.transform), j.inliers, j.conflicts,
                     j.points, links=tuple(_reversed(c) for c in j.links))
            small, big = big, small
        j = replace(j, centre=_centroid(small))
        joined = merge(big, small, transform=j.transform)
        if drift is not None:
            joined.add_loop_closures(j.links)
            rejected: list[dict] = []
            bend(joined, straighten(joined, drift, rejected))
            joined.reject_loop_closures(rejected)
        if forget_below > 0 or forget_label_share > 0:
            forget(joined, forget_below, min_label_share=forget_label_share)
        del models[j.model_id]
        models[j.into] = joined
        if same:  # the pool follows: the folded model gone, the joined one re-indexed
            pool.drop(j.model_id)
            pool.update(joined)
        joins.append(j)
        queue.insert(0, j.into)  # the joined model may now fit yet another
    return joins


def _reversed(link: dict) -> dict:
    """The same link seen from its other end."""
    return {**link, "state": link["to"], "to": link["state"],
            "rel": [float(v) for v in se2.inverse(tuple(link["rel"]))]}


def _centroid(model: AbstractModel) -> tuple[float, float]:
    """The mean position of a model's states (where a join's error is measured)."""
    xy = np.array([model.pose(s)[:2] for s in model.states()], float).reshape(-1, 2)
    return (float(xy[:, 0].mean()), float(xy[:, 1].mean())) if len(xy) else (0.0, 0.0)
