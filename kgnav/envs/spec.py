"""What an environment declares about itself: camera, actions, class vocabulary.

The agent builds its camera model, its map's class channels and its action geometry (look-around
turn counts, bump threshold) from an :class:`EnvSpec`, so nothing in :mod:`kgnav.agent` needs to
know which simulator produced the frames.

>>> spec = EnvSpec("grid", CameraSpec(64, 48, hfov_deg=90.0), ActionSpec(turn_deg=45.0),
...                classes=("crate", "lamp"))
>>> spec.actions.full_turn, spec.actions.index("turn_left"), spec.class_id("lamp")
(8, 2, 2)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from kgnav.errors import KgnavError

#: The ObjectNav action names, in Habitat's (and kgnav's simulator's) index order.
ACTION_NAMES = ("stop", "move_forward", "turn_left", "turn_right")


class EnvSpecError(KgnavError, ValueError):
    """An environment declares an impossible spec or breaks the protocol it declared."""


@dataclass(frozen=True)
class CameraSpec:
    """The RGB-D camera: image size, intrinsics and mounting.

    Give the focal length as ``hfov_deg`` (horizontal field of view), ``vfov_deg`` (vertical;
    square pixels assumed) or ``fx`` / ``fy`` in pixels. ``cx``, ``cy``: the principal point in
    pixels (default: the image centre). ``pitch_deg``: the optical axis above the horizontal
    (negative looks down); ``height_m``: above the floor; ``forward_m``: ahead of the agent's
    centre. Depth is z-depth in metres clipped to [``min_depth``, ``max_depth``];
    ``max_depth`` means "no return within range".
    """

    width: int
    height: int
    hfov_deg: float | None = None
    vfov_deg: float | None = None
    fx: float | None = None
    fy: float | None = None
    cx: float | None = None
    cy: float | None = None
    pitch_deg: float = 0.0
    height_m: float = 0.88
    forward_m: float = 0.0
    min_depth: float = 0.5
    max_depth: float = 5.0

    def __post_init__(self):
        if int(self.width) < 1 or int(self.height) < 1:
            raise EnvSpecError(f"camera image must be at least 1x1, got {self.width}x{self.height}")
        given = [k for k in ("hfov_deg", "vfov_deg", "fx") if getattr(self, k) is not None]
        if len(given) != 1:
            raise EnvSpecError("camera needs exactly one of hfov_deg, vfov_deg, fx "
                               f"(got {', '.join(given) or 'none'})")
        for k in ("hfov_deg", "vfov_deg"):
            v = getattr(self, k)
            if v is not None and not 0 < v < 180:
                raise EnvSpecError(f"camera {k} must be in (0, 180), got {v}")
        for k in ("fx", "fy"):
            v = getattr(self, k)
            if v is not None and not v > 0:
                raise EnvSpecError(f"camera {k} must be > 0, got {v}")
        if not 0 <= self.min_depth < self.max_depth:
            raise EnvSpecError(f"camera depth range must have 0 <= min < max, got "
                               f"[{self.min_depth}, {self.max_depth}]")
        if not -90 < self.pitch_deg < 90:
            raise EnvSpecError(f"camera pitch_deg must be in (-90, 90), got {self.pitch_deg}")


@dataclass(frozen=True)
class ActionSpec:
    """The discrete actions: ``names[i]`` is what action index ``i`` does (each of
    :data:`ACTION_NAMES` exactly once, in any order); ``step_m`` is the forward step and
    ``turn_deg`` the turn of ``turn_left`` (counter-clockwise) and ``turn_right``."""

    names: tuple[str, ...] = ACTION_NAMES
    step_m: float = 0.25
    turn_deg: float = 30.0

    def __post_init__(self):
        if sorted(self.names) != sorted(ACTION_NAMES):
            raise EnvSpecError(f"actions must name each of {', '.join(ACTION_NAMES)} once, "
                               f"got {tuple(self.names)}")
        if not self.step_m > 0:
            raise EnvSpecError(f"step_m must be > 0, got {self.step_m}")
        if not 0 < self.turn_deg <= 90:
            raise EnvSpecError(f"turn_deg must be in (0, 90], got {self.turn_deg}")

    def index(self, name: str) -> int:
        """The action index of ``name``."""
        return self.names.index(name)

    @property
    def full_turn(self) -> int:
        """Turns in one look all round (12 for 30°)."""
        return max(1, round(360.0 / self.turn_deg))

    def turns(self, degrees: float) -> int:
        """Turns closest to ``degrees`` (at least one)."""
        return max(1, round(degrees / self.turn_deg))

    @property
    def bump_distance(self) -> float:
        """A forward move that advanced less than this (m) was blocked: 12 % of a step
        (3 cm of 0.25 m)."""
        return self.step_m * 3 / 25


@dataclass(frozen=True)
class EnvSpec:
    """Everything an agent must know about an environment before its first frame.

    ``classes``: the object vocabulary; class id ``k`` (1-based) in ``semantic`` and
    ``objectgoal`` is ``classes[k - 1]``. ``semantic``: whether observations carry the
    ground-truth ``semantic`` channel (needed by the noise segmenters only). ``max_steps``:
    actions per episode before it is truncated. ``agent_radius``: the agent's footprint (m),
    which the planner keeps off obstacles.
    """

    name: str
    camera: CameraSpec
    actions: ActionSpec = ActionSpec()
    classes: tuple[str, ...] = ()
    semantic: bool = False
    max_steps: int = 500
    agent_radius: float = 0.18

    def __post_init__(self):
        if not self.classes:
            raise EnvSpecError(f"environment {self.name!r} declares no object classes")
        if len(set(self.classes)) != len(self.classes):
            raise EnvSpecError(f"environment {self.name!r} names a class twice")
        if int(self.max_steps) < 1:
            raise EnvSpecError(f"max_steps must be >= 1, got {self.max_steps}")
        if not self.agent_radius > 0:
            raise EnvSpecError(f"agent_radius must be > 0, got {self.agent_radius}")

    def class_id(self, name: str) -> int:
        """The 1-based id of class ``name``."""
        from kgnav.errors import UnknownClassError

        if name not in self.classes:
            raise UnknownClassError(name, self.classes)
        return self.classes.index(name) + 1

    def observation_space(self):
        """The observations as a ``gymnasium.spaces.Dict`` (the keys of
        :data:`kgnav.envs.protocol.OBSERVATION_KEYS`, and ``semantic`` when declared)."""
        from gymnasium import spaces

        H, W, cam = self.camera.height, self.camera.width, self.camera
        obs = {"rgb": spaces.Box(0, 255, (H, W, 3), np.uint8),
               "depth": spaces.Box(cam.min_depth, cam.max_depth, (H, W), np.float32),
               "pose": spaces.Box(-np.inf, np.inf, (3,), np.float64),
               "objectgoal": spaces.Discrete(len(self.classes) + 1)}
        if self.semantic:
            obs["semantic"] = spaces.Box(0, np.iinfo(np.int32).max, (H, W, 2), np.int32)
        return spaces.Dict(obs)

    def action_space(self):
        """The actions as a ``gymnasium.spaces.Discrete``."""
        from gymnasium import spaces

        return spaces.Discrete(len(self.actions.names))

    def class_name(self, k: int) -> str:
        """The class of 1-based id ``k``."""
        if not 1 <= int(k) <= len(self.classes):
            raise EnvSpecError(f"class id {k} out of range (1..{len(self.classes)}) for "
                               f"environment {self.name!r}")
        return self.classes[int(k) - 1]


def focal_lengths(cam: CameraSpec) -> tuple[float, float]:
    """(fx, fy) in pixels from whichever of hfov/vfov/fx the spec gives.

    >>> [round(f, 2) for f in focal_lengths(CameraSpec(160, 120, hfov_deg=90.0))]
    [80.0, 80.0]
    """
    if cam.fx is not None:
        fx = float(cam.fx)
    elif cam.hfov_deg is not None:
        fx = (cam.width / 2) / math.tan(math.radians(cam.hfov_deg) / 2)
    else:
        fx = (cam.height / 2) / math.tan(math.radians(cam.vfov_deg) / 2)
    return fx, float(cam.fy) if cam.fy is not None else fx
