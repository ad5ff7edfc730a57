"""``MapBuilder``: depth + pose (+ segmentation) → the allocentric episode map.

The map lives in the episode frame (the pose observation's frame: the start pose is (0, 0, 0))
at 5 cm per cell. It starts as ``size × size`` cells centred on the start (480 × 480 = 24 m
square, as Active Neural SLAM and SemExp) and **grows** when the agent's sensor range reaches
its edge, so no reachable goal is ever off the map however large the house (a Matterport3D
house can be 40 m across); planning stays bounded because the planner works on windows.
Channels:

* ``obstacle``: cells holding a depth point within the obstacle height band (above the floor,
  below the agent's height; floor and ceiling points are not obstacles);
* ``explored``: cells inside the camera's field of view up to the first obstacle along each
  image column (the free space the agent has seen) plus every obstacle cell;
* ``semantic[c]``: per class, how many segmented pixels (subsampled) landed in the cell: an
  evidence count, fused over time like the other channels;
* ``bumped``: cells where the agent collided with something the map missed (the planner's);
* ``searched``: the part of ``explored`` seen from at most ``search_range`` (3 m, as far as a
  miss counts against an object, :data:`kgnav.memory.evidence.MISS_RANGE`), where the agent
  would have found an object; farther, a segmenter misses much;
* ``prior_obstacle`` / ``prior_explored`` / ``prior_searched`` (after :meth:`MapBuilder.seed`):
  what a remembered Abstract Model knows of the place, mapped with a relocation; the agent's own
  view overrides it (a cell it sees free loses its remembered obstacle).

Rows are y, columns x: cell ``(i, j)`` has centre ``((j - oj + 0.5) * res, (i - oi + 0.5) * res)``
where ``origin = (oi, oj)`` is the cell holding the episode start. Growing shifts ``origin`` and
increments ``generation``; whoever caches cell indices compares the generation.

>>> from kgnav.agent.camera import Camera
>>> mb = MapBuilder(Camera(), size=240)
>>> m = mb.reset()
>>> depth = np.full((120, 160), 5.0, np.float32)
>>> m = mb.update(depth, (0.0, 0.0, 0.0))
>>> bool(m.explored[m.to_cell(2.0, 0.0)]), bool(m.explored[m.to_cell(-2.0, 0.0)])
(True, False)
>>> m = mb.update(depth, (30.0, 0.0, 0.0))     # far beyond the first 12 m square: it grows
>>> m.shape[1] > 240, bool(m.explored[m.to_cell(32.0, 0.0)]), m.generation
(True, True, 1)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from kgnav.agent.camera import Camera
from kgnav.common.classes import OBJECT_CLASSES
from kgnav.memory.evidence import MISS_RANGE
from kgnav.memory.geometry import OccupancyGrid


@dataclass
class EpisodeMap:
    """The fused episode map (see the module docstring). Arrays are (H, W)."""

    obstacle: np.ndarray  # uint8 0/1 (uint8 so OpenCV can draw into it in place)
    explored: np.ndarray  # uint8 0/1
    semantic: np.ndarray  # uint16 (n_classes, H, W)
    resolution: float
    classes: tuple[str, ...] = OBJECT_CLASSES
    origin: tuple[int, int] | None = None  # cell of the episode start; default: the centre
    bumped: np.ndarray | None = None  # uint8 0/1, same shape
    generation: int = 0  # bumped on every growth or seeding: what others derived is stale
    prior_obstacle: np.ndarray | None = None  # uint8 0/1: obstacles a memory knows of
    prior_explored: np.ndarray | None = None  # uint8 0/1: space a memory has seen
    searched: np.ndarray | None = None  # uint8 0/1: explored from within the search range
    prior_searched: np.ndarray | None = None  # uint8 0/1: ... by a memory
    # (class, x, y, belief) in the episode frame: the objects a memory believes in, for a
    # policy that looks for the goal near what it remembers (set by the agent loop)
    prior_objects: tuple = ()

    def __post_init__(self):
        if self.origin is None:
            self.origin = (self.obstacle.shape[0] // 2, self.obstacle.shape[1] // 2)
        if self.bumped is None:
            self.bumped = np.zeros_like(self.obstacle)
        if self.searched is None:
            self.searched = np.zeros_like(self.obstacle)

    @property
    def shape(self) -> tuple[int, int]:
        return self.obstacle.shape

    @property
    def size(self) -> int:
        """The longer side in cells."""
        return max(self.obstacle.shape)

    @property
    def corner(self) -> tuple[float, float]:
        """Episode-frame (x, y) of the map's lower-left corner (cell (0, 0)'s corner)."""
        return -self.origin[1] * self.resolution, -self.origin[0] * self.resolution

    def to_cell(self, x: float, y: float) -> tuple[int, int]:
        """Cell (row, col) of episode-frame point (x, y); may lie outside the map."""
        (oi, oj), r = self.origin, self.resolution
        return int(math.floor(y / r)) + oi, int(math.floor(x / r)) + oj

    def to_xy(self, i: float, j: float) -> tuple[float, float]:
        """Episode-frame centre of cell (row i, col j)."""
        (oi, oj), r = self.origin, self.resolution
        return (j - oj + 0.5) * r, (i - oi + 0.5) * r

    def inside(self, i: int, j: int) -> bool:
        return 0 <= i < self.obstacle.shape[0] and 0 <= j < self.obstacle.shape[1]

    def blocked(self, crop=None, prior: bool = True) -> np.ndarray:
        """uint8 obstacles, bumps and (with ``prior``) remembered obstacles (over ``crop`` =
        (i0, i1, j0, j1))."""
        i0, i1, j0, j1 = crop if crop is not None else (0, self.shape[0], 0, self.shape[1])
        occ = self.obstacle[i0:i1, j0:j1] | self.bumped[i0:i1, j0:j1]
        if prior and self.prior_obstacle is not None:
            occ = occ | self.prior_obstacle[i0:i1, j0:j1]
        return occ

    def known(self, prior: bool = True, crop=None) -> np.ndarray:
        """uint8 cells seen by the agent or (with ``prior``), before it, by a remembered
        model (over ``crop`` = (i0, i1, j0, j1))."""
        i0, i1, j0, j1 = crop if crop is not None else (0, self.shape[0], 0, self.shape[1])
        if not prior or self.prior_explored is None:
            return self.explored[i0:i1, j0:j1]
        return self.explored[i0:i1, j0:j1] | self.prior_explored[i0:i1, j0:j1]

    def searched_any(self, crop=None) -> np.ndarray:
        """uint8 cells searched by the agent or by a remembered model (over ``crop``)."""
        i0, i1, j0, j1 = crop if crop is not None else (0, self.shape[0], 0, self.shape[1])
        if self.prior_searched is None:
            return self.searched[i0:i1, j0:j1]
        return self.searched[i0:i1, j0:j1] | self.prior_searched[i0:i1, j0:j1]

    def forget_prior(self) -> None:
        """Drop what a memory said of the place (a relocation refuted)."""
        self.prior_objects = ()
        if self.prior_obstacle is not None:
            self.prior_obstacle = self.prior_explored = self.prior_searched = None
            self.generation += 1

    def class_mask(self, cls: str, min_count: int = 1) -> np.ndarray:
        """Cells with at least ``min_count`` evidence of class ``cls``."""
        return self.semantic[self.classes.index(cls)] >= min_count

    def cover(self, i0: int, i1: int, j0: int, j1: int, chunk: int = 120,
              limit: int | None = None) -> bool:
        """Grow the map so that rows ``i0..i1`` and columns ``j0..j1`` (current cell indices,
        ends exclusive) lie inside it, padding by ``chunk`` more cells on a side that grows
        (fewer, larger growths), and never beyond ``limit`` cells a side (what does not fit
        then stays off the map). Returns whether it grew."""
        H, W = self.obstacle.shape
        pad = [_grow(H, max(-i0, 0), max(i1 - H, 0), chunk, limit),
               _grow(W, max(-j0, 0), max(j1 - W, 0), chunk, limit)]
        if not any(pad[0] + pad[1]):
            return False
        self.obstacle = np.pad(self.obstacle, pad)
        self.explored = np.pad(self.explored, pad)
        self.bumped = np.pad(self.bumped, pad)
        self.searched = np.pad(self.searched, pad)
        if self.prior_obstacle is not None:
            self.prior_obstacle = np.pad(self.prior_obstacle, pad)
            self.prior_explored = np.pad(self.prior_explored, pad)
            self.prior_searched = np.pad(self.prior_searched, pad)
        self.semantic = np.pad(self.semantic, [(0, 0), *pad])
        self.origin = (self.origin[0] + pad[0][0], self.origin[1] + pad[1][0])
        self.generation += 1
        return True


def _grow(n: int, lo: int, hi: int, chunk: int, limit: int | None) -> tuple[int, int]:
    """Padding (before, after) of an axis of ``n`` cells that must gain ``lo`` and ``hi``."""
    a, b = (lo and lo + chunk), (hi and hi + chunk)
    if limit is None or n + a + b <= limit:
        return a, b
    a, b = lo, hi  # no slack
    room = max(limit - n, 0)
    if a + b > room:
        a = a * room // (a + b)
        b = room - a if hi else 0
    return a, b


class MapBuilder:
    """Fuses each frame into an :class:`EpisodeMap`.

    ``obstacle_band`` is the (min, max) height in metres of points that block the agent;
    ``stride`` subsamples pixels for the semantic channels (every ``stride``-th row and column);
    ``size`` is the starting side in cells; the map grows up to ``max_size`` cells a side.
    """

    def __init__(
        self,
        camera: Camera,
        size: int = 480,
        resolution: float = 0.05,
        obstacle_band: tuple[float, float] = (0.1, 1.5),
        stride: int = 2,
        classes: tuple[str, ...] = OBJECT_CLASSES,
        max_size: int = 4000,
        search_range: float = MISS_RANGE,
    ):
        if size < 8 or resolution <= 0 or max_size < size:
            raise ValueError(f"bad map geometry: size {size}, resolution {resolution}, "
                             f"max_size {max_size}")
        self.camera = camera
        self.size = int(size)
        self.resolution = float(resolution)
        self.obstacle_band = obstacle_band
        self.stride = max(1, int(stride))
        self.classes = tuple(classes)
        self.max_size = int(max_size)
        self.search_range = float(search_range)
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
        oi, oj = self.map_.origin
        return (np.floor(py * k).astype(np.int32) + oi, np.floor(px * k).astype(np.int32) + oj)

    def _reach(self, m: EpisodeMap, pose) -> None:
        """Grow the map to hold everything the sensor can see from ``pose`` (up to
        ``max_size`` cells a side: beyond that, what falls off is not mapped)."""
        i, j = m.to_cell(pose[0], pose[1])
        k = int(math.ceil((self.camera.max_depth + 0.5) / self.resolution))
        m.cover(i - k, i + k + 1, j - k, j + k + 1, limit=self.max_size)

    def update(self, depth: np.ndarray, pose, segmentation=None) -> EpisodeMap:
        """Fuse one frame taken at episode-frame ``pose``; returns the map."""
        m = self.map_ if self.map_ is not None else self.reset()
        self._reach(m, pose)
        cam = self.camera
        forward, left, up = cam.points(depth)
        lo, hi = self.obstacle_band
        far = depth >= cam.max_depth - 1e-3  # no return within range: nothing there to map
        blocking = (up > lo) & (up < hi) & ~far
        H, W = m.shape

        # free space: per column, up to the nearest blocking point (or the sensor range);
        # forward is the depth itself for a level camera
        col_free = np.where(blocking, forward, np.float32(cam.max_depth)).min(axis=0)
        fwd = col_free
        lft = -col_free * cam.ray_right
        ci, cj = self._cells(pose, np.concatenate([[0.0], fwd]), np.concatenate([[0.0], lft]))
        i0, i1 = max(int(ci.min()), 0), min(int(ci.max()) + 1, H)
        j0, j1 = max(int(cj.min()), 0), min(int(cj.max()) + 1, W)
        if i0 < i1 and j0 < j1:
            # drawn on a window: what the agent sees free overrides what a memory said
            fan = np.zeros((i1 - i0, j1 - j0), np.uint8)
            cv2.fillPoly(fan, [np.stack([cj - j0, ci - i0], axis=1).astype(np.int32)], 1)
            m.explored[i0:i1, j0:j1] |= fan
            if m.prior_obstacle is not None:
                m.prior_obstacle[i0:i1, j0:j1] &= 1 - fan
            # the near part of the fan, through its end (what ends a column may be the object)
            near = np.minimum(col_free + 2 * self.resolution, np.float32(self.search_range))
            si, sj = self._cells(pose, np.concatenate([[0.0], near]),
                                 np.concatenate([[0.0], -near * cam.ray_right]))
            fan[:] = 0
            cv2.fillPoly(fan, [np.stack([sj - j0, si - i0], axis=1).astype(np.int32)], 1)
            m.searched[i0:i1, j0:j1] |= fan

        # obstacles
        if blocking.any():
            oi, oj = self._cells(pose, forward[blocking], left[blocking])
            ok = (oi >= 0) & (oi < H) & (oj >= 0) & (oj < W)
            m.obstacle[oi[ok], oj[ok]] = 1
            m.explored[oi[ok], oj[ok]] = 1

        if segmentation is not None:
            self._fuse_semantic(m, pose, forward, left, far, segmentation)
        return m

    def seed(self, grid: OccupancyGrid, transform) -> EpisodeMap:
        """Add a remembered :class:`~kgnav.memory.geometry.OccupancyGrid` (in a model's frame) to
        the map as prior knowledge: ``transform`` maps the episode frame into the model frame (a
        relocation's). Known-free cells join ``prior_explored``; obstacles ``prior_obstacle``
        (which the agent's own view clears again where it sees free space). The map grows to
        hold the remembered area (up to ``max_size``)."""
        m = self.map_ if self.map_ is not None else self.reset()
        tx, ty, th = (float(v) for v in transform)
        c, s = math.cos(th), math.sin(th)
        gh, gw = grid.free.shape
        # the grid's corners in the episode frame (inverse of the model <- episode transform)
        xs = grid.x0 + np.array([0, gw, 0, gw]) * grid.resolution - tx
        ys = grid.y0 + np.array([0, 0, gh, gh]) * grid.resolution - ty
        ex, ey = c * xs + s * ys, -s * xs + c * ys
        a, b = m.to_cell(float(ex.min()), float(ey.min()))
        a2, b2 = m.to_cell(float(ex.max()), float(ey.max()))
        m.cover(a - 1, a2 + 2, b - 1, b2 + 2, limit=self.max_size)
        a, b = m.to_cell(float(ex.min()), float(ey.min()))
        a2, b2 = m.to_cell(float(ex.max()), float(ey.max()))
        H, W = m.shape
        i0, i1, j0, j1 = max(a - 1, 0), min(a2 + 2, H), max(b - 1, 0), min(b2 + 2, W)
        if i0 >= i1 or j0 >= j1:
            return m
        # window cell (i, j) -> episode point -> model point -> grid cell
        (oi, oj), r, rg = m.origin, m.resolution, grid.resolution
        k = r / rg
        ox, oy = (j0 - oj + 0.5) * r, (i0 - oi + 0.5) * r
        M = np.array([[c * k, -s * k, (c * ox - s * oy + tx - grid.x0) / rg - 0.5],
                      [s * k, c * k, (s * ox + c * oy + ty - grid.y0) / rg - 0.5]])
        size = (j1 - j0, i1 - i0)
        flags = cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP
        obst = grid.obstacle.astype(np.uint8)
        free = grid.known_free.astype(np.uint8)
        w_obst = cv2.warpAffine(obst, M, size, flags=flags, borderValue=0)
        w_free = cv2.warpAffine(free, M, size, flags=flags, borderValue=0)
        w_near = cv2.warpAffine(grid.searched.astype(np.uint8), M, size, flags=flags,
                                borderValue=0)
        if m.prior_obstacle is None:
            m.prior_obstacle = np.zeros_like(m.obstacle)
            m.prior_explored = np.zeros_like(m.explored)
            m.prior_searched = np.zeros_like(m.explored)
        seen_free = m.explored[i0:i1, j0:j1] & (1 - m.obstacle[i0:i1, j0:j1])
        m.prior_explored[i0:i1, j0:j1] |= w_free | w_obst
        m.prior_searched[i0:i1, j0:j1] |= w_near
        m.prior_obstacle[i0:i1, j0:j1] |= w_obst & (1 - seen_free)
        m.generation += 1  # planners must replan with what is now known
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
        H, W = m.shape
        ok = (i >= 0) & (i < H) & (j >= 0) & (j < W) & (cls < len(self.classes))
        flat = (cls[ok].astype(np.int64) * H + i[ok]) * W + j[ok]
        idx, counts = np.unique(flat, return_counts=True)
        sem = m.semantic.reshape(-1)
        sem[idx] = np.minimum(sem[idx].astype(np.int64) + counts, 65535).astype(np.uint16)
