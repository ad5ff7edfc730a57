"""Which remembered object to head for: the paper's view count, or the belief of the evidence.

* ``"views"`` (the paper): the closest to the agent among the ``top_k`` most-seen objects of the
  goal class (:func:`kgnav.memory.query.goal_point`).
* ``"belief"`` (the default): the closest among the objects of the goal class whose belief
  (:func:`kgnav.memory.evidence.belief`: views against misses of the states that had them in view)
  is at least ``min_belief`` and whose place gave the goal class in at least
  ``min_label_share`` of its views (the rest: another class at the same spot, a segmenter's
  confusion). A place the memory looked at many times without seeing the goal there is no
  longer a goal because a segmenter glitched twice. A place the segmenter keeps mislabelling,
  from every side and in every episode, is told apart by the lower confidence of those labels:
  among the candidates seen from at least ``score_views`` states, one whose views' mean
  detection confidence falls more than ``score_margin`` below the best candidate's is left
  out. The comparison is within the goal class, because a segmenter is surer of some
  classes than of others (of beds than of plants); a class's only candidate stays, unless
  ``min_score`` (off by default) is set: then a candidate seen from ``score_views`` states
  whose mean confidence is below it is left out even when it is the only one.
  ``remembered_floor`` (off by default) does the same per class, for remembered candidates
  only (those the episode has not perceived itself): the segmenter is surer of some classes
  than of others, and a candidate seen in this episode is judged on arrival anyway.

Either rule skips objects seen from fewer than ``min_views`` states and the ids excluded by
the caller (objects already looked for and not found).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from kgnav.memory import query
from kgnav.memory.evidence import (
    DEFAULT_BELIEF,
    BeliefModel,
    Evidence,
    ScanTable,
    belief,
    object_evidence,
)
from kgnav.memory.model import AbstractModel, ObjectInfo

GOAL_RULES = ("belief", "views")


@dataclass(frozen=True)
class GoalConfig:
    rule: str = "belief"
    top_k: int = query.TOP_K  # the views rule's "most seen"
    min_views: int = 2  # a goal seen from one state only is likely a segmenter glitch
    min_belief: float = 0.5
    min_label_share: float = 0.5  # the views at its place mostly give the goal class
    belief: BeliefModel = field(default_factory=lambda: DEFAULT_BELIEF)
    evidence_refresh: int = 8  # recount an object's misses after this many new states
    keep_margin: float = 1.5  # m: the object already headed for stays the goal unless
    # another is closer by more than this (0: always the closest, the paper)
    score_margin: float = 0.1  # belief rule: leave out a candidate whose mean detection
    # confidence is this far below the best candidate's (math.inf: off)
    score_views: int = 3  # ... among those seen from this many states
    min_score: float = 0.0  # belief rule: leave out a candidate seen from score_views states
    # whose views' mean detection confidence is below this, even its class's only one (0: off)
    # belief rule, per class ((class, floor), ...): leave out a *remembered* candidate (one
    # this episode has not perceived itself) seen from score_views states whose mean
    # confidence is below its class's floor, even the class's only one; what the agent sees
    # itself is judged on arrival instead. Calibrated per class on a run's memory against
    # ground truth (kgnav goal-floors); empty: off
    remembered_floor: tuple[tuple[str, float], ...] = ()

    def __post_init__(self):
        if self.rule not in GOAL_RULES:
            raise ValueError(f"goal rule must be one of {GOAL_RULES}, got {self.rule!r}")
        floors = dict(self.remembered_floor)
        if len(floors) != len(self.remembered_floor) or not all(
                isinstance(c, str) and 0.0 <= float(v) <= 1.0 for c, v in floors.items()):
            raise ValueError(f"remembered_floor must give each class once a floor in [0, 1], "
                             f"got {self.remembered_floor!r}")


def choose_goal(model: AbstractModel, cls: str, near, config: GoalConfig,
                exclude=(), table: ScanTable | None = None, among=None,
                cache: dict | None = None, current: str | None = None,
                perceived=None) -> ObjectInfo | None:
    """The object of class ``cls`` to head for from ``near`` (model frame), or None;
    ``among``: consider only these object ids; ``cache``: evidence kept between calls (see
    :func:`kgnav.memory.evidence.object_evidence`); ``current``: the object headed for so far, which
    stays the goal while it qualifies unless another is closer by more than
    ``config.keep_margin`` (walking past one goal toward another does not flip between them);
    ``perceived``: the ids this episode perceived itself, which ``config.remembered_floor``
    spares (None: every candidate is one the episode perceived, the floor spares all).
    """
    if among is not None:
        exclude = set(exclude) | {o for o in model._index.by_class.get(cls, ())
                                  if o not in among}
    if config.rule == "views":
        return query.goal_point(model, cls, near, config.top_k, exclude=exclude,
                                min_views=config.min_views)
    cands = [o for o in query.ranked_objects(model, cls)
             if o.id not in exclude and o.n_views >= config.min_views]
    if not cands:
        return None
    ev = object_evidence(model, [o.id for o in cands], table=table, cache=cache,
                         stale=config.evidence_refresh, weak_below=config.belief.weak_below)
    remembered = max(config.min_score, dict(config.remembered_floor).get(cls, 0.0))

    def least_score(oid: str) -> float:  # what a judged candidate's mean confidence must reach
        spared = perceived is None or oid in perceived
        return config.min_score if spared else remembered

    trusted = [o for o in cands if trusts(ev[o.id], config)
               and (ev[o.id].n_views < config.score_views
                    or ev[o.id].mean_score >= least_score(o.id))]
    judged = [ev[o.id].mean_score for o in trusted if ev[o.id].n_views >= config.score_views]
    if judged and math.isfinite(config.score_margin):
        floor = max(judged) - config.score_margin
        trusted = [o for o in trusted if ev[o.id].n_views < config.score_views
                   or ev[o.id].mean_score >= floor]
    if not trusted:
        return None
    x, y = float(near[0]), float(near[1])
    return min(trusted, key=lambda o: (math.hypot(o.position[0] - x, o.position[1] - y)
                                       - (config.keep_margin if o.id == current else 0.0), o.id))


def trusts(ev: Evidence, config: GoalConfig) -> bool:
    """Whether the belief rule would head for an object with evidence ``ev`` (on its own:
    the confidence comparison with other candidates is :func:`choose_goal`'s)."""
    return (belief(ev, config.belief) >= config.min_belief
            and ev.label_share >= config.min_label_share)
