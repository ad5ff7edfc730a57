"""The pinhole depth camera the agent reasons with: pixels + z-depth → points in the agent frame.

Conventions (as the simulator's renderer and Habitat): the agent frame has x forward, y left,
z up from the floor; pixel column ``u`` grows to the right, row ``v`` downwards; depth is z-depth
(distance along the optical axis), so a pixel's forward coordinate *is* its depth.

>>> cam = Camera(width=160, height=120)
>>> f, left, up = cam.points(np.full((120, 160), 2.0, np.float32))
>>> float(f[60, 80]), round(float(up[60, 80]), 2)
(2.0, 0.87)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Camera:
    """Intrinsics and mounting of the agent's RGB-D camera."""

    width: int = 160
    height: int = 120
    hfov_deg: float = 79.0
    height_m: float = 0.88  # camera height above the floor
    min_depth: float = 0.5
    max_depth: float = 5.0
    _rays: tuple = field(default=(), init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        focal = (self.width / 2) / math.tan(math.radians(self.hfov_deg) / 2)
        right = ((np.arange(self.width) + 0.5) - self.width / 2) / focal
        up = (self.height / 2 - (np.arange(self.height) + 0.5)) / focal
        object.__setattr__(self, "_rays", (focal, right.astype(np.float32),
                                           up.astype(np.float32)))

    @classmethod
    def from_env(cls, env) -> Camera:
        """The camera of a :class:`kgnav.sim.ObjectNavEnv` (reads its renderer's settings)."""
        r = env.renderer
        return cls(r.width, r.height, math.degrees(r.hfov), r.cam_h, r.min_depth, r.max_depth)

    @property
    def focal(self) -> float:
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

    def points(self, depth: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per-pixel (forward, left, up-from-floor) in metres, agent frame."""
        d = self.check(depth)
        left = -d * self.ray_right[None, :]
        up = self.height_m + d * self.ray_up[:, None]
        return d, left, up

    def column_ranges(self, depth: np.ndarray, band: tuple[float, float]) -> np.ndarray:
        """Per image column, the z-depth of the nearest point whose height lies in ``band``
        (what blocks the agent), or ``max_depth`` when none does within range."""
        d, _left, up = self.points(depth)
        far = d >= self.max_depth - 1e-3  # no return within range
        blocking = (up > band[0]) & (up < band[1]) & ~far
        return np.where(blocking, d, np.float32(self.max_depth)).min(axis=0)

    def point(self, u: float, v: float, depth: float) -> tuple[float, float, float]:
        """The agent-frame point of (sub)pixel (u, v) at z-depth ``depth``."""
        r = (u + 0.5 - self.width / 2) / self.focal
        up = (self.height / 2 - (v + 0.5)) / self.focal
        return depth, -depth * r, self.height_m + depth * up


def to_frame(pose, forward, left):
    """Agent-frame (forward, left) coordinates → the frame ``pose`` = (x, y, theta) lives in."""
    x, y, t = pose
    c, s = math.cos(t), math.sin(t)
    return x + c * forward - s * left, y + s * forward + c * left
