"""What a state saw of the free space: range profiles, and the occupancy they add up to.

A state of an Abstract Model may carry a **range profile**: for ``bins`` equal slices of the
camera's horizontal field of view, the z-depth (metres along the optical axis) of the nearest
point that blocks the agent (within the obstacle height band), or ``max_range`` when nothing
within range does. A few dozen float16 values per state are enough to rebuild

* the **free space** the state saw: the fan from the camera through each bin's range, and
* the **obstacles** it hit: each bin's end point when it lies within range,

so a stored model doubles as a coarse map: :func:`occupancy` rasterises all its states into an
:class:`OccupancyGrid` (model frame). The agent seeds its episode map with it after a
relocation, verifies relocations against it, and checks whether a remembered object lay in
view of a state (negative evidence).

The profile's geometry (:class:`ScanGeometry`: field of view, bins, range) is recorded once per
model.

>>> scan = ScanGeometry(hfov_deg=90.0, bins=4, max_range=5.0)
>>> ranges = np.array([2.0, 2.0, 5.0, 5.0], np.float16)
>>> pts = scan.endpoints((0.0, 0.0, 0.0), ranges)     # only the bins that hit something
>>> np.round(pts, 2).tolist()
[[2.0, 1.5], [2.0, 0.5]]
>>> grid = occupancy_from_scans(scan, [(0.0, 0.0, 0.0)], [ranges], resolution=0.1)
>>> grid.state_at(1.0, 0.0), grid.state_at(2.0, 1.5), grid.state_at(-1.0, 0.0)
('free', 'obstacle', 'unknown')
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass

import cv2
import numpy as np

#: Bins of a profile by default: 40 slices of the field of view (2 degrees each at 79 degrees).
DEFAULT_BINS = 40
#: Free space is drawn this far short of each end point, so the obstacle cell is not painted free.
_FREE_MARGIN = 0.1


@dataclass(frozen=True)
class ScanGeometry:
    """How a model's range profiles were taken: horizontal field of view (degrees), number of
    bins across it (left to right), and the range meaning "nothing blocks within range"."""

    hfov_deg: float = 79.0
    bins: int = DEFAULT_BINS
    max_range: float = 5.0

    def __post_init__(self):
        if not (0 < self.hfov_deg < 180 and self.bins >= 1 and self.max_range > 0):
            raise ValueError(f"bad scan geometry {self}")

    def to_json(self) -> str:
        return json.dumps(asdict(self), sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> ScanGeometry:
        d = json.loads(text)
        return cls(float(d["hfov_deg"]), int(d["bins"]), float(d["max_range"]))

    @property
    def slopes(self) -> np.ndarray:
        """Rightward slope (per metre of depth) of each bin's central ray, left to right."""
        t = math.tan(math.radians(self.hfov_deg) / 2)
        return ((2 * (np.arange(self.bins) + 0.5) / self.bins) - 1.0) * t

    def profile(self, column_ranges: np.ndarray) -> np.ndarray:
        """Per-bin minimum of per-image-column ranges (width need not divide evenly)."""
        cols = np.asarray(column_ranges, np.float32)
        edges = np.linspace(0, len(cols), self.bins + 1).round().astype(int)[:-1]
        return np.minimum.reduceat(cols, edges).astype(np.float16)

    def _local(self, ranges) -> tuple[np.ndarray, np.ndarray]:
        r = np.minimum(np.asarray(ranges, np.float32), self.max_range)
        return r, -r * self.slopes  # forward, left

    def endpoints(self, pose, ranges) -> np.ndarray:
        """(N, 2) points, in the frame of ``pose``, where the profile hit an obstacle."""
        fwd, left = self._local(ranges)
        hit = fwd < self.max_range - 1e-3
        return _to_frame(pose, fwd[hit], left[hit])

    def fan(self, pose, ranges, margin: float = _FREE_MARGIN) -> np.ndarray:
        """(bins + 1, 2) polygon of the free space seen from ``pose`` (camera first)."""
        fwd, left = self._local(ranges)
        scale = np.maximum(fwd - margin, 0.0) / np.maximum(fwd, 1e-6)
        pts = _to_frame(pose, fwd * scale, left * scale)
        return np.vstack([np.asarray(pose[:2], float)[None, :], pts])

    def covers(self, poses, ranges, point, max_distance: float, margin: float = 0.3
               ) -> np.ndarray:
        """Which of the states at ``poses`` (S, 3) with profiles ``ranges`` (S, bins) had
        ``point`` (x, y) in view: in the field of view, within ``max_distance`` ahead and not
        behind the first obstacle of its bin (``margin`` m of slack: the point may be that
        obstacle itself)."""
        poses = np.asarray(poses, float).reshape(-1, 3)
        ranges = np.asarray(ranges, np.float32).reshape(len(poses), self.bins)
        dx, dy = point[0] - poses[:, 0], point[1] - poses[:, 1]
        c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
        fwd = c * dx + s * dy
        left = -s * dx + c * dy
        tan_half = math.tan(math.radians(self.hfov_deg) / 2)
        ok = (fwd > 0.2) & (fwd <= max_distance)
        slope = np.where(ok, -left / np.where(ok, fwd, 1.0), 0.0)
        ok &= np.abs(slope) <= tan_half
        b = np.clip(((slope / tan_half + 1) / 2 * self.bins).astype(int), 0, self.bins - 1)
        return ok & (fwd <= ranges[np.arange(len(b)), b] + margin)


def _to_frame(pose, fwd: np.ndarray, left: np.ndarray) -> np.ndarray:
    x, y, t = (float(v) for v in pose)
    c, s = math.cos(t), math.sin(t)
    return np.stack([x + c * fwd - s * left, y + s * fwd + c * left], axis=1)


@dataclass
class OccupancyGrid:
    """Free and obstacle evidence of many range profiles, rasterised. ``free`` / ``hits`` count
    the profiles that saw each cell free / hit an obstacle in it; rows are y, columns x; cell
    (i, j) covers ``[x0 + j*res, x0 + (j+1)*res] x [y0 + i*res, ...]``."""

    free: np.ndarray  # uint16
    hits: np.ndarray  # uint16
    x0: float
    y0: float
    resolution: float
    near: np.ndarray | None = None  # uint16: profiles that saw the cell within ``near_range``
    # (:func:`occupancy_from_scans`); None when not asked for

    @property
    def searched(self) -> np.ndarray:
        """Cells some profile saw from close enough to find an object there (``near`` > 0;
        all False without ``near``)."""
        if self.near is None:
            return np.zeros(self.free.shape, bool)
        return self.near > 0

    @property
    def obstacle(self) -> np.ndarray:
        """Cells hit by at least one profile and not seen free far more often than hit."""
        return (self.hits > 0) & (self.hits.astype(np.int32) * 4 >= self.free)

    @property
    def known_free(self) -> np.ndarray:
        return (self.free > 0) & ~self.obstacle

    def cell(self, x: float, y: float) -> tuple[int, int]:
        return (int(math.floor((y - self.y0) / self.resolution)),
                int(math.floor((x - self.x0) / self.resolution)))

    def state_at(self, x: float, y: float) -> str:
        """``"free"``, ``"obstacle"`` or ``"unknown"`` at point (x, y)."""
        i, j = self.cell(x, y)
        h, w = self.free.shape
        if not (0 <= i < h and 0 <= j < w):
            return "unknown"
        if self.obstacle[i, j]:
            return "obstacle"
        return "free" if self.free[i, j] > 0 else "unknown"


def occupancy_from_scans(scan: ScanGeometry, poses, ranges, resolution: float = 0.05,
                         pad: float = 0.5, near_range: float | None = None) -> OccupancyGrid:
    """Rasterise range profiles taken at ``poses`` (one frame) into an :class:`OccupancyGrid`.

    With ``near_range`` (m) the grid also counts, in ``near``, the profiles that saw each cell
    from at most that far: the part of the free space, and the obstacles ending it, that a
    segmenter would have searched for objects (an object is an obstacle, so the end point of a
    bin is counted too)."""
    poses = [tuple(float(v) for v in p) for p in poses]
    if not poses:
        z = np.zeros((1, 1), np.uint16)
        return OccupancyGrid(z, z.copy(), 0.0, 0.0, resolution,
                             None if near_range is None else z.copy())
    xy = np.array([p[:2] for p in poses])
    reach = scan.max_range + pad  # (hits beyond, at the edges of the view, are dropped below)
    x0, y0 = xy.min(axis=0) - reach
    x1, y1 = xy.max(axis=0) + reach
    w = int(math.ceil((x1 - x0) / resolution))
    h = int(math.ceil((y1 - y0) / resolution))
    free = np.zeros((h, w), np.uint16)
    hits = np.zeros((h, w), np.uint16)
    near = None if near_range is None else np.zeros((h, w), np.uint16)
    one = np.zeros((h, w), np.uint8)
    k = 1.0 / resolution
    for pose, r in zip(poses, ranges, strict=True):
        # a stored profile is trusted no further than the sensor reaches (a damaged or foreign
        # value must not reach outside the grid)
        r = np.nan_to_num(np.asarray(r, np.float64), nan=scan.max_range, posinf=scan.max_range)
        r = np.clip(r, 0.0, scan.max_range)
        _paint(free, one, scan.fan(pose, r), x0, y0, k)
        if near is not None:
            # up to and just past the end point (what ends a bin may be the object), capped
            _paint(near, one, scan.fan(pose, np.minimum(r + _FREE_MARGIN, near_range), 0.0),
                   x0, y0, k)
        end = np.floor((scan.endpoints(pose, r) - (x0, y0)) * k).astype(np.int64)
        end = end[(end[:, 0] >= 0) & (end[:, 0] < w) & (end[:, 1] >= 0) & (end[:, 1] < h)]
        if len(end):
            flat = np.unique(end[:, 1] * w + end[:, 0])
            hits.reshape(-1)[flat] += 1
    return OccupancyGrid(free, hits, float(x0), float(y0), resolution, near)


def _paint(count: np.ndarray, scratch: np.ndarray, poly: np.ndarray, x0: float, y0: float,
           k: float) -> None:
    """Add 1 to ``count`` over the polygon ``poly`` (points in metres; ``scratch``: a uint8
    array of the same shape, overwritten)."""
    h, w = count.shape
    cells = np.floor((poly - (x0, y0)) * k).astype(np.int32)
    i0, j0 = max(int(cells[:, 1].min()), 0), max(int(cells[:, 0].min()), 0)
    i1, j1 = min(int(cells[:, 1].max()) + 1, h), min(int(cells[:, 0].max()) + 1, w)
    if i0 < i1 and j0 < j1:
        sub = scratch[i0:i1, j0:j1]
        sub[:] = 0
        cv2.fillPoly(sub, [cells - (j0, i0)], 1)
        count[i0:i1, j0:j1] += sub
