"""Views of the simulator's houses and when two of them show "the same place".

Two views (house, x, y, θ) are related as follows — the definitions of both the training signal
and the relocation benchmark:

* **positive** (same place): same house, positions within :data:`POS_DIST` (0.5 m) and headings
  within :data:`POS_TURN` (30°);
* **negative** (another place): another house, or the same house with positions more than
  :data:`NEG_DIST` (1 m) apart or headings more than :data:`NEG_TURN` (90°) apart — a match on
  such a pair would put the agent in the wrong house, more than 1 m off, or facing elsewhere;
* otherwise **ambiguous** (0.5–1 m, 30–90°): neither rewarded nor penalised.

>>> relation(0, (0.0, 0.0, 0.0), 0, (0.3, 0.0, 0.4))
1
>>> relation(0, (0.0, 0.0, 0.0), 1, (0.0, 0.0, 0.0))
-1
>>> relation(0, (0.0, 0.0, 0.0), 0, (0.7, 0.0, 0.0))
0
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from kgnav.sim.house import Scene
from kgnav.sim.navmesh import NavMap
from kgnav.sim.render import Renderer

POS_DIST, POS_TURN = 0.5, math.radians(30)
NEG_DIST, NEG_TURN = 1.0, math.radians(90)
POSITIVE, AMBIGUOUS, NEGATIVE = 1, 0, -1

Pose = tuple[float, float, float]


def turn_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Absolute heading difference in [0, π] (broadcasts)."""
    return np.abs(np.remainder(np.asarray(a) - np.asarray(b) + np.pi, 2 * np.pi) - np.pi)


def relations(houses_a: np.ndarray, poses_a: np.ndarray, houses_b: np.ndarray,
              poses_b: np.ndarray) -> np.ndarray:
    """int8 :data:`POSITIVE` / :data:`AMBIGUOUS` / :data:`NEGATIVE` of view pairs, elementwise.

    ``houses_*`` are int arrays, ``poses_*`` the same shapes plus a last axis (x, y, θ); all
    broadcast together, so ``relations(h[:, None], p[:, None], h[None], p[None])`` is a matrix.
    """
    pa, pb = np.asarray(poses_a, float), np.asarray(poses_b, float)
    same = np.asarray(houses_a) == np.asarray(houses_b)
    d = np.hypot(pa[..., 0] - pb[..., 0], pa[..., 1] - pb[..., 1])
    t = turn_between(pa[..., 2], pb[..., 2])
    out = np.zeros(np.broadcast(same, d).shape, np.int8)
    out[same & (d <= POS_DIST) & (t <= POS_TURN)] = POSITIVE
    out[~same | (d > NEG_DIST) | (t > NEG_TURN)] = NEGATIVE
    return out


def relation_matrix(houses: np.ndarray, poses: np.ndarray,
                    houses_b: np.ndarray | None = None,
                    poses_b: np.ndarray | None = None) -> np.ndarray:
    """:func:`relations` of every view of the first set (N) with every one of the second (M),
    (N, M); the second set defaults to the first."""
    houses = np.asarray(houses)
    poses = np.asarray(poses, float).reshape(-1, 3)
    hb = houses if houses_b is None else np.asarray(houses_b)
    pb = poses if poses_b is None else np.asarray(poses_b, float).reshape(-1, 3)
    return relations(houses[:, None], poses[:, None], hb[None, :], pb[None, :])


def relation(house_a: int, pose_a: Pose, house_b: int, pose_b: Pose) -> int:
    """Relation of two views: 1 positive, 0 ambiguous, -1 negative."""
    return int(relations(np.array(house_a), np.array(pose_a), np.array(house_b),
                         np.array(pose_b)))


class ViewSampler:
    """Random poses on the navigable floor of some houses, and their rendered RGB frames.

    ``width``/``height`` are the render resolution (the agent's 160×120 by default: the encoder
    must learn on exactly the frames it will be given, downscaled the same way).
    """

    def __init__(self, scenes: Sequence[Scene], width: int = 160, height: int = 120):
        self.scenes = list(scenes)
        self.width, self.height = width, height
        self.navs = [NavMap.from_scene(s) for s in self.scenes]
        self.cells = [nav.navigable_cells() for nav in self.navs]
        self._renderers: dict[int, Renderer] = {}

    def __len__(self) -> int:
        return len(self.scenes)

    def random_pose(self, house: int, rng: np.random.Generator) -> Pose:
        """Uniform over navigable cells (jittered inside the cell), heading uniform."""
        nav, cells = self.navs[house], self.cells[house]
        i, j = cells[rng.integers(len(cells))]
        x, y = nav.to_world(int(i), int(j))
        r = nav.resolution
        return (x + rng.uniform(-r / 2, r / 2), y + rng.uniform(-r / 2, r / 2),
                rng.uniform(-math.pi, math.pi))

    def pose_near(self, house: int, pose: Pose, rng: np.random.Generator,
                  dist: tuple[float, float] = (0.0, POS_DIST),
                  turn: tuple[float, float] = (0.0, POS_TURN),
                  tries: int = 40) -> Pose | None:
        """A navigable pose at distance in ``dist`` and heading offset in ``turn`` from ``pose``.

        Distance is uniform over the annulus' area, the turn uniform with a random sign. None if
        no navigable position was found in ``tries`` draws.
        """
        x, y, th = pose
        nav = self.navs[house]
        lo, hi = dist
        for _ in range(tries):
            r = math.sqrt(rng.uniform(lo * lo, hi * hi))
            phi = rng.uniform(-math.pi, math.pi)
            dth = rng.uniform(*turn) * (1 if rng.random() < 0.5 else -1)
            px, py = x + r * math.cos(phi), y + r * math.sin(phi)
            if nav.is_navigable(px, py):
                return (px, py, math.remainder(th + dth, 2 * math.pi))
        return None

    def renderer(self, house: int) -> Renderer:
        if house not in self._renderers:
            self._renderers[house] = Renderer(self.scenes[house], self.width, self.height)
        return self._renderers[house]

    def render(self, house: int, pose: Pose) -> np.ndarray:
        """RGB uint8 frame (H, W, 3) seen from ``pose`` in ``house``."""
        return self.renderer(house).render(*pose)[0]

    def render_depth(self, house: int, pose: Pose) -> tuple[np.ndarray, np.ndarray]:
        """(RGB, depth) frames seen from ``pose`` in ``house``."""
        rgb, depth, _ = self.renderer(house).render(*pose)
        return rgb, depth
