"""``StateCreator``: one abstract state ``s = <F_s, C_s, {F_s,c}>`` per step.

``F_s`` comes from the :class:`~kgnav.agent.features.FeatureExtractor`; ``C_s`` and the per-object
``F_s,c`` from the segmentation: each segment becomes a :class:`~kgnav.memory.model.Detection` whose
position is the paper's "depth of the bounding-box centroid added to the agent pose" (here the
median depth over the segment's pixels, which stays on the object when the box centre does not,
e.g. between a chair's legs), its bbox and its distance from the agent, plus how far its
visible surface extends around that point (``radius``: large objects seen from different
sides then stay one object) and the segmenter's score. The state also gets its range profile
(:mod:`kgnav.memory.geometry`): the free space it saw, a few dozen numbers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from kgnav.agent.camera import Camera, to_frame
from kgnav.memory.geometry import DEFAULT_BINS, ScanGeometry
from kgnav.memory.model import Detection


@dataclass(frozen=True)
class AbstractState:
    """What the State Creator hands to the knowledge-modelling phase."""

    features: np.ndarray  # F_s, unit float32
    pose: tuple[float, float, float]  # episode frame
    detections: tuple[Detection, ...]  # {F_s,c}; C_s is their classes
    ranges: np.ndarray | None = None  # range profile (see StateCreator.scan)
    weak: tuple[Detection, ...] = ()  # from the segmenter's sub-threshold segments, if asked

    @property
    def classes(self) -> frozenset[str]:
        return frozenset(d.cls for d in self.detections)


class StateCreator:
    """Builds :class:`AbstractState` records from a frame's features, segmentation and depth.

    Segments smaller than ``min_pixels`` or with no valid depth are not objects the agent can
    place; they are dropped. ``obstacle_band`` (m above the floor) is what blocks the agent in
    the range profile, as in the map; ``bins`` the profile's resolution.
    """

    def __init__(self, camera: Camera, min_pixels: int = 20,
                 obstacle_band: tuple[float, float] = (0.1, 1.5), bins: int = DEFAULT_BINS):
        self.camera = camera
        self.min_pixels = int(min_pixels)
        self.obstacle_band = obstacle_band
        self.scan = ScanGeometry(camera.hfov_deg, int(bins), camera.max_depth)

    def detections(self, segmentation, depth: np.ndarray, pose) -> tuple[Detection, ...]:
        cam = self.camera
        far = cam.max_depth - 1e-3
        out = []
        for seg in segmentation.segments:
            if seg.pixels < self.min_pixels:
                continue
            u0, v0, u1, v1 = seg.bbox
            inside = segmentation.instances[v0:v1, u0:u1] == seg.id
            d = depth[v0:v1, u0:u1][inside]
            d = d[d < far]
            if d.size == 0:
                continue
            z = float(np.median(d))
            fwd, left, up = cam.point((u0 + u1 - 1) / 2, (v0 + v1 - 1) / 2, z)
            x, y = to_frame(pose, fwd, left)
            out.append(Detection(seg.cls, (x, y, up), (u0, v0, u1, v1), math.hypot(fwd, left),
                                 int(seg.pixels), self._radius(inside, depth, u0, v0, z, fwd, left),
                                 float(seg.score)))
        return tuple(out)

    def _radius(self, inside, depth, u0, v0, z, fwd, left) -> float:
        """How far (m, floor plane) the segment's surface extends around its point: half the
        diagonal of the 5-95 percentile box of its pixels that lie near its depth (a mask
        bleeding onto the wall behind must not make a chair two metres wide)."""
        vv, uu = np.nonzero(inside)
        if len(vv) > 200:  # a subsample is plenty for percentiles
            step = len(vv) // 200 + 1
            vv, uu = vv[::step], uu[::step]
        d = depth[v0 + vv, u0 + uu].astype(np.float64)
        near = np.abs(d - z) <= 0.5
        if near.sum() < 3:
            return 0.0
        d, uu = d[near], uu[near]
        lf = -d * self.camera.ray_right[u0 + uu]
        (d0, d1), (l0, l1) = np.percentile(d, [5, 95]), np.percentile(lf, [5, 95])
        return 0.5 * math.hypot(d1 - d0, l1 - l0)

    def ranges(self, depth: np.ndarray, columns: np.ndarray | None = None) -> np.ndarray:
        """The frame's range profile (:class:`kgnav.memory.geometry.ScanGeometry`, ``self.scan``);
        ``columns``: the per-column ranges if already computed
        (:meth:`Camera.column_ranges`)."""
        if columns is None:
            columns = self.camera.column_ranges(depth, self.obstacle_band)
        return self.scan.profile(columns)

    def __call__(self, features: np.ndarray, segmentation, depth: np.ndarray,
                 pose, columns: np.ndarray | None = None) -> AbstractState:
        pose = tuple(float(v) for v in pose)
        weak = getattr(segmentation, "weak", None)
        return AbstractState(np.asarray(features, np.float32), pose,
                             self.detections(segmentation, depth, pose),
                             self.ranges(depth, columns),
                             () if weak is None else self.detections(weak, depth, pose))
