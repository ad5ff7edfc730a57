"""Evidence for and against the objects of an Abstract Model, and the belief it adds up to.

Counting views (the paper's "top five most-seen") trusts a segmenter's persistent mistakes more
the more often they recur, and never learns that a place was looked at many times without the
goal being there. The evidence of an object is therefore:

* **positive**: ``n_views`` (distinct states that saw it), ``n_episodes`` (distinct episodes
  among them) and ``score`` (summed detection confidence of its views; ``mean_score``, its
  mean, is what tells a segmenter's persistent mistakes from real objects, which recur as
  often but are detected with more confidence);
* **negative**: ``n_missed``, the states that *should* have seen it and did not: the object's
  position lay in their field of view, within :data:`MISS_RANGE`, and in front of the first
  obstacle of their range profile (so not hidden behind a wall), yet they hold no view of it.

All of it is a function of the graph (views, states and their range profiles), computed on
demand by :func:`object_evidence`; it therefore survives saving and loading unchanged, and
merging combines it exactly: the evidence of a merged model is that of its union of states and
views. :func:`belief` turns it into the probability that the object is real, a naive-Bayes
log-odds of detection against false alarm per state: a real object in view is detected with
probability about ``p_detect``, a place without one yields a detection of that class with
about ``p_false``.

>>> import numpy as np
>>> from kgnav import AbstractModel, Detection
>>> from kgnav.memory.geometry import ScanGeometry
>>> m = AbstractModel(2, model_id="e", scan=ScanGeometry(90.0, 4, 5.0))
>>> far = np.full(4, 5.0)
>>> s0 = m.add_state([1.0, 0.0], (0, 0, 0), [Detection("chair", (2.0, 0.0, 0.4))], ranges=far)
>>> s1 = m.add_state([0.0, 1.0], (0.5, 0, 0), ranges=far)     # looks at it, sees nothing
>>> ev = object_evidence(m)["o0"]
>>> ev.n_views, ev.n_missed, ev.n_episodes
(1, 1, 1)
>>> round(belief(ev), 3)
0.201
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from kgnav.memory.model import SEES, AbstractModel

#: Farther than this (m), a state that did not see an object is no evidence against it: a
#: segmenter misses much of what is far.
MISS_RANGE = 3.0
#: Objects of other classes this close (m, centre to centre) are other labels for the same
#: thing: real objects do not stand inside each other.
RIVAL_RADIUS = 0.4


@dataclass(frozen=True)
class Evidence:
    """What a model knows for and against one object. ``n_rival``: views of objects of
    other classes at the same place (within :data:`RIVAL_RADIUS`): another label for the same
    thing, as a segmenter that confuses a desk with a sofa gives it."""

    n_views: int
    n_episodes: int
    n_missed: int
    score: float
    n_rival: int = 0
    n_weak: int = 0  # of n_views: views scored under the belief model's weak_below

    @property
    def mean_score(self) -> float:
        """The mean detection confidence of its views (0 without views): a segmenter's
        persistent mistake recurs, but with lower confidence than what it gets right."""
        return self.score / self.n_views if self.n_views else 0.0

    @property
    def label_share(self) -> float:
        """The share of the views at this place that gave this object's class."""
        return self.n_views / (self.n_views + self.n_rival) if self.n_views else 0.0


@dataclass(frozen=True)
class BeliefModel:
    """Parameters of :func:`belief`: detection probability of a real object in view, false
    alarm probability of a place without one, and the prior log-odds of a first detection."""

    p_detect: float = 0.6
    p_false: float = 0.05
    prior: float = -3.0
    #: a view scored under this is a weak one (a segment under the segmenter's detection
    #: threshold, kept as evidence: ``AgentConfig.weak_score``); 0: every view is a detection
    weak_below: float = 0.0
    #: the log-odds a weak view adds (a detection adds :attr:`view_weight`)
    weak_weight: float = 1.0

    @property
    def view_weight(self) -> float:
        return math.log(self.p_detect / self.p_false)

    @property
    def miss_weight(self) -> float:
        return math.log((1.0 - self.p_detect) / (1.0 - self.p_false))


DEFAULT_BELIEF = BeliefModel()


def belief(ev: Evidence, model: BeliefModel = DEFAULT_BELIEF) -> float:
    """Probability that the object is real, from its views and misses."""
    logit = (model.prior + model.view_weight * (ev.n_views - ev.n_weak)
             + model.weak_weight * ev.n_weak + model.miss_weight * ev.n_missed)
    return 1.0 / (1.0 + math.exp(-min(max(logit, -50.0), 50.0)))


class ScanTable:
    """The poses and range profiles of a model's states, as arrays (build once, query often;
    :meth:`extend` appends the states a growing model gained since, :meth:`add` one state)."""

    def __init__(self, model: AbstractModel):
        self.scan = model.scan
        bins = self.scan.bins if self.scan is not None else 0
        self.ids: list[str] = []
        self._poses = np.zeros((16, 3), float)
        self._ranges = np.zeros((16, bins), np.float32)
        self.states_read = 0  # the model's states read so far, with a profile or not
        self.extend(model)

    def extend(self, model: AbstractModel) -> None:
        """Add the states ``model`` gained since this table last read it (states are only
        appended while a model grows, and keep their poses)."""
        g = model.graph
        for s in itertools.islice(model.states(), self.states_read, None):
            d = g.nodes[s]
            if d.get("ranges") is not None:
                self.add(s, (d["x"], d["y"], d["theta"]), d["ranges"])
        self.states_read = model.n_states

    def add(self, sid: str, pose, ranges) -> None:
        n = len(self.ids)
        if n == len(self._poses):
            self._poses = np.concatenate([self._poses, np.zeros_like(self._poses)])
            self._ranges = np.concatenate([self._ranges, np.zeros_like(self._ranges)])
        self._poses[n] = pose
        self._ranges[n] = ranges
        self.ids.append(sid)

    @property
    def poses(self) -> np.ndarray:
        return self._poses[:len(self.ids)]

    @property
    def ranges(self) -> np.ndarray:
        return self._ranges[:len(self.ids)]

    def __len__(self) -> int:
        return len(self.ids)

    def covering(self, x: float, y: float, max_distance: float = MISS_RANGE) -> list[str]:
        """Ids of the states that had (x, y) in view (see :meth:`ScanGeometry.covers`)."""
        if not self.ids:
            return []
        hit = self.scan.covers(self.poses, self.ranges, (x, y), max_distance)
        return [self.ids[i] for i in np.flatnonzero(hit)]


def object_evidence(model: AbstractModel, objects: Iterable[str] | None = None,
                    miss_range: float = MISS_RANGE, table: ScanTable | None = None,
                    cache: dict | None = None, stale: int = 0,
                    weak_below: float = 0.0) -> dict[str, Evidence]:
    """The :class:`Evidence` of ``objects`` (default: all), by id.

    ``cache`` (a dict the caller keeps) with ``stale`` > 0 reuses an object's evidence while
    its views and position are unchanged and ``table`` has grown by fewer than ``stale``
    states since: an agent asking every step need not recount every state. ``weak_below``:
    views scored under this are counted as weak (``Evidence.n_weak``)."""
    g = model.graph
    ids = list(model.objects()) if objects is None else [o for o in objects if o in g]
    if table is None and ids and model.scan is not None:
        table = ScanTable(model)
    n = len(table) if table is not None else 0
    rivals = None  # built on the first object the cache cannot answer: it reads them all
    out = {}
    for o in ids:
        d = g.nodes[o]
        key = (d["n_views"], d["x"], d["y"])
        if cache is not None and stale > 0:
            hit = cache.get(o)
            if hit is not None and hit[1] == key and n - hit[0] < stale:
                out[o] = hit[2]
                continue
        seers = {s for s, _, k in g.in_edges(o, keys=True) if k == SEES}
        episodes = {g.nodes[s]["episode"] for s in seers}
        weak = 0
        if weak_below > 0:
            weak = sum(1 for s in seers if g.edges[s, o, SEES].get("score", 1.0) < weak_below)
        missed = 0
        if table is not None:
            missed = sum(1 for s in table.covering(d["x"], d["y"], miss_range) if s not in seers)
        if rivals is None:
            rivals = _Rivals(model)
        out[o] = Evidence(len(seers), len(episodes), missed, float(d["score"]),
                          rivals.views(o, d), weak)
        if cache is not None:
            cache[o] = (n, key, out[o])
    return out


class _Rivals:
    """Object positions, classes and views of a model, to count other labels of a place."""

    def __init__(self, model: AbstractModel):
        g = model.graph
        self.ids = list(model.objects())
        self.xy = np.array([(g.nodes[o]["x"], g.nodes[o]["y"]) for o in self.ids],
                           float).reshape(-1, 2)
        self.cls = np.array([g.nodes[o]["cls"] for o in self.ids], dtype=object)
        self.n_views = np.array([g.nodes[o]["n_views"] for o in self.ids], int)

    def views(self, oid: str, d: dict) -> int:
        if not self.ids:
            return 0
        near = np.hypot(self.xy[:, 0] - d["x"], self.xy[:, 1] - d["y"]) <= RIVAL_RADIUS
        near &= self.cls != d["cls"]
        return int(self.n_views[near].sum())


def forget(model: AbstractModel, below: float = 0.2, belief_model: BeliefModel = DEFAULT_BELIEF,
           min_label_share: float = 0.0) -> int:
    """Consolidate a memory: remove the objects whose belief has fallen below ``below`` (seen
    once or twice, then looked at and not seen again: a segmenter's passing mistake), and
    those whose place gave their class in less than ``min_label_share`` of its views (another
    label for the same thing won: a segmenter's confusion of one object with a look-alike
    class, which persists and so is never missed). Returns how many were removed. An object
    the evidence has not yet judged (seen once, never looked at again) stays."""
    ev = object_evidence(model, weak_below=belief_model.weak_below)
    return model.remove_objects(o for o, e in ev.items() if belief(e, belief_model) < below
                                or (e.n_views and e.label_share < min_label_share))
