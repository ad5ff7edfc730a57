"""Fast Marching planner on the episode map (scikit-fmm), as in Active Neural SLAM.

Unexplored cells count as navigable (the paper: this is what lets the agent discover new
space); obstacles, plus cells where the agent bumped into something, are inflated by the agent
radius. Distances to the goal cells are computed by Fast Marching on a crop of the map around
what is explored, the agent and the goal (with a remembered model's geometry on the map,
``unknown_speed`` < 1 makes cells neither the agent nor the memory has seen slower, so the
plan prefers the way the memory knows to a shortcut through space that may hold a wall), and
reused for a few steps unless the goal changes,
the agent collides, leaves the crop, or the path ahead becomes blocked. The action turns the
agent toward a short-term goal a few cells down the distance field, or moves it forward.

>>> import numpy as np
>>> from kgnav.agent.mapping import MapBuilder
>>> from kgnav.agent.camera import Camera
>>> m = MapBuilder(Camera(), size=120).reset()
>>> goal = np.zeros((120, 120), bool); goal[60, 100] = True   # 2 m straight ahead
>>> p = FMMPlanner().plan(m, (0.0, 0.0, 0.0), goal, key="demo")
>>> p.action, round(p.distance, 2)
('move_forward', 2.0)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
import skfmm

from kgnav.agent.mapping import EpisodeMap

_NEIGHBOURS = [(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)]


def disc(radius_cells: int) -> np.ndarray:
    """A filled disc structuring element of the given radius (cells)."""
    r = max(0, int(radius_cells))
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))


def fmm_distance(traversable: np.ndarray, targets: np.ndarray, clearance: float = 0.0,
                 speed: np.ndarray | None = None, narrow: float = 0.0) -> np.ndarray:
    """Geodesic distance in cells from every traversable cell to the nearest target cell.

    Target cells read 0 and are always passable; cells that are not traversable or cannot reach
    a target read ``inf``. With ``clearance`` (cells) > 0 the result is a travel time in which
    cells nearer than that to a non-traversable cell are slower (down to a quarter speed), so
    paths keep off walls and corners instead of grazing them. ``speed`` (same shape, in (0, 1])
    makes it a travel time with that speed per cell (times the clearance slowdown).
    ``narrow`` > 0 stops the march there: cells whose value would be at least that read
    ``inf``, every other cell reads exactly what the whole march gives it (Fast Marching
    settles cells in order of their value), at a fraction of the cost. With a ``speed``
    (a travel time) the march may stop short of it: cells up to 2 below it can read
    ``inf`` too (1.43 the most seen in 3000 random maps).

    >>> trav = np.ones((1, 5), bool); goal = np.zeros((1, 5), bool); goal[0, 0] = True
    >>> half = np.full((1, 5), 0.5)
    >>> [round(float(fmm_distance(trav, goal, speed=v)[0, 4]), 2) for v in (None, half)]
    [4.0, 7.5]
    """
    out = np.full(traversable.shape, np.inf)
    if not targets.any():
        return out
    phi = np.where(targets, -1.0, 1.0)
    free = traversable | targets
    try:
        if clearance > 0:
            room = cv2.distanceTransform(free.astype(np.uint8), cv2.DIST_L2, 3)
            slow = np.clip(room / clearance, 0.25, 1.0)
            speed = slow if speed is None else slow * speed
        if speed is not None:
            d = skfmm.travel_time(np.ma.MaskedArray(phi, ~free), speed, dx=1.0,
                                  narrow=narrow)
        else:
            d = skfmm.distance(np.ma.MaskedArray(phi, ~free), dx=1.0, narrow=narrow)
    except ValueError:  # no free cell borders a target: only the targets themselves
        out[targets] = 0.0
        return out
    vals = np.ma.filled(d.astype(float), np.inf) + 0.5
    vals[targets] = 0.0
    out[free] = vals[free]
    return out


def reachable(free: np.ndarray, cell: tuple[int, int], cells: np.ndarray) -> bool:
    """Whether a cell of the mask ``cells`` lies in the 4-connected region of ``free`` that
    holds ``cell``: exactly when Fast Marching between them over ``free`` ends finite (its
    stencil is 4-connected). One connected-components pass costs a small part of a march,
    and the planner's marches that do not reach the agent (walled in by its own inflated
    map, or a goal sealed off) are about half of all it would run.

    >>> free = np.ones((3, 5), bool); free[:, 2] = False
    >>> goal = np.zeros((3, 5), bool); goal[1, 4] = True
    >>> reachable(free, (1, 0), goal), reachable(free | goal, (1, 3), goal)
    (False, True)
    """
    if not free[cell]:
        return False
    _, lab = cv2.connectedComponents(free.astype(np.uint8), connectivity=4)
    return bool((lab[cells] == lab[cell]).any())


def descend(field: np.ndarray, i: int, j: int, steps: int) -> list[tuple[int, int]]:
    """Up to ``steps`` cells of steepest descent of ``field`` from cell (i, j), over the
    8-neighbourhood; stops early at a local minimum. The start cell is not included."""
    h, w = field.shape
    path = []
    for _ in range(steps):
        best, bi, bj = field[i, j], i, j
        for di, dj in _NEIGHBOURS:
            a, b = i + di, j + dj
            if 0 <= a < h and 0 <= b < w and field[a, b] < best:
                best, bi, bj = field[a, b], a, b
        if (bi, bj) == (i, j):
            break
        i, j = bi, bj
        path.append((i, j))
    return path


def steer(pose, waypoint: tuple[float, float], tolerance: float) -> str:
    """The action toward ``waypoint`` from ``pose`` (x, y, theta): turn when the heading error
    exceeds ``tolerance`` (radians), else move forward."""
    err = math.atan2(waypoint[1] - pose[1], waypoint[0] - pose[0]) - pose[2]
    err = math.atan2(math.sin(err), math.cos(err))
    if err > tolerance:
        return "turn_left"
    if err < -tolerance:
        return "turn_right"
    return "move_forward"


@dataclass(frozen=True)
class Plan:
    """One planning step: the action, whether the agent is in the goal cells, the remaining
    geodesic distance (m, ``inf`` if unreachable) and the short-term goal (episode frame)."""

    action: str
    reached: bool
    distance: float
    waypoint: tuple[float, float] | None


class FMMPlanner:
    """Plans on an :class:`EpisodeMap` toward a boolean goal mask of the same shape.

    ``key`` identifies the goal (a new key forces replanning); ``replan_every`` bounds how many
    steps a distance field is reused; ``lookahead`` is how many cells down the field the
    short-term goal lies; ``turn_tolerance_deg`` is the heading error tolerated before turning;
    ``unknown_speed`` (in (0, 1]) is how fast unseen cells count once the map holds a
    remembered prior (1: as fast as known free space, the memory-less planner's view);
    ``prior_inflation`` (m; None: as the agent's own obstacles, never more) how far the
    remembered obstacles grow for the agent's centre: a memory laid on by a relocation and
    drawn from many episodes' drifting profiles has its walls a little thick and a little off
    already, and growing them by the full radius again closes doorways the agent fits
    through.
    """

    def __init__(
        self,
        agent_radius: float = 0.18,
        margin: float = 0.05,
        lookahead: int = 8,
        turn_tolerance_deg: float = 20.0,
        replan_every: int = 10,
        crop_margin: float = 2.0,
        unknown_speed: float = 1.0,
        prior_inflation: float | None = None,
    ):
        if not 0 < unknown_speed <= 1:
            raise ValueError(f"unknown_speed must be in (0, 1], got {unknown_speed}")
        if prior_inflation is not None and not 0 <= prior_inflation < math.inf:
            raise ValueError(f"prior_inflation must be None or a finite length >= 0 m, "
                             f"got {prior_inflation}")
        self.prior_inflation = prior_inflation
        self.agent_radius = float(agent_radius)
        self.margin = float(margin)
        self.lookahead = int(lookahead)
        self.turn_tolerance = math.radians(turn_tolerance_deg)
        self.replan_every = int(replan_every)
        self.crop_margin = float(crop_margin)
        self.unknown_speed = float(unknown_speed)
        self.reset()

    def reset(self) -> None:
        self._cache = None
        self._dirty = True

    # ------------------------------------------------------------------ map edits
    def note_collision(self, m: EpisodeMap, pose) -> None:
        """Mark the cells just ahead of the agent blocked (``m.bumped``): the map missed an
        obstacle there."""
        x, y, t = pose
        c, s = math.cos(t), math.sin(t)
        pts = []
        for f in (0.25, 0.3):  # a narrow mark: a wide one can seal a doorway once inflated
            for lat in (-0.05, 0.05):
                pts.append(m.to_cell(x + c * f - s * lat, y + s * f + c * lat))
        for i, j in pts:
            if m.inside(i, j):
                m.bumped[i, j] = 1
        self._dirty = True

    def window(self, m: EpisodeMap, agent: tuple[int, int], goal: np.ndarray, *,
              wide: bool = False):
        """The window planned over: around the agent and the goal (``wide``: and everything
        explored) with a margin; Fast Marching cost grows with its area."""
        mask = goal | m.explored.astype(bool) if wide else goal
        rows = np.flatnonzero(mask.any(axis=1))
        cols = np.flatnonzero(mask.any(axis=0))
        pad = int(self.crop_margin / m.resolution)
        i0 = min(rows.min() if rows.size else agent[0], agent[0]) - pad
        i1 = max(rows.max() if rows.size else agent[0], agent[0]) + pad + 1
        j0 = min(cols.min() if cols.size else agent[1], agent[1]) - pad
        j1 = max(cols.max() if cols.size else agent[1], agent[1]) + pad + 1
        H, W = m.shape
        return max(i0, 0), min(i1, H), max(j0, 0), min(j1, W)

    def traversable(self, m: EpisodeMap, crop, agent: tuple[int, int], *,
                    squeeze: bool = False, prior: bool = True, bare: bool = False
                    ) -> np.ndarray:
        """Cells of ``crop`` the agent's centre may occupy (unexplored counts as free).

        ``squeeze`` inflates obstacles by less than the agent radius: the fallback when the
        agent is walled in by its own conservative map (a doorway closed by inflation).
        ``bare`` does not inflate them at all: the last resort when even that leaves the
        agent no way out (its bump marks and a wall seal the patch it stands on; bumping
        on the way marks what really blocks). ``prior=False`` leaves out the obstacles a
        remembered model put on the map.
        """
        i0, i1, j0, j1 = crop
        trav = self._free(m, crop, self._inflation(m, squeeze=squeeze, bare=bare), prior)
        # the agent's own cell and a little around it stay free, or it could never leave
        ai, aj, r = agent[0] - i0, agent[1] - j0, self._PATCH
        trav[max(ai - r, 0):ai + r + 1, max(aj - r, 0):aj + r + 1] = True
        return trav

    _PATCH = 2  # cells each side of the agent's own that always count as free

    def _free(self, m: EpisodeMap, crop, k: int, prior: bool = True) -> np.ndarray:
        """Cells of ``crop`` clear of the obstacles grown by ``k`` cells (the remembered ones,
        with ``prior``, by at most :attr:`prior_inflation`)."""
        if not prior or m.prior_obstacle is None or self.prior_inflation is None:
            return cv2.dilate(m.blocked(crop, prior=prior), disc(k)) == 0
        kp = min(k, math.ceil(self.prior_inflation / m.resolution - 1e-9))
        i0, i1, j0, j1 = crop
        own = cv2.dilate(m.blocked(crop, prior=False), disc(k)) == 0
        return own & (cv2.dilate(m.prior_obstacle[i0:i1, j0:j1], disc(kp)) == 0)

    def _inflation(self, m: EpisodeMap, *, squeeze: bool = False, bare: bool = False) -> int:
        """How many cells obstacles grow by for the agent's centre (see :meth:`traversable`)."""
        if bare:
            return 0
        return math.ceil((self.agent_radius + (-self.margin if squeeze else self.margin))
                         / m.resolution)

    def path_blocked(self, m: EpisodeMap, crop, agent: tuple[int, int],
                     path: list[tuple[int, int]]) -> bool:
        """Whether a cell of ``path`` (map cells inside ``crop``) is one :meth:`traversable`
        over ``crop`` would rule out. The same answer, from the obstacles within an
        inflation radius of the path only: checked every step, it must not inflate the
        whole window."""
        if not path:
            return False
        i0, i1, j0, j1 = crop
        k = self._inflation(m)
        rows, cols = [p[0] for p in path], [p[1] for p in path]
        w0, w2 = max(min(rows) - k, i0), max(min(cols) - k, j0)
        win = (w0, min(max(rows) + k + 1, i1), w2, min(max(cols) + k + 1, j1))
        trav = self._free(m, win, k)
        return any(not trav[i - w0, j - w2] for i, j in path
                   if max(abs(i - agent[0]), abs(j - agent[1])) > self._PATCH)

    def passable(self, m: EpisodeMap, crop, agent: tuple[int, int], targets: np.ndarray, *,
                 prior: bool = True, drop_prior: bool = False, enter_targets: bool = False
                 ) -> np.ndarray | None:
        """The first of the traversable maps over ``crop`` (:meth:`traversable`) from which
        the agent reaches a cell of ``targets`` (crop-shaped), in the one order both the
        planner and the frontier policy fall back in; None when none reaches one.

        The order: obstacles inflated by the agent's radius, then squeezed (a doorway that
        inflation closed); with ``drop_prior``, then inflated without the remembered
        obstacles (a memory's coarse walls guide the way but never rule a goal out: a doorway
        its range profiles caught only at an angle looks closed); last, when the agent is
        :meth:`sealed` in, with obstacles not inflated (``bare``): its own when its own map
        seals it, its own and the memory's when the memory's does. A planner and a policy
        that fell back differently would disagree: the policy would pick a frontier the
        planner refuses, and the agent would turn in place. ``prior``: with the remembered
        obstacles to begin with; ``enter_targets``: the targets are passable themselves
        (Fast Marching's zero set) rather than cells to reach (a march from the agent).
        """
        here = (agent[0] - crop[0], agent[1] - crop[2])

        def reaches(trav: np.ndarray) -> bool:
            return reachable(trav | targets if enter_targets else trav, here, targets)

        remembered = prior and m.prior_obstacle is not None
        tries = [{"prior": prior}, {"prior": prior, "squeeze": True}]
        if drop_prior and remembered:
            tries.append({"prior": False})
        for kw in tries:
            trav = self.traversable(m, crop, agent, **kw)
            if reaches(trav):
                return trav
        # walled in: by the agent's own map first when the memory may be dropped, then as
        # far as the memory knows (the space its own map leaves open was seen by the memory,
        # so nothing is left to explore there)
        for p in ((False, True) if drop_prior and remembered
                  else (False,) if drop_prior else (prior,)):
            if self.sealed(m, crop, agent, prior=p):
                trav = self.traversable(m, crop, agent, prior=p, bare=True)
                if reaches(trav):
                    return trav
        return None

    def distances(self, m: EpisodeMap, crop, agent: tuple[int, int],
                  targets: np.ndarray) -> np.ndarray:
        """Fast Marching distances (cells) over ``crop`` to ``targets`` (crop-shaped), on the
        first map of :meth:`passable`'s order (remembered obstacles dropped before the bare
        one) that reaches them; ``inf`` everywhere when none does."""
        trav = self.passable(m, crop, agent, targets, drop_prior=True, enter_targets=True)
        if trav is None:
            return np.full(targets.shape, np.inf)
        return fmm_distance(trav, targets, speed=self._speed(m, crop))

    def sealed(self, m: EpisodeMap, crop, agent: tuple[int, int], *, prior: bool = True
               ) -> bool:
        """Whether the squeezed map walls the agent in: the cells it can reach in ``crop``
        hold nothing unexplored and do not run off the window, so no frontier and no way
        on. Only then is planning on the bare obstacles worth its risk (a goal merely out of
        reach, with space left to explore, would otherwise stay a goal, and the agent would
        push at a gap it does not fit)."""
        trav = self.traversable(m, crop, agent, squeeze=True, prior=prior).astype(np.uint8)
        _, lab = cv2.connectedComponents(trav, connectivity=4)
        mine = lab == lab[agent[0] - crop[0], agent[1] - crop[2]]
        if mine[0].any() or mine[-1].any() or mine[:, 0].any() or mine[:, -1].any():
            return False
        return not (mine & (m.known(prior, crop=crop) == 0)).any()

    def _speed(self, m: EpisodeMap, crop) -> np.ndarray | None:
        """Per-cell speed over ``crop``: None (uniform) without a remembered prior."""
        if self.unknown_speed >= 1.0 or m.prior_explored is None:
            return None
        return np.where(m.known(crop=crop) > 0, 1.0, self.unknown_speed)

    # ------------------------------------------------------------------ planning
    def plan(self, m: EpisodeMap, pose, goal: np.ndarray, key=None) -> Plan:
        """The next action toward ``goal`` (bool mask over the map) from ``pose``."""
        agent = m.to_cell(pose[0], pose[1])
        if not m.inside(*agent):
            return Plan("turn_left", False, math.inf, None)
        c = self._cache
        fresh = (
            c is None
            or self._dirty
            or c["key"] != key
            or c["generation"] != m.generation  # the map grew: cell indices moved
            or c["age"] >= self.replan_every
            or not (c["crop"][0] <= agent[0] < c["crop"][1]
                    and c["crop"][2] <= agent[1] < c["crop"][3])
        )
        if not fresh:
            i0, j0 = c["crop"][0], c["crop"][2]
            # the old field may not cover where the agent stands now (its free patch moved)
            fresh = not math.isfinite(c["dist"][agent[0] - i0, agent[1] - j0])
        if not fresh:
            fresh = self.path_blocked(m, c["crop"], agent,
                                      self._descend(c["dist"], agent, c["crop"]))
        if fresh:
            crop = self.window(m, agent, goal)
            i0, i1, j0, j1 = crop
            dist = self.distances(m, crop, agent, goal[i0:i1, j0:j1])
            if not math.isfinite(dist[agent[0] - i0, agent[1] - j0]):
                # the way round may leave the tight window: plan over all that is known
                crop = self.window(m, agent, goal, wide=True)
                i0, i1, j0, j1 = crop
                dist = self.distances(m, crop, agent, goal[i0:i1, j0:j1])
            c = self._cache = {"key": key, "crop": crop, "dist": dist, "age": 0,
                               "generation": m.generation}
            self._dirty = False
        c["age"] += 1
        return self._act(m, pose, agent, c)

    def _descend(self, dist: np.ndarray, agent, crop) -> list[tuple[int, int]]:
        i0, j0 = crop[0], crop[2]
        path = descend(dist, agent[0] - i0, agent[1] - j0, self.lookahead)
        return [(i + i0, j + j0) for i, j in path]

    def _act(self, m: EpisodeMap, pose, agent, c) -> Plan:
        i0, j0 = c["crop"][0], c["crop"][2]
        d_here = c["dist"][agent[0] - i0, agent[1] - j0]
        if d_here == 0.0:
            return Plan("stop", True, 0.0, None)
        if not math.isfinite(d_here):
            return Plan("turn_left", False, math.inf, None)
        path = self._descend(c["dist"], agent, c["crop"])
        if not path:
            return Plan("turn_left", False, float(d_here) * m.resolution, None)
        wx, wy = m.to_xy(*path[-1])
        return Plan(steer(pose, (wx, wy), self.turn_tolerance), False,
                    float(d_here) * m.resolution, (wx, wy))
