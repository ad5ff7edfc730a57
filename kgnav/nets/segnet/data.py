"""Training and benchmark frames for the segmenter: rendered views with their labels.

Nothing is stored on disk: a batch is rendered on the fly from a seeded generator.

* **Views** (:class:`LabelledViews`): three in four look at an object — a class drawn uniformly
  among those the house holds (class-balanced sampling, so rare classes and the six goal classes
  are seen as often as chairs), one of its instances, a navigable spot 0.6–5 m from it (uniform
  in distance, so far objects are as frequent as near ones) and a heading towards it ± 35°; the
  rest are uniform random poses.
* **Augmentation** (:func:`augment`, training only; lighting and texture variation): horizontal
  flip; global brightness, per-channel gain (light colour), gamma, a brightness gradient across
  the frame (uneven lighting), sensor noise on RGB; a little depth noise.

>>> import numpy as np
>>> rgb = np.full((6, 8, 3), 128, np.uint8)
>>> a, d, lab = augment(rgb, np.full((6, 8), 2.0, np.float32), np.ones((6, 8), np.int64),
...                     np.random.default_rng(0))
>>> a.shape, a.dtype, d.shape, lab.shape
((6, 8, 3), dtype('uint8'), (6, 8), (6, 8))
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import numpy as np

from kgnav.nets.encoder.views import Pose, ViewSampler
from kgnav.sim.house import Scene

OBJECT_SHARE = 0.75  # share of views aimed at an object
DIST_RANGE = (0.6, 5.0)  # m, distance of an aimed view from the object's centre
AIM_JITTER = math.radians(35)


class LabelledViews(ViewSampler):
    """:class:`ViewSampler` that also aims views at objects and returns semantic labels."""

    def __init__(self, scenes: Sequence[Scene], width: int = 160, height: int = 120):
        super().__init__(scenes, width, height)
        # per house: class name -> the instances of it
        self.by_class: list[dict[str, list]] = []
        for s in self.scenes:
            d: dict[str, list] = {}
            for o in s.objects:
                d.setdefault(o.cls, []).append(o)
            self.by_class.append({k: d[k] for k in sorted(d)})

    def aimed_pose(self, house: int, rng: np.random.Generator, tries: int = 30) -> Pose | None:
        """A navigable pose looking at an instance of a uniformly drawn class of the house."""
        classes = self.by_class[house]
        names = list(classes)
        objs = classes[names[int(rng.integers(len(names)))]]
        o = objs[int(rng.integers(len(objs)))]
        cx, cy = o.center
        nav = self.navs[house]
        for _ in range(tries):
            r = rng.uniform(*DIST_RANGE)
            phi = rng.uniform(-math.pi, math.pi)
            x, y = cx + r * math.cos(phi), cy + r * math.sin(phi)
            if nav.is_navigable(x, y):
                th = math.atan2(cy - y, cx - x) + rng.uniform(-AIM_JITTER, AIM_JITTER)
                return (x, y, math.remainder(th, 2 * math.pi))
        return None

    def draw_pose(self, house: int, rng: np.random.Generator,
                  object_share: float = OBJECT_SHARE) -> Pose:
        """An aimed pose with probability ``object_share``, else a random one."""
        p = self.aimed_pose(house, rng) if rng.random() < object_share else None
        return p or self.random_pose(house, rng)

    def render_labelled(self, house: int, pose: Pose
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(RGB uint8 (H, W, 3), depth float32 (H, W), semantic int32 (H, W, 2)) from ``pose``."""
        return self.renderer(house).render(*pose)

    def frames(self, rng: np.random.Generator, n: int, houses: Sequence[int] | None = None,
               object_share: float = OBJECT_SHARE):
        """``n`` labelled frames from ``houses`` (default: all, round robin after a shuffle):
        (rgb (n, H, W, 3), depth (n, H, W), semantic (n, H, W, 2), houses (n,), poses (n, 3))."""
        hs = list(range(len(self))) if houses is None else list(houses)
        order = [hs[int(i)] for i in rng.permutation(len(hs))]
        rgbs, depths, sems, hh, poses = [], [], [], [], []
        for k in range(n):
            h = order[k % len(order)]
            p = self.draw_pose(h, rng, object_share)
            rgb, depth, sem = self.render_labelled(h, p)
            rgbs.append(rgb)
            depths.append(depth)
            sems.append(sem)
            hh.append(h)
            poses.append(p)
        return (np.stack(rgbs), np.stack(depths), np.stack(sems), np.array(hh),
                np.array(poses, float))


def labels_at(semantic: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Class-id labels (H, W) of a semantic frame (H, W, 2) resampled (nearest) to ``size``."""
    cls = np.ascontiguousarray(semantic[..., 0]).astype(np.uint8)
    if (cls.shape[1], cls.shape[0]) != tuple(size):
        cls = cv2.resize(cls, size, interpolation=cv2.INTER_NEAREST)
    return cls.astype(np.int64)


def augment(rgb: np.ndarray, depth: np.ndarray, labels: np.ndarray, rng: np.random.Generator
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Lighting / texture / sensor variation of one (downscaled) frame; labels follow flips."""
    h, w = labels.shape
    u = rng.random(8)
    if u[0] < 0.5:
        rgb, depth, labels = rgb[:, ::-1], depth[:, ::-1], labels[:, ::-1]
    x = rgb.astype(np.float32) * (1 / 255)
    x = x ** np.float32(0.8 + 0.45 * u[1])  # gamma 0.8-1.25
    gain = (0.6 + 0.8 * u[2]) * (0.9 + 0.2 * rng.random(3))  # brightness, light colour
    ramp = np.linspace(-1, 1, w if u[3] < 0.5 else h, dtype=np.float32) * (0.25 * u[4])
    ramp = 1 + (ramp[None, :] if u[3] < 0.5 else ramp[:, None])  # uneven lighting
    x = x * gain.astype(np.float32) * ramp[..., None]
    x += rng.normal(0, 0.025 * u[5], x.shape).astype(np.float32)  # sensor noise
    out = np.clip(x * 255 + 0.5, 0, 255).astype(np.uint8)
    d = depth * np.float32(1 + 0.02 * (u[6] - 0.5))
    d = d + rng.normal(0, 0.01, d.shape).astype(np.float32) * (u[7] < 0.5)
    return out, d.astype(np.float32), np.ascontiguousarray(labels)
