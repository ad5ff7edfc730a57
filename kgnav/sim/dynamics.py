"""Agent actions, collisions and optional seeded actuation / odometry noise (named models:
:mod:`kgnav.sim.noise`).

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
    blocked: float = 0.0  # of a collided move, the commanded length it did not travel (m)


@dataclass(frozen=True)
class NoiseModel:
    """Gaussian motion noise per action (zero: noiseless, the default).

    ``forward_sigma``/``lateral_sigma`` (m) and ``forward_turn_sigma`` (rad) perturb a forward
    move; ``turn_sigma`` (rad) perturbs a turn. The rest (all 0 unless set; see
    :func:`kgnav.sim.noise.locobot`): the means of a move's errors (``forward_mean``,
    ``lateral_mean``, positive to the left, ``forward_turn_mean``, counter-clockwise), a turn's
    overshoot in its own direction (``turn_mean``) and the shift of the base while turning
    (``turn_forward_*``, ``turn_lateral_*``), the extra heading error of a move that collides
    (``bump_turn_sigma``), and ``clip``: errors truncated at ``clip`` standard deviations
    from their mean (0: not truncated). Odometry noise is separate: see :class:`Odometry`.
    """

    forward_sigma: float = 0.0
    lateral_sigma: float = 0.0
    forward_turn_sigma: float = 0.0
    turn_sigma: float = 0.0
    forward_mean: float = 0.0
    lateral_mean: float = 0.0
    forward_turn_mean: float = 0.0
    turn_mean: float = 0.0
    turn_forward_sigma: float = 0.0
    turn_lateral_sigma: float = 0.0
    turn_forward_mean: float = 0.0
    turn_lateral_mean: float = 0.0
    bump_turn_sigma: float = 0.0
    clip: float = 0.0

    @classmethod
    def scaled(cls, k: float) -> NoiseModel:
        """A plausible noise model multiplied by ``k`` (k=1: 2.5 cm / 1 cm / 1° / 2°)."""
        return cls(0.025 * k, 0.01 * k, math.radians(1.0) * k, math.radians(2.0) * k)

    @property
    def active(self) -> bool:
        return any(v != 0 for k, v in self.__dict__.items() if k != "clip")


def _draw(rng: np.random.Generator, sigma: float, clip: float) -> float:
    """A zero-mean Gaussian error; truncated at ``clip`` sigmas when ``clip`` > 0."""
    e = float(rng.normal(0.0, sigma))
    return max(-clip * sigma, min(clip * sigma, e)) if clip > 0 else e


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
            sign = 1.0 if action == TURN_LEFT else -1.0
            da = sign * TURN_ANGLE
            if n.turn_sigma > 0:
                da += _draw(self.rng, n.turn_sigma, n.clip)
            da += sign * n.turn_mean  # an overshoot in the turn's direction
            if n.turn_forward_sigma or n.turn_lateral_sigma or n.turn_forward_mean \
                    or n.turn_lateral_mean:  # the base shifts while it turns
                f = n.turn_forward_mean + (_draw(self.rng, n.turn_forward_sigma, n.clip)
                                           if n.turn_forward_sigma else 0.0)
                s_ = n.turn_lateral_mean + (_draw(self.rng, n.turn_lateral_sigma, n.clip)
                                            if n.turn_lateral_sigma else 0.0)
                c, s = math.cos(t), math.sin(t)
                px, py = x + c * f - s * s_, y + s * f + c * s_
                if self.nav.is_navigable(px, py):
                    return StepResult((px, py, wrap_angle(t + da)), False,
                                      math.hypot(px - x, py - y))
            return StepResult((x, y, wrap_angle(t + da)), False, 0.0)
        if action != MOVE_FORWARD:
            raise ValueError(f"unknown action {action!r} (0 stop, 1 forward, 2 left, 3 right)")
        fwd, lat, dth = FORWARD_STEP, 0.0, 0.0
        if n.active:
            fwd += _draw(self.rng, n.forward_sigma, n.clip) if n.forward_sigma else 0.0
            lat = _draw(self.rng, n.lateral_sigma, n.clip) if n.lateral_sigma else 0.0
            dth = _draw(self.rng, n.forward_turn_sigma, n.clip) if n.forward_turn_sigma else 0
            fwd += n.forward_mean
            if n.clip > 0:  # a truncated model always moves a little (as habitat-sim's)
                fwd = max(fwd, 0.05 * FORWARD_STEP)
            lat += n.lateral_mean
            dth += n.forward_turn_mean
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
        travelled = math.hypot(bx - x, by - y)
        if collided and n.bump_turn_sigma > 0:  # a bump twists the base
            dth += _draw(self.rng, n.bump_turn_sigma, n.clip)
        return StepResult((bx, by, wrap_angle(t + dth)), collided, travelled,
                          max(length - travelled, 0.0) if collided else 0.0)


@dataclass(frozen=True)
class OdometryModel:
    """The pose sensor's errors (zero: perfect dead reckoning, the default).

    ``sigma_xy`` (m) / ``sigma_theta`` (rad): a fixed error per step that moved or turned (the
    generic ``odometry=S`` level). The rest grow with the motion (:func:`kgnav.sim.noise.
    locobot`): standard deviations per metre moved along (``forward_per_m``), sideways
    (``lateral_per_m``) and of heading (``theta_per_m``), and per radian turned of heading
    (``theta_per_rad``) and position (``xy_per_rad``); ``slip``/``slip_sigma``: the share of
    a collided move's blocked length the wheels report as motion (clipped to [0, 1])."""

    sigma_xy: float = 0.0
    sigma_theta: float = 0.0
    forward_per_m: float = 0.0
    lateral_per_m: float = 0.0
    theta_per_m: float = 0.0
    theta_per_rad: float = 0.0
    xy_per_rad: float = 0.0
    slip: float = 0.0
    slip_sigma: float = 0.0

    @property
    def active(self) -> bool:
        return any(v != 0 for v in self.__dict__.values())

    @property
    def proportional(self) -> bool:
        return any(v != 0 for k, v in self.__dict__.items() if k not in ("sigma_xy",
                                                                          "sigma_theta"))


class Odometry:
    """Dead-reckoned pose estimate: the true motion of each step plus optional Gaussian noise
    (``sigma_xy``/``sigma_theta`` per step, or an :class:`OdometryModel` as ``model``).

    With no noise it equals the true pose relative to the start.
    """

    def __init__(self, sigma_xy: float = 0.0, sigma_theta: float = 0.0,
                 rng: np.random.Generator | None = None, *, model: OdometryModel | None = None):
        if model is None:
            model = OdometryModel(sigma_xy=sigma_xy, sigma_theta=sigma_theta)
        self.model = model
        self.sigma_xy, self.sigma_theta = model.sigma_xy, model.sigma_theta
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.pose = (0.0, 0.0, 0.0)

    def reset(self) -> None:
        self.pose = (0.0, 0.0, 0.0)

    def update(self, before, after, blocked: float = 0.0) -> np.ndarray:
        """Advance by the world motion ``before -> after`` (``blocked``: of a collided move,
        the length the wheels turned without moving); returns the estimate (3,)."""
        d = relative_pose(before, after)
        if d[0] != 0 or d[1] != 0:  # noise accrues only when the agent moves or turns
            if self.sigma_xy > 0:
                d[:2] += self.rng.normal(0.0, self.sigma_xy, 2)
        if d[2] != 0 and self.sigma_theta > 0:
            d[2] += float(self.rng.normal(0.0, self.sigma_theta))
        m = self.model
        if m.proportional:
            if blocked > 0 and (m.slip > 0 or m.slip_sigma > 0):  # the wheels slip on
                share = m.slip + (float(self.rng.normal(0.0, m.slip_sigma))
                                  if m.slip_sigma > 0 else 0.0)
                d[0] += blocked * min(max(share, 0.0), 1.0)
            dist, turned = math.hypot(d[0], d[1]), abs(float(d[2]))
            if dist > 0 or turned > 0:
                e = self.rng.normal(0.0, 1.0, 3)
                sxy = m.xy_per_rad * turned
                d[0] += e[0] * math.hypot(m.forward_per_m * dist, sxy)
                d[1] += e[1] * math.hypot(m.lateral_per_m * dist, sxy)
                d[2] += e[2] * math.hypot(m.theta_per_m * dist, m.theta_per_rad * turned)
        self.pose = compose(self.pose, d)
        return np.array(self.pose, np.float64)
