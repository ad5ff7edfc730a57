"""Views of any registered environment, collected through the environment protocol.

:class:`~kgnav.nets.encoder.views.ViewSampler` renders kgnav's houses from any pose; another
simulator offers only ``reset`` and ``step``. :class:`EnvViewSampler` therefore walks: in every
scene it runs a few episodes with a seeded random walk (mostly forward, turning on bumps and now
and then at random, never ``stop``) and keeps every frame with its pose. It then serves the
same calls as ``ViewSampler`` (``random_pose``, ``pose_near``, ``render``, ``render_depth``)
from those views, so the encoder's trainer and the relocation benchmark run unchanged on
another simulator's frames.

Poses are in the world frame when the environment tells where its episodes start (hook
``episode_start``); otherwise only the first episode of each scene is walked and poses stay in
its start frame. Headings come in multiples of the environment's turn angle, so "same place"
(within 0.5 m and 30°) pairs are views from nearby spots with equal or neighbouring headings.

The same arguments give the same views (the walk is seeded, the environments are).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from kgnav.common import se2
from kgnav.envs import EnvSuite, check_env, check_observation
from kgnav.envs.protocol import episode_seed
from kgnav.errors import KgnavError

Pose = tuple[float, float, float]


@dataclass(frozen=True)
class SceneViews:
    """The views of one scene: ``name``, poses (N, 3), RGB (N, H, W, 3), depth (N, H, W);
    ``semantic`` (N, H, W, 2) uint16 (class, instance ids) when the walk asked for it."""

    name: str
    poses: np.ndarray
    rgb: np.ndarray
    depth: np.ndarray
    semantic: np.ndarray | None = None


def walk_scene(env, name: str, steps: int, episodes: int, seed: int,
               scene: int = 0, semantic: bool = False) -> SceneViews:
    """``steps`` views of one environment (scene) from seeded random walks over its first
    ``episodes`` episodes (only the first without an ``episode_start`` hook). ``semantic``:
    keep the environment's semantic frames too (its ground truth, for training a segmenter);
    otherwise the walk tells the environment it may skip them. The walk is the same either
    way."""
    spec = check_env(env, name)
    if semantic and not spec.semantic:
        raise KgnavError(f"environment {spec.name!r} has no semantic channel (EnvSpec."
                         f"semantic): its frames carry no labels to train a segmenter on")
    act = spec.actions
    start_of = getattr(env, "episode_start", None)
    episodes = max(1, episodes if start_of is not None else 1)
    per = [steps // episodes + (k < steps % episodes) for k in range(episodes)]
    poses, rgbs, depths, sems = [], [], [], []
    forward, left, right = (act.index(a) for a in ("move_forward", "turn_left", "turn_right"))
    for ep, n in enumerate(per):
        s = episode_seed(seed, scene, ep)
        rng = np.random.default_rng(s)
        obs, _ = env.reset(seed=s, options={"episode": ep, "semantic": semantic})
        start = tuple(start_of(ep)) if start_of is not None else (0.0, 0.0, 0.0)
        last, turns = None, 0
        for k in range(n):
            check_observation(obs, spec, semantic)
            p = se2.compose(start, tuple(float(v) for v in obs["pose"]))
            poses.append(p)
            rgbs.append(obs["rgb"])
            depths.append(obs["depth"].astype(np.float16))
            if semantic:
                sems.append(_labels16(obs["semantic"], spec.name))
            if k == n - 1:
                break
            blocked = last is not None and math.dist(last[:2], p[:2]) < act.bump_distance
            if turns:  # finish a turn away from a wall
                a, turns = (left if turns > 0 else right), turns - (1 if turns > 0 else -1)
            elif blocked:
                t = int(rng.integers(1, act.turns(180) + 1))
                a = left if rng.random() < 0.5 else right
                turns = (t - 1) * (1 if a == left else -1)
            else:
                a = int(rng.choice([forward, left, right], p=[0.7, 0.15, 0.15]))
            last = p if a == forward else None
            obs, _r, term, trunc, _info = env.step(a)
            if term or trunc:
                break
    return SceneViews(name, np.array(poses, float), np.stack(rgbs), np.stack(depths),
                      np.stack(sems) if semantic else None)


def _labels16(sem: np.ndarray, env: str) -> np.ndarray:
    """A semantic frame as uint16 (half the memory of int32 over thousands of views)."""
    if sem.size and int(sem.max()) > np.iinfo(np.uint16).max:
        raise KgnavError(f"environment {env!r}: semantic ids above 65535 cannot be kept")
    return sem.astype(np.uint16)


class EnvViewSampler:
    """The views of several scenes, served like :class:`~kgnav.nets.encoder.views.ViewSampler`.

    ``views``: one :class:`SceneViews` per scene (:meth:`from_suite` walks them). A pose
    handed out by :meth:`random_pose` or :meth:`pose_near` is one of the stored views, and
    :meth:`render` returns its frame.
    """

    def __init__(self, views: Sequence[SceneViews]):
        if len(views) < 2:
            raise KgnavError("feature calibration needs views of at least two scenes "
                             f"(got {len(views)})")
        self.views = list(views)
        self.scenes = self.views  # ``.name`` per scene, as ViewSampler's scenes have
        self._index = [{tuple(map(float, p)): i for i, p in enumerate(v.poses)}
                       for v in self.views]

    @classmethod
    def from_suite(cls, suite: EnvSuite, scenes: Sequence[int], steps: int = 400,
                   episodes: int = 4, seed: int = 0,
                   progress: Callable[[int, int], None] | None = None,
                   semantic: bool = False) -> EnvViewSampler:
        """Walk ``steps`` views in each of ``scenes`` of an environment's suite (with their
        semantic frames when ``semantic``)."""
        out = []
        for n, k in enumerate(scenes):
            env = suite.make(k, episodes)
            name = str(getattr(env, "scene_name", None) or f"{suite.name}-{k:02d}")
            out.append(walk_scene(env, name, steps, min(episodes, suite.episode_count(k)),
                                  seed, k, semantic))
            if progress is not None:
                progress((n + 1) * steps, len(scenes) * steps)
        return cls(out)

    def __len__(self) -> int:
        return len(self.views)

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) of the frames."""
        h, w = self.views[0].rgb.shape[1:3]
        return w, h

    def random_pose(self, house: int, rng: np.random.Generator) -> Pose:
        poses = self.views[house].poses
        return tuple(map(float, poses[rng.integers(len(poses))]))

    def pose_near(self, house: int, pose: Pose, rng: np.random.Generator,
                  dist: tuple[float, float] = (0.0, 0.5),
                  turn: tuple[float, float] = (0.0, math.radians(30)),
                  tries: int = 40) -> Pose | None:
        """A stored view other than ``pose`` at a distance in ``dist`` and a heading offset in
        ``turn`` (both inclusive) from it; ``pose`` itself only when the ranges admit it and
        no other view does; None if none. (``tries``: ViewSampler's, unused here.)"""
        poses = self.views[house].poses
        d = np.hypot(poses[:, 0] - pose[0], poses[:, 1] - pose[1])
        t = np.abs(np.remainder(poses[:, 2] - pose[2] + np.pi, 2 * np.pi) - np.pi)
        eps = 1e-6
        ok = (d >= dist[0] - eps) & (d <= dist[1] + eps) & (t >= turn[0] - eps) \
            & (t <= turn[1] + eps)
        same = (d < eps) & (t < eps)
        cand = np.flatnonzero(ok & ~same)
        if len(cand):
            return tuple(map(float, poses[cand[rng.integers(len(cand))]]))
        if (ok & same).any():
            return tuple(map(float, pose))
        return None

    def _at(self, house: int, pose: Pose) -> int:
        try:
            return self._index[house][tuple(map(float, pose))]
        except KeyError:
            raise KgnavError(f"no stored view of scene {house} at pose {pose}") from None

    def render(self, house: int, pose: Pose) -> np.ndarray:
        return self.views[house].rgb[self._at(house, pose)]

    def render_depth(self, house: int, pose: Pose) -> tuple[np.ndarray, np.ndarray]:
        i = self._at(house, pose)
        v = self.views[house]
        return v.rgb[i], v.depth[i].astype(np.float32)
