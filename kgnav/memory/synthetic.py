"""Small synthetic environments that produce Abstract Models without a renderer.

Used by the demo, the tests and the benchmarks of the knowledge core. A :class:`SyntheticWorld` is
a rectangle of floor with objects in it; an agent walks it with the paper's actions and sees the
objects inside its field of view. State features are a smooth function of the pose (random Fourier
features of position and heading) on top of a per-world code, so nearby views have close
features, distant views and other worlds do not — what relocation needs. Everything is seeded.

>>> w = SyntheticWorld(seed=1, feature_dim=64)
>>> m = w.explore(steps=20, episode=0, seed=0)
>>> m.n_states > 0 and m.n_objects > 0
True
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from kgnav.common import se2
from kgnav.common.classes import OBJECT_CLASSES
from kgnav.memory.model import AbstractModel, Detection

FORWARD_M = 0.25
TURN_RAD = math.radians(30.0)
HFOV_RAD = math.radians(79.0)
SENSOR_RANGE_M = 5.0


@dataclass(frozen=True)
class SyntheticObject:
    cls: str
    x: float
    y: float
    z: float


class SyntheticWorld:
    """A seeded rectangular world with objects and pose-dependent view features.

    Parameters
    ----------
    seed:
        Seeds the layout, the objects and the feature basis.
    size:
        Floor extent ``(width, height)`` in metres.
    n_objects:
        Number of objects, classes drawn from ``classes``.
    feature_dim:
        Length of the state features.
    world_weight:
        Weight of the per-world code in the features (higher: views of one world are closer).
    """

    def __init__(
        self,
        seed: int = 0,
        size: tuple[float, float] = (10.0, 8.0),
        n_objects: int = 24,
        feature_dim: int = 2048,
        classes: tuple[str, ...] = OBJECT_CLASSES,
        world_weight: float = 0.4,
    ):
        rng = np.random.default_rng(seed)
        self.seed = seed
        self.size = (float(size[0]), float(size[1]))
        self.feature_dim = feature_dim
        self.classes = classes
        self.objects = [
            SyntheticObject(
                str(rng.choice(classes)),
                float(rng.uniform(0.3, size[0] - 0.3)),
                float(rng.uniform(0.3, size[1] - 0.3)),
                float(rng.uniform(0.2, 1.5)),
            )
            for _ in range(n_objects)
        ]
        # random Fourier features of (x, y, cos θ, sin θ): ~1 m position and ~40° heading scale
        self._freq = rng.normal(size=(4, feature_dim)) * np.array([[1.2], [1.2], [2.0], [2.0]])
        self._phase = rng.uniform(0, 2 * math.pi, size=feature_dim)
        code = rng.normal(size=feature_dim)
        self._code = code / np.linalg.norm(code)
        self.world_weight = world_weight

    def features(self, pose) -> np.ndarray:
        """Unit-norm float32 features of the view from a world pose."""
        x, y, theta = pose
        z = np.array([x, y, math.cos(theta), math.sin(theta)]) @ self._freq + self._phase
        view = np.cos(z) * math.sqrt(2.0 / self.feature_dim)
        f = self.world_weight * self._code + (1.0 - self.world_weight) * view
        return (f / np.linalg.norm(f)).astype(np.float32)

    def features_batch(self, poses: np.ndarray) -> np.ndarray:
        """:meth:`features` for an ``(N, 3)`` array of poses."""
        p = np.asarray(poses, dtype=float)
        z = np.stack([p[:, 0], p[:, 1], np.cos(p[:, 2]), np.sin(p[:, 2])], 1) @ self._freq
        view = np.cos(z + self._phase) * math.sqrt(2.0 / self.feature_dim)
        f = self.world_weight * self._code + (1.0 - self.world_weight) * view
        return (f / np.linalg.norm(f, axis=1, keepdims=True)).astype(np.float32)

    def detections(self, pose, rng: np.random.Generator | None = None, noise: float = 0.05):
        """Objects inside the field of view and range of ``pose``, in the world frame."""
        x, y, theta = pose
        out = []
        for ob in self.objects:
            dx, dy = ob.x - x, ob.y - y
            dist = math.hypot(dx, dy)
            bearing = se2.wrap_angle(math.atan2(dy, dx) - theta)
            if dist > SENSOR_RANGE_M or dist < 0.1 or abs(bearing) > HFOV_RAD / 2:
                continue
            ex, ey = (rng.normal(0.0, noise, 2) if rng is not None else (0.0, 0.0))
            u = 80.0 - 80.0 * bearing / (HFOV_RAD / 2)
            half = 40.0 / max(dist, 0.5)
            out.append(
                Detection(
                    ob.cls,
                    (ob.x + float(ex), ob.y + float(ey), ob.z),
                    (u - half, 60.0 - half, u + half, 60.0 + half),
                    dist,
                    int(4 * half * half),
                )
            )
        return out

    def _free(self, x: float, y: float) -> bool:
        return 0.2 <= x <= self.size[0] - 0.2 and 0.2 <= y <= self.size[1] - 0.2

    def start_pose(self, rng: np.random.Generator) -> se2.Pose:
        return (
            float(rng.uniform(0.5, self.size[0] - 0.5)),
            float(rng.uniform(0.5, self.size[1] - 0.5)),
            float(rng.choice(12) * TURN_RAD),
        )

    def walk(self, steps: int, seed: int = 0, start: se2.Pose | None = None):
        """A random walk: list of ``(action, world_pose)`` with the pose after each action.

        The first entry is ``(None, start)``. Where a forward move would leave the floor the
        walker turns left instead, so every recorded action did what its name says.
        """
        rng = np.random.default_rng(seed)
        pose = start if start is not None else self.start_pose(rng)
        out = [(None, pose)]
        for _ in range(steps):
            action = str(rng.choice(["move_forward"] * 3 + ["turn_left", "turn_right"]))
            x, y, th = pose
            if action == "move_forward":
                nx_, ny_ = x + FORWARD_M * math.cos(th), y + FORWARD_M * math.sin(th)
                if self._free(nx_, ny_):
                    pose = (nx_, ny_, th)
                else:
                    pose = (x, y, se2.wrap_angle(th + TURN_RAD))
                    action = "turn_left"
            else:
                sign = 1.0 if action == "turn_left" else -1.0
                pose = (x, y, se2.wrap_angle(th + sign * TURN_RAD))
            out.append((action, pose))
        return out

    def explore(
        self,
        steps: int,
        episode: int = 0,
        seed: int = 0,
        model_id: str | None = None,
        start: se2.Pose | None = None,
    ) -> AbstractModel:
        """Walk ``steps`` actions and record the Abstract Model in the episode's frame.

        As in the task, poses are relative to the start of the episode: the model's frame is the
        start pose, and :attr:`last_start` keeps that pose in world coordinates.
        """
        rng = np.random.default_rng(seed + 7919)
        path = self.walk(steps, seed=seed, start=start)
        origin = path[0][1]
        self.last_start = origin
        to_episode = se2.inverse(origin)
        model = AbstractModel(
            self.feature_dim,
            model_id=model_id or f"w{self.seed}-e{episode}",
            classes=self.classes,
            extractor=f"synthetic-{self.feature_dim}",
        )
        feats = self.features_batch(np.array([p for _, p in path]))
        prev = None
        for step, ((action, pose), f) in enumerate(zip(path, feats, strict=True)):
            dets = [
                Detection(
                    d.cls,
                    (*se2.apply_to_point(to_episode, d.position[0], d.position[1]), d.position[2]),
                    d.bbox,
                    d.distance,
                    d.pixels,
                )
                for d in self.detections(pose, rng)
            ]
            s = model.add_state(f, se2.compose(to_episode, pose), dets, episode=episode, step=step)
            if prev is not None:
                model.add_transition(prev, action, s)
            prev = s
        return model


def clustered_features(
    n_states: int, feature_dim: int = 2048, n_worlds: int = 20, seed: int = 0
) -> tuple[np.ndarray, np.ndarray, list[SyntheticWorld]]:
    """``n_states`` features from random poses in ``n_worlds`` worlds (several environments' worth).

    Returns ``(features, world_index, worlds)``.
    """
    rng = np.random.default_rng(seed)
    worlds = [
        SyntheticWorld(seed=seed * 1000 + i, feature_dim=feature_dim) for i in range(n_worlds)
    ]
    which = np.sort(rng.integers(0, n_worlds, n_states))
    feats = np.empty((n_states, feature_dim), dtype=np.float32)
    for i, w in enumerate(worlds):
        rows = np.flatnonzero(which == i)
        poses = np.stack(
            [
                rng.uniform(0, w.size[0], len(rows)),
                rng.uniform(0, w.size[1], len(rows)),
                rng.uniform(-math.pi, math.pi, len(rows)),
            ],
            1,
        )
        feats[rows] = w.features_batch(poses)
    return feats, which, worlds
