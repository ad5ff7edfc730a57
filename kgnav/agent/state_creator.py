"""``StateCreator``: one abstract state ``s = <F_s, C_s, {F_s,c}>`` per step.

``F_s`` comes from the :class:`~kgnav.agent.features.FeatureExtractor`; ``C_s`` and the per-object
``F_s,c`` from the segmentation: each segment becomes a :class:`~kgnav.model.Detection` whose
position is the paper's "depth of the bounding-box centroid added to the agent pose" (here the
median depth over the segment's pixels, which stays on the object when the box centre does not,
e.g. between a chair's legs), its bbox and its distance from the agent.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from kgnav.agent.camera import Camera, to_frame
from kgnav.model import Detection


@dataclass(frozen=True)
class AbstractState:
    """What the State Creator hands to the knowledge-modelling phase."""

    features: np.ndarray  # F_s, unit float32
    pose: tuple[float, float, float]  # episode frame
    detections: tuple[Detection, ...]  # {F_s,c}; C_s is their classes

    @property
    def classes(self) -> frozenset[str]:
        return frozenset(d.cls for d in self.detections)


class StateCreator:
    """Builds :class:`AbstractState` records from a frame's features, segmentation and depth.

    Segments smaller than ``min_pixels`` or with no valid depth are not objects the agent can
    place; they are dropped.
    """

    def __init__(self, camera: Camera, min_pixels: int = 20):
        self.camera = camera
        self.min_pixels = int(min_pixels)

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
                                 int(seg.pixels)))
        return tuple(out)

    def __call__(self, features: np.ndarray, segmentation, depth: np.ndarray,
                 pose) -> AbstractState:
        pose = tuple(float(v) for v in pose)
        return AbstractState(np.asarray(features, np.float32), pose,
                             self.detections(segmentation, depth, pose))
