"""``MapBuilder``: depth + pose (+ segmentation) → the allocentric episode map.

The map lives in the episode frame (the pose observation's frame: the start pose is (0, 0, 0))
at 5 cm per cell, ``size × size`` cells centred on the start (480 × 480 = 24 m square, as Active
Neural SLAM and SemExp). Channels:

* ``obstacle``: cells holding a depth point within the obstacle height band (above the floor,
  below the agent's height; floor and ceiling points are not obstacles);
* ``explored``: cells inside the camera's field of view up to the first obstacle along each
  image column (the free space the agent has seen) plus every obstacle cell;
* ``semantic[c]``: per class, how many segmented pixels (subsampled) landed in the cell: an
  evidence count, fused over time like the other channels.

Rows are y, columns x: cell ``(i, j)`` has centre ``((j - c + 0.5) * res, (i - c + 0.5) * res)``
with ``c = size // 2``.

>>> from kgnav.agent.camera import Camera
>>> mb = MapBuilder(Camera(), size=100)
>>> m = mb.reset()
>>> depth = np.full((120, 160), 5.0, np.float32)
>>> m = mb.update(depth, (0.0, 0.0, 0.0))
>>> bool(m.explored[m.to_cell(2.0, 0.0)]), bool(m.explored[m.to_cell(-2.0, 0.0)])
(True, False)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from kgnav.agent.camera import Camera
from kgnav.classes import OBJECT_CLASSES


@dataclass
class EpisodeMap:
    """The fused episode map (see the module docstring). Arrays are (size, size)."""

    obstacle: np.ndarray  # uint8 0/1 (uint8 so OpenCV can draw into it in place)
    explored: np.ndarray  # uint8 0/1
    semantic: np.ndarray  # uint16 (n_classes, size, size)
    resolution: float
    classes: tuple[str, ...] = OBJECT_CLASSES

    @property
    def size(self) -> int:
        return self.obstacle.shape[0]

    @property
    def center(self) -> int:
        return self.size // 2

    def to_cell(self, x: float, y: float) -> tuple[int, int]:
        """Cell (row, col) of episode-frame point (x, y); may lie outside the map."""
        c, r = self.center, self.resolution
        return int(math.floor(y / r)) + c, int(math.floor(x / r)) + c

    def to_xy(self, i: float, j: float) -> tuple[float, float]:
        """Episode-frame centre of cell (row i, col j)."""
        c, r = self.center, self.resolution
        return (j - c + 0.5) * r, (i - c + 0.5) * r

    def inside(self, i: int, j: int) -> bool:
        return 0 <= i < self.size and 0 <= j < self.size

    def class_mask(self, cls: str, min_count: int = 1) -> np.ndarray:
        """Cells with at least ``min_count`` evidence of class ``cls``."""
        return self.semantic[self.classes.index(cls)] >= min_count


class MapBuilder:
    """Fuses each frame into an :class:`EpisodeMap`.

    ``obstacle_band`` is the (min, max) height in metres of points that block the agent;
    ``stride`` subsamples pixels for the semantic channels (every ``stride``-th row and column).
    """

    def __init__(
        self,
        camera: Camera,
        size: int = 480,
        resolution: float = 0.05,
        obstacle_band: tuple[float, float] = (0.1, 1.5),
        stride: int = 2,
        classes: tuple[str, ...] = OBJECT_CLASSES,
    ):
        if size < 8 or resolution <= 0:
            raise ValueError(f"bad map geometry: size {size}, resolution {resolution}")
        self.camera = camera
        self.size = int(size)
        self.resolution = float(resolution)
        self.obstacle_band = obstacle_band
        self.stride = max(1, int(stride))
        self.classes = tuple(classes)
        self.map_: EpisodeMap | None = None

    def reset(self) -> EpisodeMap:
        n = self.size
        self.map_ = EpisodeMap(
            obstacle=np.zeros((n, n), np.uint8),
            explored=np.zeros((n, n), np.uint8),
            semantic=np.zeros((len(self.classes), n, n), np.uint16),
            resolution=self.resolution,
            classes=self.classes,
        )
        return self.map_

    def _cells(self, pose, forward, left) -> tuple[np.ndarray, np.ndarray]:
        x, y, t = pose
        c, s = math.cos(t), math.sin(t)
        px = x + c * forward - s * left
        py = y + s * forward + c * left
        k = 1.0 / self.resolution
        ctr = self.size // 2
        return (np.floor(py * k).astype(np.int32) + ctr, np.floor(px * k).astype(np.int32) + ctr)

    def update(self, depth: np.ndarray, pose, segmentation=None) -> EpisodeMap:
        """Fuse one frame taken at episode-frame ``pose``; returns the map."""
        m = self.map_ if self.map_ is not None else self.reset()
        cam = self.camera
        forward, left, up = cam.points(depth)
        lo, hi = self.obstacle_band
        far = depth >= cam.max_depth - 1e-3  # no return within range: nothing there to map
        blocking = (up > lo) & (up < hi) & ~far
        n = self.size

        # free space: per column, up to the nearest blocking point (or the sensor range)
        col_free = np.where(blocking, depth, np.float32(cam.max_depth)).min(axis=0)
        fwd = col_free
        lft = -col_free * cam.ray_right
        ci, cj = self._cells(pose, np.concatenate([[0.0], fwd]), np.concatenate([[0.0], lft]))
        poly = np.stack([cj, ci], axis=1).astype(np.int32)
        cv2.fillPoly(m.explored, [poly], 1)

        # obstacles
        if blocking.any():
            oi, oj = self._cells(pose, forward[blocking], left[blocking])
            ok = (oi >= 0) & (oi < n) & (oj >= 0) & (oj < n)
            m.obstacle[oi[ok], oj[ok]] = 1
            m.explored[oi[ok], oj[ok]] = 1

        if segmentation is not None:
            self._fuse_semantic(m, pose, forward, left, far, segmentation)
        return m

    def _fuse_semantic(self, m, pose, forward, left, far, segmentation) -> None:
        st = self.stride
        lab = segmentation.classes[::st, ::st]
        keep = (lab > 0) & ~far[::st, ::st]
        if not keep.any():
            return
        f = forward[::st, ::st][keep]
        lft = left[::st, ::st][keep]
        cls = lab[keep] - 1  # class ids are 1-based
        i, j = self._cells(pose, f, lft)
        n = self.size
        ok = (i >= 0) & (i < n) & (j >= 0) & (j < n) & (cls < len(self.classes))
        flat = (cls[ok].astype(np.int64) * n + i[ok]) * n + j[ok]
        idx, counts = np.unique(flat, return_counts=True)
        sem = m.semantic.reshape(-1)
        sem[idx] = np.minimum(sem[idx].astype(np.int64) + counts, 65535).astype(np.uint16)
