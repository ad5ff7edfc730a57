"""The oracle: ground-truth map and pose, shortest path to the nearest goal instance.

The upper bound of every table (the paper's "SMNet (GT)" analogue): it reads the simulator's
navigable map, true pose and object positions, follows the Fast Marching distance field to the
closest point within ``stop_distance`` of any goal instance and stops there. Its failures measure
the task's own limits (actuation, the 500-step budget), not perception or memory.
"""

from __future__ import annotations

import math

import numpy as np

from kgnav.agent.planner import descend, fmm_distance, steer
from kgnav.model import ACTIONS


class OracleAgent:
    """Acts in a :class:`kgnav.sim.ObjectNavEnv` from its ground truth (same ``reset``/``act``
    interface as :class:`~kgnav.agent.loop.ObjectNavAgent`)."""

    def __init__(self, env, stop_distance: float = 0.8, lookahead: int = 6,
                 turn_tolerance_deg: float = 20.0):
        self.env = env
        self.stop_distance = float(stop_distance)
        self.lookahead = int(lookahead)
        self.turn_tolerance = math.radians(turn_tolerance_deg)
        self._fields: dict = {}
        self.relocation_ = None

    def reset(self, goal_class: str, **_ignored) -> None:
        self.goal = goal_class
        self.step_ = 0
        nav = self.env.navigable_map()
        key = (id(nav), goal_class)
        if key not in self._fields:
            # travel time that keeps off walls: a grazing path catches door frames
            self._fields[key] = fmm_distance(nav.grid, nav.goal_region(goal_class,
                                                                       self.stop_distance), 4.0)
        self._field = self._fields[key]

    def act(self, obs) -> int:
        self.step_ += 1
        nav = self.env.navigable_map()
        x, y, theta = self.env.world_pose
        if nav.l2_to_class(x, y, self.goal) <= self.stop_distance:
            return ACTIONS.index("stop")
        f = self._field
        try:
            i, j = nav.snap(x, y)
        except ValueError:
            return ACTIONS.index("turn_left")
        path = descend(f, i, j, self.lookahead)
        if path:
            i, j = path[-1]
        wx, wy = nav.to_world(i, j)
        if math.hypot(wx - x, wy - y) < 1e-6:
            return ACTIONS.index("stop" if np.isfinite(f[i, j]) else "turn_left")
        return ACTIONS.index(steer((x, y, theta), (wx, wy), self.turn_tolerance))
