"""``ObjectNavEnv``: the embedded simulator as a ``gymnasium.Env``.

>>> from kgnav.sim import ObjectNavEnv
>>> env = ObjectNavEnv(split="val", scene=0, width=160, height=120)
>>> obs, info = env.reset(seed=0)
>>> obs["rgb"].shape, obs["depth"].shape, obs["semantic"].shape, obs["pose"].tolist()
((120, 160, 3), (120, 160), (120, 160, 2), [0.0, 0.0, 0.0])
>>> obs, reward, terminated, truncated, info = env.step(1)  # move_forward
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from kgnav.common.classes import OBJECT_CLASSES, class_id
from kgnav.envs.spec import ActionSpec, CameraSpec, EnvSpec
from kgnav.sim.dynamics import (
    ACTION_NAMES,
    FORWARD_STEP,
    STOP,
    TURN_ANGLE,
    Dynamics,
    NoiseModel,
    Odometry,
    relative_pose,
)
from kgnav.sim.episodes import (
    MAX_STEPS,
    Episode,
    episodes_for,
    generate_episodes,
    load_scene_of,
)
from kgnav.sim.house import AGENT_RADIUS, Scene
from kgnav.sim.metrics import SUCCESS_DISTANCE, dts, softspl, spl
from kgnav.sim.navmesh import NavMap
from kgnav.sim.noise import NoiseSpec, resolve_noise
from kgnav.sim.render import CAMERA_HEIGHT, HFOV_DEG, MAX_DEPTH, MIN_DEPTH, Renderer

SUCCESS_REWARD = 2.5
SLACK_REWARD = -0.01


class ObjectNavEnv(gym.Env):
    """Object Goal Navigation in one procedural house.

    Parameters: ``split``/``scene`` pick a house of a split (``scene`` an index), or pass a
    :class:`Scene` as ``scene`` (then ``split`` is ignored); ``episodes`` overrides the episode
    list (default: :func:`episodes_for`, or 20 generated episodes for a custom scene).
    ``actuation_noise`` is a :class:`NoiseModel` or a float multiplier of
    :meth:`NoiseModel.scaled`; ``odometry_noise`` (m, and the same number of degrees) is the
    per-step standard deviation of the pose sensor's dead-reckoning error. Both default to 0.
    ``noise``: a named noise model instead (:mod:`kgnav.sim.noise`: ``"locobot"``,
    ``"locobot,depth=0.01"``, ... or a :class:`~kgnav.sim.noise.NoiseSpec`; default none).

    Episode choice at ``reset``: ``options={"episode": i}`` (index or :class:`Episode`), else
    ``seed % len(episodes)`` when a seed is given, else the episode after the previous one.
    The seed also seeds the noise generators.

    It implements the environment protocol of :mod:`kgnav.envs` (``env_spec``) with every
    ground-truth hook (``scene_name``, ``episode_start``, ``start_frame_to_world``,
    ``l2_distance_to_goal``, ``scene_objects``, ``navigable_map``, ``world_pose``, ``topdown``).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(
        self,
        split: str = "val",
        scene: int | Scene = 0,
        width: int = 160,
        height: int = 120,
        *,
        episodes: list[Episode] | None = None,
        n_episodes: int | None = None,
        hfov_deg: float = HFOV_DEG,
        camera_height: float = CAMERA_HEIGHT,
        min_depth: float = MIN_DEPTH,
        max_depth: float = MAX_DEPTH,
        max_steps: int = MAX_STEPS,
        actuation_noise: float | NoiseModel = 0.0,
        odometry_noise: float = 0.0,
        noise: str | NoiseSpec | None = None,
        render_mode: str | None = None,
        cache: bool = True,
    ):
        if isinstance(scene, Scene):
            self.scene = scene
            self.episodes = list(episodes) if episodes is not None else generate_episodes(
                scene, n_episodes or 20)
        else:
            self.scene = load_scene_of(split, int(scene), cache)
            self.episodes = list(episodes) if episodes is not None else episodes_for(
                split, int(scene), n_episodes, cache)
        if not self.episodes:
            raise ValueError("no episodes")
        self.split = split
        self.nav = NavMap.from_scene(self.scene)
        self.renderer = Renderer(self.scene, width, height, hfov_deg, camera_height,
                                 min_depth, max_depth)
        self.max_steps = int(max_steps)
        if isinstance(actuation_noise, NoiseModel):
            spec = resolve_noise(noise, 0.0, odometry_noise)
            if actuation_noise.active:
                spec = replace(spec, name="custom", actuation=actuation_noise)
        else:
            spec = resolve_noise(noise, float(actuation_noise), float(odometry_noise))
        self.noise_spec = spec
        self.noise = spec.actuation
        self.odometry_noise = float(odometry_noise)
        self.render_mode = render_mode
        H, W = int(height), int(width)
        n_cls = len(OBJECT_CLASSES)
        big = np.finfo(np.float32).max
        self.observation_space = spaces.Dict({
            "rgb": spaces.Box(0, 255, (H, W, 3), np.uint8),
            "depth": spaces.Box(min_depth, max_depth, (H, W), np.float32),
            "semantic": spaces.Box(0, max(len(self.scene.objects), n_cls), (H, W, 2), np.int32),
            "pose": spaces.Box(-np.inf, np.inf, (3,), np.float64),
            "gps": spaces.Box(-big, big, (2,), np.float32),
            "compass": spaces.Box(-np.pi, np.pi, (1,), np.float32),
            "objectgoal": spaces.Discrete(n_cls + 1),
        })
        self.action_space = spaces.Discrete(4)
        r = self.renderer
        self.env_spec = EnvSpec(
            "kgnav",
            CameraSpec(r.width, r.height, hfov_deg=math.degrees(r.hfov), height_m=r.cam_h,
                       min_depth=r.min_depth, max_depth=r.max_depth),
            ActionSpec(ACTION_NAMES, FORWARD_STEP, round(math.degrees(TURN_ANGLE), 9)),
            classes=OBJECT_CLASSES, semantic=True, max_steps=self.max_steps,
            agent_radius=AGENT_RADIUS)
        self._next_episode = 0
        self.episode: Episode = self.episodes[0]
        self._world = (0.0, 0.0, 0.0)
        self._done = True
        self._depth_rng: np.random.Generator | None = None
        self._obs: dict[str, Any] | None = None
        self.trajectory: list[tuple[float, float, float]] = []

    # ------------------------------------------------------------------ gymnasium API
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        ep = (options or {}).get("episode")
        if isinstance(ep, Episode):
            self.episode = ep
        else:
            if ep is not None:
                i = int(ep)
            elif seed is not None:
                i = int(seed) % len(self.episodes)
            else:
                i = self._next_episode
            self.episode = self.episodes[i % len(self.episodes)]
            self._next_episode = (i + 1) % len(self.episodes)
        a, b = (int(v) for v in self.np_random.integers(0, 2**31 - 1, size=2))
        self.dynamics = Dynamics(self.nav, self.noise, np.random.default_rng(a))
        self.odometry = Odometry(model=self.noise_spec.odometry, rng=np.random.default_rng(b))
        self._depth_rng = (np.random.default_rng([a, b, 0xD3]) if self.noise_spec.depth > 0
                           else None)
        self._start = tuple(float(v) for v in self.episode.start)
        self._world = self._start
        self._steps = 0
        self._path = 0.0
        self._done = False
        self._stopped = False
        self._collided = False
        self._last: int | None = None
        self.trajectory = [self._world]
        self._d_init = self.geodesic_distance(*self._start[:2])
        self._d_prev = self._d_init
        obs = self._observe(np.zeros(3))
        return obs, self._info()

    def step(self, action):
        if self._done:
            raise RuntimeError("episode is over: call reset() first")
        a = int(action)
        if not 0 <= a < 4:
            raise ValueError(f"unknown action {action!r} (0 stop, 1 forward, 2 left, 3 right)")
        self._steps += 1
        before = self._world
        res = self.dynamics.step(before, a)
        self._world = res.pose
        self._last = a
        self._collided = res.collided
        self._path += res.travelled
        self.trajectory.append(self._world)
        pose = self.odometry.update(before, self._world, res.blocked) if a != STOP else \
            np.array(self.odometry.pose, np.float64)
        terminated = a == STOP
        truncated = not terminated and self._steps >= self.max_steps
        self._stopped = terminated
        self._done = terminated or truncated
        d = self.geodesic_distance(*self._world[:2])
        reward = SLACK_REWARD
        if math.isfinite(d) and math.isfinite(self._d_prev):
            reward += self._d_prev - d
        self._d_prev = d
        info = self._info(d)
        if info["success"]:
            reward += SUCCESS_REWARD
        obs = self._observe(pose)
        return obs, float(reward), bool(terminated), bool(truncated), info

    def render(self):
        """The current RGB frame (``render_mode="rgb_array"``)."""
        return None if self._obs is None else self._obs["rgb"]

    # ------------------------------------------------------------------ ground truth
    @property
    def world_pose(self) -> tuple[float, float, float]:
        """The agent's true world pose (x, y, theta)."""
        return self._world

    @property
    def goal_class(self) -> str:
        return self.episode.goal_class

    @property
    def scene_name(self) -> str:
        return self.scene.name

    def episode_start(self, i: int):
        """World start pose (x, y, theta) of episode ``i``."""
        return self.episodes[i].start

    def scene_objects(self):
        """The house's object instances (:class:`kgnav.sim.house.ObjectInstance`)."""
        return self.scene.objects

    def navigable_map(self) -> NavMap:
        """Ground-truth navigable map: ``.grid`` (bool, rows = y), ``.resolution``, ``.origin``."""
        return self.nav

    def geodesic_distance(self, x: float, y: float, cls: str | None = None) -> float:
        """Geodesic distance (m) from world (x, y) to the success region of ``cls``
        (default: the current goal class)."""
        return self.nav.geodesic_distance(x, y, cls or self.episode.goal_class)

    def l2_distance_to_goal(self, x: float | None = None, y: float | None = None) -> float:
        """L2 distance from (x, y) (default: the agent) to the closest goal footprint."""
        if x is None or y is None:
            x, y = self._world[0], self._world[1]
        return self.nav.l2_to_class(x, y, self.episode.goal_class)

    def start_frame_to_world(self, x: float, y: float) -> tuple[float, float]:
        """Map a point from the episode-start frame (the pose observation's) to the world."""
        sx, sy, st = self._start
        c, s = math.cos(st), math.sin(st)
        return sx + c * x - s * y, sy + s * x + c * y

    def world_to_start_frame(self, x: float, y: float) -> tuple[float, float]:
        """Map a world point into the episode-start frame."""
        p = relative_pose(self._start, (x, y, 0.0))
        return float(p[0]), float(p[1])

    def topdown(self, path=None, agent_map=None, **kw):
        """Top-down picture of the scene with this episode's trajectory (see
        :func:`kgnav.sim.topdown.draw_topdown`); writes a PNG when ``path`` is given."""
        from kgnav.sim.topdown import draw_topdown

        return draw_topdown(self.scene, path=path, episode=self.episode,
                            trajectory=self.trajectory, agent_map=agent_map, **kw)

    # ------------------------------------------------------------------ internals
    def _observe(self, pose) -> dict[str, Any]:
        rgb, depth, sem = self.renderer.render(*self._world)
        if self._depth_rng is not None:
            depth = noisy_depth(depth, self.noise_spec.depth, self._depth_rng,
                                self.renderer.min_depth, self.renderer.max_depth)
        pose = np.asarray(pose, np.float64)
        self._obs = {
            "rgb": rgb,
            "depth": depth,
            "semantic": sem,
            "pose": pose,
            "gps": pose[:2].astype(np.float32),
            "compass": np.array([pose[2]], np.float32),
            "objectgoal": np.int64(class_id(self.episode.goal_class)),
        }
        return self._obs

    def _info(self, d: float | None = None) -> dict[str, Any]:
        if d is None:
            d = self._d_prev
        x, y, _t = self._world
        l2 = self.nav.l2_to_class(x, y, self.episode.goal_class)
        ok = self._stopped and l2 <= SUCCESS_DISTANCE
        shortest = self._d_init
        return {
            "scene": self.scene.name,
            "split": self.split,
            "episode": self.episode,
            "episode_id": self.episode.episode_id,
            "goal_class": self.episode.goal_class,
            "world_pose": np.array(self._world, np.float64),
            "start_pose": np.array(self._start, np.float64),
            "steps": self._steps,
            "collided": self._collided,
            "path_length": self._path,
            "distance_to_goal": d,
            "l2_distance_to_goal": l2,
            "shortest_path_length": shortest,
            "success": bool(ok),
            "spl": spl(ok, shortest, self._path),
            "softspl": softspl(d, self._d_init, shortest, self._path) if math.isfinite(d) else 0.0,
            "dts": dts(l2),
            "done": self._done,
            "last_action": ACTION_NAMES[self._last] if self._last is not None else None,
        }


def noisy_depth(depth: np.ndarray, per_m: float, rng: np.random.Generator, lo: float,
                hi: float) -> np.ndarray:
    """``depth`` with Gaussian noise of ``per_m`` m per metre of depth, clipped to [lo, hi]."""
    d = depth + rng.standard_normal(depth.shape) * (per_m * depth)
    return np.clip(d, lo, hi).astype(np.float32)
