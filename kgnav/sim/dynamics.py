"""Agent actions, collisions and optional seeded actuation / odometry noise.

Actions are numbered as in Habitat: 0 ``stop``, 1 ``move_forward`` (0.25 m), 2 ``turn_left``
(+30°, counter-clockwise), 3 ``turn_right`` (-30°). A forward move is checked against the
ground-truth navigable map in 2.5 cm sub-steps and stops at the last free sub-step: a collision
stops the motion (no sliding along walls).

>>> from kgnav.sim.house import generate_house
>>> from kgnav.sim.navmesh import NavMap
>>> d = Dynamics(NavMap.from_scene(generate_house(3)))
>>> d.step((1.0, 1.0, 0.0), TURN_LEFT).pose[2]  # doctest: +ELLIPSIS
0.5235...
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from kgnav.sim.navmesh import NavMap

STOP, MOVE_FORWARD, TURN_LEFT, TURN_RIGHT = 0, 1, 2, 3
ACTION_NAMES: tuple[str, ...] = ("stop", "move_forward", "turn_left", "turn_right")
FORWARD_STEP = 0.25  # m
TURN_ANGLE = math.radians(30.0)
_SUBSTEP = 0.025  # m


def wrap_angle(a: float) -> float:
    """Angle wrapped to (-pi, pi]."""
    a = math.fmod(a + math.pi, 2 * math.pi)
    if a <= 0:
        a += 2 * math.pi
    return a - math.pi


def relative_pose(origin, pose) -> np.ndarray:
    """``pose`` (world x, y, theta) expressed in the frame of ``origin`` (float64 (3,))."""
    ox, oy, ot = origin
    c, s = math.cos(ot), math.sin(ot)
    dx, dy = pose[0] - ox, pose[1] - oy
    return np.array([c * dx + s * dy, -s * dx + c * dy, wrap_angle(pose[2] - ot)], np.float64)


def compose(pose, delta) -> tuple[float, float, float]:
    """Apply ``delta`` (expressed in ``pose``'s frame) to ``pose``."""
    x, y, t = pose
    c, s = math.cos(t), math.sin(t)
    return (x + c * delta[0] - s * delta[1], y + s * delta[0] + c * delta[1],
            wrap_angle(t + delta[2]))


@dataclass(frozen=True)
class StepResult:
    """Outcome of one action: the new world pose, whether it collided, distance travelled."""

    pose: tuple[float, float, float]
    collided: bool
    travelled: float


@dataclass(frozen=True)
class NoiseModel:
    """Gaussian noise, standard deviations per action (zero: noiseless, the default).

    ``forward_sigma``/``lateral_sigma`` (m) and ``forward_turn_sigma`` (rad) perturb a forward
    move; ``turn_sigma`` (rad) perturbs a turn. Odometry noise is separate: see
    :class:`Odometry`.
    """

    forward_sigma: float = 0.0
    lateral_sigma: float = 0.0
    forward_turn_sigma: float = 0.0
    turn_sigma: float = 0.0

    @classmethod
    def scaled(cls, k: float) -> NoiseModel:
        """A plausible noise model multiplied by ``k`` (k=1: 2.5 cm / 1 cm / 1° / 2°)."""
        return cls(0.025 * k, 0.01 * k, math.radians(1.0) * k, math.radians(2.0) * k)

    @property
    def active(self) -> bool:
        return any(v > 0 for v in (self.forward_sigma, self.lateral_sigma,
                                   self.forward_turn_sigma, self.turn_sigma))


class Dynamics:
    """Moves an agent on a :class:`NavMap`; ``rng`` drives the actuation noise."""

    def __init__(self, nav: NavMap, noise: NoiseModel | None = None,
                 rng: np.random.Generator | None = None):
        self.nav = nav
        self.noise = noise or NoiseModel()
        self.rng = rng if rng is not None else np.random.default_rng(0)

    def step(self, pose, action: int) -> StepResult:
        """Apply ``action`` to world ``pose`` (x, y, theta)."""
        x, y, t = (float(v) for v in pose)
        n = self.noise
        if action == STOP:
            return StepResult((x, y, t), False, 0.0)
        if action in (TURN_LEFT, TURN_RIGHT):
            da = TURN_ANGLE if action == TURN_LEFT else -TURN_ANGLE
            if n.turn_sigma > 0:
                da += float(self.rng.normal(0.0, n.turn_sigma))
            return StepResult((x, y, wrap_angle(t + da)), False, 0.0)
        if action != MOVE_FORWARD:
            raise ValueError(f"unknown action {action!r} (0 stop, 1 forward, 2 left, 3 right)")
        fwd, lat, dth = FORWARD_STEP, 0.0, 0.0
        if n.active:
            fwd += float(self.rng.normal(0.0, n.forward_sigma)) if n.forward_sigma else 0.0
            lat = float(self.rng.normal(0.0, n.lateral_sigma)) if n.lateral_sigma else 0.0
            dth = float(self.rng.normal(0.0, n.forward_turn_sigma)) if n.forward_turn_sigma else 0
        c, s = math.cos(t), math.sin(t)
        ex, ey = c * fwd - s * lat, s * fwd + c * lat
        length = math.hypot(ex, ey)
        k = max(int(math.ceil(length / _SUBSTEP)), 1)
        bx, by = x, y
        collided = False
        for i in range(1, k + 1):
            px, py = x + ex * i / k, y + ey * i / k
            if not self.nav.is_navigable(px, py):
                collided = True
                break
            bx, by = px, py
        return StepResult((bx, by, wrap_angle(t + dth)), collided, math.hypot(bx - x, by - y))


class Odometry:
    """Dead-reckoned pose estimate: the true motion of each step plus optional Gaussian noise.

    With ``sigma_xy = sigma_theta = 0`` it equals the true pose relative to the start.
    """

    def __init__(self, sigma_xy: float = 0.0, sigma_theta: float = 0.0,
                 rng: np.random.Generator | None = None):
        self.sigma_xy, self.sigma_theta = sigma_xy, sigma_theta
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.pose = (0.0, 0.0, 0.0)

    def reset(self) -> None:
        self.pose = (0.0, 0.0, 0.0)

    def update(self, before, after) -> np.ndarray:
        """Advance by the world motion ``before -> after``; returns the estimate (3,)."""
        d = relative_pose(before, after)
        if d[0] != 0 or d[1] != 0:  # noise accrues only when the agent moves or turns
            if self.sigma_xy > 0:
                d[:2] += self.rng.normal(0.0, self.sigma_xy, 2)
        if d[2] != 0 and self.sigma_theta > 0:
            d[2] += float(self.rng.normal(0.0, self.sigma_theta))
        self.pose = compose(self.pose, d)
        return np.array(self.pose, np.float64)
