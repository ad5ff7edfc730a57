"""The oracle: ground-truth map and pose, shortest path to the nearest goal instance.

The upper bound of every table (the paper's "SMNet (GT)" analogue): it reads the simulator's
navigable map, true pose and object positions, follows the Fast Marching distance field toward
the goal instances and stops as soon as it stands within ``stop_distance`` of one (success is
1 m). Its failures measure the task's own limits (the 500-step budget), not perception or memory.

Greedy steering down the distance field can wedge the agent's disc against a corner or a door
frame, where every ``move_forward`` is blocked. The oracle notices (a blocked move, or no progress
for a while) and then searches short action sequences with the simulator's motion rule (a
forward move advances in 2.5 cm sub-steps and stops at the last navigable one) for one that
gets it closer, so it never pushes into an obstacle until the step limit.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from kgnav.agent.planner import descend, fmm_distance, steer
from kgnav.memory.model import ACTIONS

_FORWARD, _LEFT, _RIGHT = (ACTIONS.index(a) for a in ("move_forward", "turn_left", "turn_right"))


class OracleAgent:
    """Acts from ground truth (same ``reset``/``act`` interface as
    :class:`~kgnav.agent.loop.ObjectNavAgent`).

    ``env`` must offer ``navigable_map()`` (a grid with ``to_cell``, ``to_world``, ``snap``,
    ``is_navigable``, ``goal_region`` and ``l2_to_class``) and ``world_pose``. ``step`` and
    ``turn_deg`` are the environment's forward step (m) and turn angle; ``search_depth`` bounds
    the recovery search (actions).
    """

    def __init__(self, env, stop_distance: float = 0.95, lookahead: int = 6,
                 turn_tolerance_deg: float = 20.0, step: float = 0.25, turn_deg: float = 30.0,
                 search_depth: int = 16, patience: int = 20, search_nodes: int = 6000):
        self.env = env
        self.stop_distance = float(stop_distance)
        self.lookahead = int(lookahead)
        self.turn_tolerance = math.radians(turn_tolerance_deg)
        self.step_length = float(step)
        self.turn = math.radians(turn_deg)
        self.search_depth = int(search_depth)
        self.search_nodes = int(search_nodes)
        self.patience = int(patience)
        self._fields: dict = {}
        self.relocation_ = None

    def reset(self, goal_class: str, **_ignored) -> None:
        self.goal = goal_class
        self.step_ = 0
        nav = self.env.navigable_map()
        key = (id(nav), goal_class)
        if key not in self._fields:
            # aim well inside the stop radius; travel time keeps off walls (a grazing path
            # catches door frames)
            region = nav.goal_region(goal_class, 0.8)
            if not region.any():
                region = nav.goal_region(goal_class, self.stop_distance)
            self._fields[key] = fmm_distance(nav.grid, region, 4.0)
        self._field = self._fields[key]
        self._plan: list[int] = []
        self._last: tuple | None = None  # (pose, action) of the previous step
        self._best = (math.inf, 0)  # lowest field value reached, and when

    def act(self, obs) -> int:
        self.step_ += 1
        nav = self.env.navigable_map()
        pose = tuple(float(v) for v in self.env.world_pose)
        if nav.l2_to_class(pose[0], pose[1], self.goal) <= self.stop_distance:
            return ACTIONS.index("stop")
        here = self._value(nav, pose)
        if here < self._best[0] - 0.05:
            self._best = (here, self.step_)
        blocked = (self._last is not None and self._last[1] == _FORWARD
                   and math.dist(self._last[0][:2], pose[:2]) < 0.01)
        if blocked or self.step_ - self._best[1] > self.patience:
            self._plan = self._search(nav, pose, here)
            self._best = (here, self.step_)
        action = self._plan.pop(0) if self._plan else self._greedy(nav, pose)
        self._last = (pose, action)
        return action

    # ------------------------------------------------------------------ helpers
    def _value(self, nav, pose) -> float:
        i, j = nav.to_cell(pose[0], pose[1])
        h, w = self._field.shape
        return float(self._field[i, j]) if 0 <= i < h and 0 <= j < w else math.inf

    def _greedy(self, nav, pose) -> int:
        f = self._field
        try:
            i, j = nav.snap(pose[0], pose[1])
        except ValueError:
            return _LEFT
        path = descend(f, i, j, self.lookahead)
        if path:
            i, j = path[-1]
        wx, wy = nav.to_world(i, j)
        if math.hypot(wx - pose[0], wy - pose[1]) < 1e-6:
            return ACTIONS.index("stop") if np.isfinite(f[i, j]) else _LEFT
        return ACTIONS.index(steer(pose, (wx, wy), self.turn_tolerance))

    def _move(self, nav, pose, action: int):
        """The simulator's motion rule, noise-free: the pose after ``action``."""
        x, y, t = pose
        if action == _LEFT:
            return x, y, t + self.turn
        if action == _RIGHT:
            return x, y, t - self.turn
        k = max(int(math.ceil(self.step_length / 0.025)), 1)
        ex, ey = math.cos(t) * self.step_length, math.sin(t) * self.step_length
        bx, by = x, y
        for s in range(1, k + 1):
            px, py = x + ex * s / k, y + ey * s / k
            if not nav.is_navigable(px, py):
                break
            bx, by = px, py
        return bx, by, t

    def _search(self, nav, pose, here: float) -> list[int]:
        """Breadth-first over action sequences (up to ``search_depth`` actions and
        ``search_nodes`` poses) for the one ending lowest on the distance field; poses are
        merged on a 5 cm / one-turn lattice, so a way out may first lead back. Returns its
        actions, or a turn when nothing gets closer."""
        def key(p):
            return (round(p[0] / 0.05), round(p[1] / 0.05),
                    round(p[2] / self.turn) % round(2 * math.pi / self.turn))

        seen = {key(pose)}
        queue = deque([(pose, [])])
        best, best_plan = here - 0.1, None
        while queue and len(seen) < self.search_nodes:
            p, plan = queue.popleft()
            if len(plan) >= self.search_depth:
                continue
            for a in (_FORWARD, _LEFT, _RIGHT):
                q = self._move(nav, p, a)
                k = key(q)
                if k in seen:
                    continue
                seen.add(k)
                v = self._value(nav, q)
                if v < best:
                    best, best_plan = v, plan + [a]
                queue.append((q, plan + [a]))
        return best_plan or [_LEFT]
