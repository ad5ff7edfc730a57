"""Global policies: where to explore when the Abstract Model has no goal to offer.

A :class:`GlobalPolicy` picks an exploration goal cell on the episode map; the agent asks it
every ``interval`` steps (25, as the paper's global policy) or sooner when the last goal was
reached or turned out unreachable. The default, :class:`FrontierPolicy`, heads for the frontier
(explored free space next to unexplored space) with the best size/distance trade-off, measured
by geodesic distance on the planner's map. Policies are registered by name like habitat-lab's
sensors, so a learned policy can be plugged in:

>>> sorted(POLICIES)[:1]
['frontier']
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol, runtime_checkable

import cv2
import numpy as np

from kgnav.agent.mapping import EpisodeMap
from kgnav.agent.planner import FMMPlanner, fmm_distance
from kgnav.registry import Registry


@runtime_checkable
class GlobalPolicy(Protocol):
    """Chooses exploration goals. ``select`` returns a map cell (row, col) or None (nothing
    left to explore)."""

    name: str

    def reset(self, seed: int) -> None: ...

    def select(self, m: EpisodeMap, pose, goal_class: str, planner: FMMPlanner
               ) -> tuple[int, int] | None: ...


#: Global policies by name; the learned ones (:mod:`kgnav.nets.explore.policy`) register on first
#: use, since they need torch.
REGISTRY: Registry[Callable[..., GlobalPolicy]] = Registry(
    "global policy", plugins=("kgnav.nets.explore.policy",))
POLICIES = REGISTRY.factories
register_policy = REGISTRY.register


def policy_names() -> list[str]:
    """Every registered policy name, the plugins' included."""
    return REGISTRY.names()


def make_policy(name: str, **params) -> GlobalPolicy:
    return REGISTRY.get(name)(**params)


def frontiers(m: EpisodeMap, min_cells: int = 6, prior: bool = True, searched: bool = False
              ) -> tuple[np.ndarray, np.ndarray]:
    """Frontier clusters: (label image, cell count per label; label 0 is "not a frontier").

    A frontier cell is known (seen by the agent, or, with ``prior``, by a remembered model
    mapped in after a relocation), not an obstacle, and touches an unknown cell. With
    ``searched``, "known" is "searched" (seen from within the search range by the agent or a
    remembered model, :meth:`EpisodeMap.searched_any`) and an obstacle is never the unknown
    side: the frontiers of the free space nobody has looked at from close enough to find an
    object in it.
    """
    blocked = m.blocked(prior=prior) > 0
    known = m.searched_any() if searched else m.known(prior)
    free = (known > 0) & ~blocked
    unknown = (known == 0) & ~blocked if searched else (known == 0)
    near_unknown = cv2.dilate(unknown.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    front = (free & near_unknown).astype(np.uint8)
    n, lab, stats, _ = cv2.connectedComponentsWithStats(front, connectivity=8)
    sizes = stats[:, cv2.CC_STAT_AREA].copy()
    sizes[0] = 0
    small = sizes < min_cells
    if small.any():
        lab[small[lab]] = 0
        sizes[small] = 0
    return lab, sizes


#: Where a frontier target came from (:attr:`FrontierPolicy.source_`): beside space neither
#: this episode nor the relocated memory has seen; beside space seen, but only from farther
#: than a search reaches (the goal is not believed in memory: look where it could have been
#: missed); this episode's own frontiers (the memory searched everywhere it can reach).
FRONTIER_SOURCES = ("unobserved", "unsearched", "episode")


def _beside_known(m: EpisodeMap, cell: tuple[int, int]) -> bool:
    """Whether every cell around ``cell`` was seen (by the agent or a memory): a frontier of
    unsearched, not of unseen, space."""
    i, j = cell
    crop = (max(i - 1, 0), i + 2, max(j - 1, 0), j + 2)
    return bool(m.known(True, crop).all())


@register_policy("frontier")
class FrontierPolicy:
    """Frontier-based exploration (Yamauchi 1997) with a size bonus.

    Cost of a frontier cell = geodesic distance from the agent (m) − ``size_weight`` × its
    cluster's size (cells), ignoring cells closer than ``min_distance`` (they would be reached
    before the view changes). Deterministic: ties go to the lowest cell index.
    ``search_memory``: after a relocation, prefer the frontiers of space nobody has searched
    from close range over those of space nobody has seen (off: it helped on calibration
    houses the segmenter never saw, not on ``val``, docs/agent.md). ``beyond_memory`` off:
    explore the agent's own frontiers as if the memory had seen nothing. An agent sets both
    from its :class:`~kgnav.agent.loop.AgentConfig`.
    """

    name = "frontier"
    BAND = 6.0  # m: the first, narrow march's reach beyond what a bonus can take off (_select)

    def __init__(self, size_weight: float = 0.01, min_distance: float = 1.0,
                 min_cells: int = 6, search_memory: bool = False, beyond_memory: bool = True):
        self.size_weight = float(size_weight)
        self.min_distance = float(min_distance)
        self.min_cells = int(min_cells)
        self.search_memory = bool(search_memory)
        self.beyond_memory = bool(beyond_memory)
        self.source_: str | None = None

    def reset(self, seed: int) -> None:
        pass

    def _cost(self, m: EpisodeMap, goal_class: str, lab: np.ndarray, sizes: np.ndarray,
              dist_m: np.ndarray, crop: tuple[int, int, int, int]) -> np.ndarray:
        """Cost of each cell of the ``crop`` window (lower is better)."""
        return dist_m - self.size_weight * sizes[lab]

    def select(self, m: EpisodeMap, pose, goal_class: str, planner: FMMPlanner
               ) -> tuple[int, int] | None:
        """The frontier cell to explore next; :attr:`source_` says which kind
        (:data:`FRONTIER_SOURCES`). Without a remembered map: the frontier of what the agent
        has seen. With one (after a relocation): the frontier of the space nobody has searched
        from close range (with ``search_memory``; the frontier of the space nobody has seen
        without it), then, when the memory leaves none, the frontiers of what the agent itself
        has seen: the memory knows the place, but the goal was not found in it, so look again
        where this episode has not."""
        if m.prior_explored is None:
            self.source_ = "unobserved"
            return self._select(m, pose, goal_class, planner, prior=True)
        if not self.beyond_memory:  # the memory's seen space vouches for nothing: explore
            self.source_ = "episode"  # as if it had not been seen
            return self._select(m, pose, goal_class, planner, prior=False)
        cell = self._select(m, pose, goal_class, planner, prior=True,
                            searched=self.search_memory)
        if cell is not None:
            self.source_ = ("unsearched" if self.search_memory and _beside_known(m, cell)
                            else "unobserved")
            return cell
        self.source_ = "episode"
        return self._select(m, pose, goal_class, planner, prior=False)

    def _select(self, m: EpisodeMap, pose, goal_class: str, planner: FMMPlanner,
                prior: bool, searched: bool = False) -> tuple[int, int] | None:
        lab, sizes = frontiers(m, self.min_cells, prior, searched)
        if not sizes.any():
            return None
        agent = m.to_cell(pose[0], pose[1])
        if not m.inside(*agent):
            return None
        crop = planner.window(m, agent, lab > 0)
        i0, i1, j0, j1 = crop
        # distances from the agent (not to it: the same on a symmetric grid)
        src = np.zeros((i1 - i0, j1 - j0), bool)
        src[agent[0] - i0, agent[1] - j0] = True
        sub = lab[i0:i1, j0:j1]
        front = sub > 0
        # walled in by its own map: the planner's fallbacks, in the planner's order (a
        # map from which no frontier is reachable would give no frontier a distance)
        trav = planner.passable(m, crop, agent, front, prior=prior)
        if trav is None:
            return None
        # First a march that stops BAND m (and what a frontier's bonus can take off its
        # cost) from the agent: when the cheapest frontier inside costs less than any
        # frontier beyond could, it is the cheapest of all, and the march over the whole
        # window (most of the policy's time) is not needed.
        bonus = self._bonus_bound(sizes)
        for band in (self.BAND + bonus, 0.0):
            dist_m = fmm_distance(trav, src, narrow=band / m.resolution) * m.resolution
            ok = front & np.isfinite(dist_m) & (dist_m >= self.min_distance)
            if band and not ok.any():
                continue  # the fallback below must see every frontier
            if not ok.any():
                ok = front & np.isfinite(dist_m)
                if not ok.any():
                    return None
            cost = np.where(ok, self._cost(m, goal_class, sub, sizes, dist_m, crop), np.inf)
            k = int(np.argmin(cost))
            # beyond the band a frontier is more than ``band`` m away: it costs more than
            # band - bonus
            if not band or cost.flat[k] < band - bonus:
                break
        i, j = divmod(k, cost.shape[1])
        return i + i0, j + j0

    def _bonus_bound(self, sizes: np.ndarray) -> float:
        """The most that :meth:`_cost` can take off a frontier's distance (m)."""
        return abs(self.size_weight) * float(np.abs(sizes).max(initial=0))


@register_policy("semantic")
class SemanticFrontierPolicy(FrontierPolicy):
    """Goal-directed frontier choice on the semantic map (the SemExp*+SI analogue).

    A frontier is cheaper the more the map around it (``radius`` metres) shows classes that
    co-occur with the goal: a toilet is looked for near sinks and bathtubs. Co-occurrence is
    ``P(goal seen | class seen)`` over the states of stored Abstract Models
    (:func:`cooccurrence`), so the policy improves as the memory grows; without it, it is the
    plain frontier policy.
    """

    name = "semantic"

    #: m: a remembered object counts as this big a patch of the semantic map
    OBJECT_RADIUS = 0.3

    def __init__(self, size_weight: float = 0.01, min_distance: float = 1.0,
                 min_cells: int = 6, weight: float = 4.0, radius: float = 2.0,
                 search_memory: bool = False, remembered: bool = False):
        super().__init__(size_weight, min_distance, min_cells, search_memory)
        self.weight = float(weight)
        self.radius = float(radius)
        self.remembered = bool(remembered)
        self.cooccurrence_: dict[str, dict[str, float]] = {}

    def fit(self, models) -> SemanticFrontierPolicy:
        """Learn class co-occurrence from Abstract Models."""
        self.cooccurrence_ = cooccurrence(models)
        return self

    def _cost(self, m, goal_class, lab, sizes, dist_m, crop):
        cost = super()._cost(m, goal_class, lab, sizes, dist_m, crop)
        related = self.cooccurrence_.get(goal_class, {})
        if not related:
            return cost
        i0, i1, j0, j1 = crop
        ev = np.zeros((i1 - i0, j1 - j0), np.float32)
        for cls, p in related.items():
            if cls in m.classes:
                ev += p * (m.semantic[m.classes.index(cls), i0:i1, j0:j1] > 0)
        if self.remembered:  # what a relocated memory believes stands there, seen or not
            r = max(1, int(self.OBJECT_RADIUS / m.resolution))
            for cls, x, y, _b in m.prior_objects:
                p = related.get(cls)
                if p:
                    i, j = m.to_cell(x, y)
                    cv2.circle(ev, (j - j0, i - i0), r, float(p), -1)
        k = max(1, int(self.radius / m.resolution))
        # mean related evidence in a (2k+1)^2 window, scaled to "cells of evidence nearby"
        near = cv2.blur(ev, (2 * k + 1, 2 * k + 1)) * (2 * k + 1)
        return cost - self.weight * np.tanh(near / 10.0)

    def _bonus_bound(self, sizes: np.ndarray) -> float:
        return super()._bonus_bound(sizes) + abs(self.weight)  # tanh is at most 1


def cooccurrence(models) -> dict[str, dict[str, float]]:
    """``out[g][c]`` = share of states seeing class ``c`` that also see class ``g``."""
    from collections import Counter

    seen: Counter = Counter()
    both: Counter = Counter()
    for model in models:
        g = model.graph
        for s in model.states():
            classes = {g.nodes[o]["cls"] for o in g.successors(s) if g.nodes[o]["kind"] == "object"}
            for c in classes:
                seen[c] += 1
                for d in classes:
                    if d != c:
                        both[d, c] += 1
    out: dict[str, dict[str, float]] = {}
    for (g_cls, c), n in both.items():
        out.setdefault(g_cls, {})[c] = n / seen[c]
    return out
