"""The map-level environment the exploration policy is trained in: one step is one decision.

Between two decisions of the global policy the real agent takes up to 25 actions toward the
long-term goal and maps what its camera sees. Rendering those frames is what makes training on
the simulator slow, so this environment keeps the agent's map and drops the images:

* **Motion**: the goal cell (a cell of the agent's :class:`~kgnav.agent.mapping.EpisodeMap`,
  episode frame) is snapped to the nearest navigable cell of the ground truth (:class:`NavMap`),
  and the agent follows the Fast Marching path to it as the agent's planner does: a waypoint
  8 cells down the distance field; turn 30° when it is more than 20° off the heading, else move
  0.25 m along the path. A decision ends after ``interval`` actions (25) or when the goal is
  within 0.25 m (the agent then asks again), and the episode after ``max_steps`` actions (500).
* **Sensing**: per action, a 2-D ray cast from the pose on the ground-truth occupancy
  (``NavMap.obstacles``: walls, object footprints, outside the house) — ``n_rays`` columns over
  the camera's 79° HFOV, z-depth clipped to [0.5, 5] m like the depth camera — fused by the
  agent's own :class:`~kgnav.agent.mapping.MapBuilder` (a one-row camera): the same explored fan
  and obstacle cells as the agent builds from depth, in the same episode frame. With
  ``semantic=True`` the ray that stops on an object also labels it (the goal-class channel).
* **Feedback**: :meth:`step` returns the explored area gained (m², Active Neural SLAM's reward)
  and, with a goal class, the decrease of the geodesic distance to it (SemExp's); the trainer
  turns these into a reward.

Everything is numpy and OpenCV: a decision costs one Fast Marching on a window and ~25 ray fans.

>>> from kgnav.sim.episodes import episodes_for, load_scene_of
>>> env = MapExploreEnv([load_scene_of("train", 0)])
>>> m = env.reset(0, episodes_for("train", 0, 5)[0].start)
>>> fb = env.step(m.to_cell(2.0, 0.0))          # two metres ahead of the start
>>> fb.steps > 0 and fb.gain_m2 >= 0, env.steps == fb.steps
(True, True)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from kgnav.agent.camera import Camera
from kgnav.agent.mapping import EpisodeMap, MapBuilder
from kgnav.agent.planner import descend, fmm_distance
from kgnav.common.classes import OBJECT_CLASSES, class_id
from kgnav.sim.dynamics import compose, relative_pose, wrap_angle
from kgnav.sim.house import Scene, rasterize_box
from kgnav.sim.navmesh import NavMap


@dataclass(frozen=True)
class Feedback:
    """What one decision did: actions taken, explored area gained (m²), geodesic distance to
    the goal class before and after (m; ``inf`` without a goal), whether the long-term goal
    was reached and whether the episode is over."""

    steps: int
    gain_m2: float
    distance_before: float
    distance_after: float
    reached: bool
    done: bool

    @property
    def progress_m(self) -> float:
        """Decrease of the geodesic distance to the goal class (0 without a goal)."""
        if not (math.isfinite(self.distance_before) and math.isfinite(self.distance_after)):
            return 0.0
        return self.distance_before - self.distance_after


class _Segmentation:
    """The ray cast's class row, shaped as the mapping code reads a segmentation."""

    def __init__(self, classes: np.ndarray):
        self.classes = classes


class MapExploreEnv:
    """Decision-level exploration in ground-truth houses (see the module docstring).

    ``scenes``: the houses; :meth:`reset` picks one by index. ``semantic``: label what the rays
    hit (needed by ``ppo-semantic``). ``marks``: action counts at which the explored area is
    recorded in :attr:`coverage` (the coverage bench's 100/250/500).
    """

    def __init__(self, scenes: list[Scene], *, max_steps: int = 500, interval: int = 25,
                 n_rays: int = 80, camera: Camera | None = None, map_size: int = 480,
                 resolution: float = 0.05, semantic: bool = False,
                 explore_radius: float = 0.25, lookahead: int = 8,
                 turn_tolerance_deg: float = 20.0, step_m: float = 0.25,
                 turn_deg: float = 30.0, marks: tuple[int, ...] = ()):
        if not scenes:
            raise ValueError("no scenes")
        if max_steps < 1 or interval < 1 or n_rays < 2:
            raise ValueError("max_steps, interval >= 1 and n_rays >= 2 expected")
        self.scenes = list(scenes)
        cam = camera or Camera()
        # one image row at the horizon: every return lies at camera height, inside the
        # obstacle band, as a wall or object does in the full depth image
        self.camera = Camera(n_rays, 1, cam.hfov_deg, cam.height_m, cam.min_depth,
                             cam.max_depth)
        self.max_steps = int(max_steps)
        self.interval = int(interval)
        self.map_size = int(map_size)
        self.resolution = float(resolution)
        self.semantic = bool(semantic)
        self.explore_radius = float(explore_radius)
        self.lookahead = int(lookahead)
        self.turn_tolerance = math.radians(turn_tolerance_deg)
        self.step_m = float(step_m)
        self.turn = math.radians(turn_deg)
        self.marks = tuple(sorted(int(k) for k in marks))
        rr = self.camera.ray_right.astype(np.float64)
        self._ray_angle = np.arctan(-rr)  # column u's direction relative to the heading
        self._ray_cos = np.cos(self._ray_angle)
        reach = cam.max_depth / float(self._ray_cos.min())
        self._t = np.arange(1, int(math.ceil(reach / 0.05)) + 1) * 0.05  # one sample a cell
        self._houses: dict[int, tuple] = {}
        self.map_: EpisodeMap | None = None

    # ------------------------------------------------------------------ per house
    def _house(self, k: int):
        if k not in self._houses:
            scene = self.scenes[k]
            nav = NavMap.from_scene(scene)
            labels = np.zeros(nav.grid.shape, np.int16)
            for o in scene.objects:
                rasterize_box(labels, o.x0, o.y0, o.x1, o.y1, class_id(o.cls))
            # nearest navigable cell of every cell: labels of a distance transform
            _, lab = cv2.distanceTransformWithLabels((~nav.grid).astype(np.uint8), cv2.DIST_L2,
                                                     5, labelType=cv2.DIST_LABEL_PIXEL)
            nearest = np.argwhere(nav.grid)[lab - 1].astype(np.int32)
            self._houses[k] = (scene, nav, labels, nearest)
        return self._houses[k]

    # ------------------------------------------------------------------ episode
    def reset(self, scene: int, start, goal_class: str | None = None) -> EpisodeMap:
        """Start an episode in house ``scene`` at world pose ``start`` (x, y, theta); returns
        the agent's map after its first view."""
        if not 0 <= scene < len(self.scenes):
            raise ValueError(f"scene index {scene} out of range 0..{len(self.scenes) - 1}")
        if goal_class is not None and goal_class not in OBJECT_CLASSES:
            raise ValueError(f"unknown goal class {goal_class!r}")
        self.scene_index = scene
        self.scene, self.nav, self._labels, self._nearest = self._house(scene)
        self.goal_class = goal_class
        self.start = tuple(float(v) for v in start)
        self.world_pose = self.start
        self.steps = 0
        self.builder = MapBuilder(self.camera, self.map_size, self.resolution, stride=1,
                                  classes=OBJECT_CLASSES if self.semantic else ())
        self.map_ = self.builder.reset()
        self.coverage: dict[int, float] = {}
        self._reveal([self.start], self.builder)
        self._explored = int(np.count_nonzero(self.map_.explored))
        self.distance = self._goal_distance(self.start)
        return self.map_

    @property
    def pose(self) -> tuple[float, float, float]:
        """The agent's episode-frame pose (the start is (0, 0, 0)), as the agent observes it."""
        return tuple(float(v) for v in relative_pose(self.start, self.world_pose))

    @property
    def explored_m2(self) -> float:
        return self._explored * self.resolution ** 2

    @property
    def done(self) -> bool:
        return self.steps >= self.max_steps or self.distance == 0.0

    def step(self, cell: tuple[int, int]) -> Feedback:
        """Head for map cell ``cell`` (row, col of :attr:`map_`) for one decision."""
        if self.map_ is None:
            raise RuntimeError("reset() first")
        if self.done:
            raise RuntimeError("the episode is over")
        poses, reached = self._travel(self._snap(cell), self.max_steps - self.steps)
        before_d = self.distance
        self._explored = int(np.count_nonzero(self.map_.explored))  # whoever edited the map
        self._reveal(poses, self.builder, first_step=self.steps + 1)
        self.steps += len(poses)
        self.world_pose = poses[-1]
        n = int(np.count_nonzero(self.map_.explored))
        gain, self._explored = n - self._explored, n
        self.distance = self._goal_distance(self.world_pose)
        return Feedback(len(poses), gain * self.resolution ** 2, before_d, self.distance,
                        reached, self.done)

    def preview(self, cell: tuple[int, int]) -> float:
        """The explored area (m²) :meth:`step` would gain heading for ``cell``, changing
        nothing (the coverage oracle's look-ahead)."""
        poses, _ = self._travel(self._snap(cell), self.max_steps - self.steps)
        m = self.map_
        ai, aj = m.to_cell(*self.pose[:2])
        r = int(math.ceil((len(poses) * self.step_m + float(self._t[-1]) + 1.0)
                          / self.resolution))
        H, W = m.shape
        i0, i1, j0, j1 = max(ai - r, 0), min(ai + r + 1, H), max(aj - r, 0), min(aj + r + 1, W)
        scratch = EpisodeMap(obstacle=m.obstacle[i0:i1, j0:j1].copy(),
                             explored=m.explored[i0:i1, j0:j1].copy(),
                             semantic=np.zeros((0, i1 - i0, j1 - j0), np.uint16),
                             resolution=m.resolution, classes=(),
                             origin=(m.origin[0] - i0, m.origin[1] - j0))
        before = int(np.count_nonzero(scratch.explored))
        builder = MapBuilder(self.camera, self.map_size, self.resolution, stride=1,
                             classes=(), max_size=max(scratch.shape) + 2 * r)
        builder.map_ = scratch
        self._reveal(poses, builder, semantic=False)
        return (int(np.count_nonzero(builder.map_.explored)) - before) * self.resolution ** 2

    # ------------------------------------------------------------------ motion
    def _snap(self, cell) -> tuple[int, int]:
        """The ground-truth navigable cell nearest to episode-map cell ``cell``."""
        x, y = self.map_.to_xy(*cell)
        wx, wy, _ = compose(self.start, (x, y, 0.0))
        i, j = self.nav.to_cell(wx, wy)
        h, w = self.nav.grid.shape
        i, j = min(max(i, 0), h - 1), min(max(j, 0), w - 1)
        return int(self._nearest[i, j, 0]), int(self._nearest[i, j, 1])

    def _field(self, goal: tuple[int, int], agent: tuple[int, int]):
        """Fast Marching distances (cells) to ``goal`` over a window holding it and the agent
        (the whole house if the way round leaves the window); (field, row0, col0)."""
        grid = self.nav.grid
        pad = 40
        h, w = grid.shape
        i0, i1 = max(min(goal[0], agent[0]) - pad, 0), min(max(goal[0], agent[0]) + pad + 1, h)
        j0, j1 = max(min(goal[1], agent[1]) - pad, 0), min(max(goal[1], agent[1]) + pad + 1, w)
        for a0, a1, b0, b1 in ((i0, i1, j0, j1), (0, h, 0, w)):
            target = np.zeros((a1 - a0, b1 - b0), bool)
            target[goal[0] - a0, goal[1] - b0] = True
            f = fmm_distance(grid[a0:a1, b0:b1], target)
            if math.isfinite(f[agent[0] - a0, agent[1] - b0]):
                break
        return f, a0, b0

    def _travel(self, goal: tuple[int, int], budget: int):
        """World poses after each action toward navigable cell ``goal`` (at most
        ``min(interval, budget)``; at least one: a turn when there is nowhere to go)."""
        x, y, th = self.world_pose
        agent = self.nav.to_cell(x, y)
        f, a0, b0 = self._field(goal, agent)
        res = self.nav.resolution
        i, j = agent[0] - a0, agent[1] - b0
        poses, reached = [], False
        for _ in range(min(self.interval, budget)):
            if f[i, j] * res <= self.explore_radius:
                reached = True
                break
            path = descend(f, i, j, self.lookahead)
            if not path:
                break
            wx, wy = self.nav.to_world(path[-1][0] + a0, path[-1][1] + b0)
            err = wrap_angle(math.atan2(wy - y, wx - x) - th)
            if abs(err) > self.turn_tolerance:
                th = wrap_angle(th + math.copysign(self.turn, err))
            else:  # 0.25 m down the path
                k = self.step_m / res
                nxt = next((p for p in path if math.hypot(p[0] - i, p[1] - j) >= k - 1e-6),
                           path[-1])
                i, j = nxt
                x, y = self.nav.to_world(i + a0, j + b0)
            poses.append((x, y, th))
        if not poses:  # already there, or stuck: look around (the agent turns left)
            poses.append((x, y, wrap_angle(th + self.turn)))
        return poses, reached

    # ------------------------------------------------------------------ sensing
    def rays(self, poses) -> tuple[np.ndarray, np.ndarray]:
        """Per world pose and image column: the z-depth the depth camera would read (m, in
        [min_depth, max_depth]; max_depth = no return) and the 1-based class id of the object
        the ray stops on (0: wall, nothing, or beyond range). Shapes (P, n_rays)."""
        p = np.asarray(poses, np.float64).reshape(-1, 3)
        ang = p[:, 2:3] + self._ray_angle[None, :]  # (P, R)
        t = self._t
        xs = p[:, 0, None, None] + np.cos(ang)[:, :, None] * t
        ys = p[:, 1, None, None] + np.sin(ang)[:, :, None] * t
        nav = self.nav
        ii = np.floor((ys - nav.origin[1]) / nav.resolution).astype(np.int32)
        jj = np.floor((xs - nav.origin[0]) / nav.resolution).astype(np.int32)
        h, w = nav.obstacles.shape
        inside = (ii >= 0) & (ii < h) & (jj >= 0) & (jj < w)
        ii, jj = np.clip(ii, 0, h - 1), np.clip(jj, 0, w - 1)
        hit = nav.obstacles[ii, jj] | ~inside  # off the grid: nothing is ever out of the house
        first = hit.argmax(axis=2)
        any_hit = hit.any(axis=2)
        cam = self.camera
        z = t[first] * self._ray_cos[None, :]
        ret = any_hit & (z < cam.max_depth)
        depth = np.where(ret, np.maximum(z, cam.min_depth), cam.max_depth).astype(np.float32)
        pi, ri = np.indices(first.shape)
        cls = np.where(ret, self._labels[ii[pi, ri, first], jj[pi, ri, first]], 0)
        return depth, cls.astype(np.int32)

    def _reveal(self, poses, builder: MapBuilder, semantic: bool | None = None,
                first_step: int = 0) -> None:
        depth, cls = self.rays(poses)
        semantic = self.semantic if semantic is None else semantic
        for k, pose in enumerate(poses):
            ep = relative_pose(self.start, pose)
            seg = _Segmentation(cls[k:k + 1]) if semantic else None
            builder.update(depth[k:k + 1], ep, seg)
            step = first_step + k
            if step in self.marks and builder is self.builder:
                self.coverage[step] = (int(np.count_nonzero(builder.map_.explored))
                                       * self.resolution ** 2)

    def _goal_distance(self, pose) -> float:
        if self.goal_class is None:
            return math.inf
        f = self.nav.distance_field(self.goal_class)
        i, j = self.nav.to_cell(pose[0], pose[1])
        return float(f[i, j])
