"""The pinhole depth camera the agent reasons with: pixels + z-depth → points in the agent frame.

Conventions (as kgnav's simulator and Habitat): the agent frame has x forward, y left, z up from
the floor; pixel column ``u`` grows to the right, row ``v`` downwards; depth is z-depth (distance
along the optical axis), so for a level camera at the agent's centre a pixel's forward
coordinate *is* its depth. A pitched camera (``pitch_deg``) or one mounted ahead of the centre
(``forward_m``) is rotated and shifted into the agent frame.

>>> cam = Camera(width=160, height=120)
>>> f, left, up = cam.points(np.full((120, 160), 2.0, np.float32))
>>> float(f[60, 80]), round(float(up[60, 80]), 2)
(2.0, 0.87)
>>> cam = Camera.from_intrinsics(64, 48, vfov_deg=60.0, pitch_deg=-10.0, height_m=1.2)
>>> round(cam.hfov_deg, 1), round(cam.point(31.5, 23.5, 2.0)[2], 3)  # centre pixel, 2 m away
(75.2, 0.853)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Camera:
    """Intrinsics and mounting of the agent's RGB-D camera.

    The focal length comes from ``hfov_deg`` unless ``fx`` is given (then ``hfov_deg`` is
    derived from it); ``fy`` defaults to ``fx`` (square pixels), the principal point
    (``cx``, ``cy``, pixels) to the image centre. ``pitch_deg``: the optical axis above the
    horizontal (negative looks down); ``forward_m``: the camera ahead of the agent's centre.
    """

    width: int = 160
    height: int = 120
    hfov_deg: float = 79.0
    height_m: float = 0.88  # camera height above the floor
    min_depth: float = 0.5
    max_depth: float = 5.0
    fx: float | None = None
    fy: float | None = None
    cx: float | None = None
    cy: float | None = None
    pitch_deg: float = 0.0
    forward_m: float = 0.0
    _rays: tuple = field(default=(), init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.fx is not None:
            object.__setattr__(self, "hfov_deg",
                               math.degrees(2 * math.atan((self.width / 2) / self.fx)))
            focal = float(self.fx)
        else:
            focal = (self.width / 2) / math.tan(math.radians(self.hfov_deg) / 2)
        fy = focal if self.fy is None else float(self.fy)
        cx = self.width / 2 if self.cx is None else float(self.cx)
        cy = self.height / 2 if self.cy is None else float(self.cy)
        right = ((np.arange(self.width) + 0.5) - cx) / focal
        up = (cy - (np.arange(self.height) + 0.5)) / fy
        object.__setattr__(self, "_rays", (focal, right.astype(np.float32),
                                           up.astype(np.float32), fy, cx, cy))

    @classmethod
    def from_intrinsics(cls, width: int, height: int, *, hfov_deg: float | None = None,
                        vfov_deg: float | None = None, fx: float | None = None,
                        fy: float | None = None, cx: float | None = None,
                        cy: float | None = None, pitch_deg: float = 0.0,
                        height_m: float = 0.88, forward_m: float = 0.0,
                        min_depth: float = 0.5, max_depth: float = 5.0) -> Camera:
        """A camera from any one of ``hfov_deg``, ``vfov_deg`` (square pixels) or ``fx``
        (pixels; ``fy`` defaults to it), a principal point (default: the image centre), its
        pitch, height and forward offset, and its depth range."""
        from kgnav.envs.spec import CameraSpec

        return cls.from_spec(CameraSpec(width, height, hfov_deg, vfov_deg, fx, fy, cx, cy,
                                        pitch_deg, height_m, forward_m, min_depth, max_depth))

    @classmethod
    def from_spec(cls, spec) -> Camera:
        """The camera an environment declares (a :class:`kgnav.envs.CameraSpec`)."""
        from kgnav.envs.spec import focal_lengths

        fx = fy = None
        if spec.hfov_deg is None or spec.fy is not None:
            fx, fy = focal_lengths(spec)
        return cls(int(spec.width), int(spec.height),
                   79.0 if spec.hfov_deg is None else float(spec.hfov_deg),
                   float(spec.height_m), float(spec.min_depth), float(spec.max_depth),
                   fx=fx, fy=fy, cx=spec.cx, cy=spec.cy, pitch_deg=float(spec.pitch_deg),
                   forward_m=float(spec.forward_m))

    @classmethod
    def from_env(cls, env) -> Camera:
        """The camera an environment declares in its ``env_spec``
        (:class:`kgnav.envs.EnvSpec`)."""
        return cls.from_spec(env.env_spec.camera)

    @property
    def focal(self) -> float:
        """Horizontal focal length (pixels)."""
        return self._rays[0]

    @property
    def ray_right(self) -> np.ndarray:
        """Rightward slope of each column's ray (per metre of depth)."""
        return self._rays[1]

    @property
    def ray_up(self) -> np.ndarray:
        """Upward slope of each row's ray (per metre of depth)."""
        return self._rays[2]

    def check(self, depth: np.ndarray) -> np.ndarray:
        if depth.shape != (self.height, self.width):
            raise ValueError(f"depth frame is {depth.shape}, the camera is "
                             f"{self.height}x{self.width}")
        return depth

    @property
    def level(self) -> bool:
        """Level and at the agent's centre: a pixel's forward coordinate is its depth."""
        return self.pitch_deg == 0 and self.forward_m == 0

    def _mount(self, d, up_cam):
        """Camera-frame (along the axis, up) → agent-frame (forward, up above the camera)."""
        p = math.radians(self.pitch_deg)
        c, s = np.float32(math.cos(p)), np.float32(math.sin(p))
        return d * c - up_cam * s + np.float32(self.forward_m), d * s + up_cam * c

    def points(self, depth: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per-pixel (forward, left, up-from-floor) in metres, agent frame."""
        d = self.check(depth)
        left = -d * self.ray_right[None, :]
        if self.level:
            up = self.height_m + d * self.ray_up[:, None]
            return d, left, up
        fwd, up = self._mount(d, d * self.ray_up[:, None])
        return fwd, left, self.height_m + up

    def column_ranges(self, depth: np.ndarray, band: tuple[float, float]) -> np.ndarray:
        """Per image column, the forward distance (the z-depth, for a level camera) of the
        nearest point whose height lies in ``band`` (what blocks the agent), or ``max_depth``
        when none does within range."""
        fwd, _left, up = self.points(depth)
        far = depth >= self.max_depth - 1e-3  # no return within range
        blocking = (up > band[0]) & (up < band[1]) & ~far
        return np.where(blocking, fwd, np.float32(self.max_depth)).min(axis=0)

    def point(self, u: float, v: float, depth: float) -> tuple[float, float, float]:
        """The agent-frame point of (sub)pixel (u, v) at z-depth ``depth``."""
        _f, _r, _u, fy, cx, cy = self._rays
        r = (u + 0.5 - cx) / self.focal
        up = (cy - (v + 0.5)) / fy
        if self.level:
            return depth, -depth * r, self.height_m + depth * up
        p = math.radians(self.pitch_deg)
        fwd = depth * math.cos(p) - depth * up * math.sin(p) + self.forward_m
        return fwd, -depth * r, self.height_m + depth * math.sin(p) + depth * up * math.cos(p)


def to_frame(pose, forward, left):
    """Agent-frame (forward, left) coordinates → the frame ``pose`` = (x, y, theta) lives in."""
    x, y, t = pose
    c, s = math.cos(t), math.sin(t)
    return x + c * forward - s * left, y + s * forward + c * left
