"""MiniWorld as the environment ``miniworld`` (``pip install 'kgnav[miniworld]'``).

Seeded multi-room houses (:mod:`kgnav.envs.miniworld_house`) rendered by MiniWorld 2.1
(:mod:`kgnav.envs.miniworld_render`), behind the protocol of :mod:`kgnav.envs`:

* camera: 160 × 120 (``--width``/``--height``), 60° vertical field of view, 1.0 m above the
  floor, pitched 10° down; z-depth clipped to [0.1, 5] m;
* actions: kgnav's (0 stop, 1 move_forward, 2 turn_left, 3 turn_right), exactly 0.25 m and
  30°: MiniWorld's randomised step and turn sizes are not used; the agent moves on the
  house's navigable grid with kgnav's motion rule (optional actuation, odometry and depth
  noise as in kgnav's simulator: the same specs, ``--noise locobot`` included);
* classes: :data:`~kgnav.envs.miniworld_house.CLASSES`; the ``semantic`` frame (class and
  instance ids) comes from the adapter's label pass, read back only for episodes that ask for
  it (``reset(options={"semantic": False})`` skips it);
* ground truth: every hook of :data:`kgnav.envs.GROUND_TRUTH_HOOKS` (SPL and the other metrics
  with geodesic distances over the navigable grid, episode starts, the objects, the navigable
  map and true pose for the oracle, a picture from above).

Splits (``--split``): ``val`` (10 houses), ``train`` (40 other houses, for retraining
features), ``calib`` (10 more, for calibrating thresholds on houses neither trained on nor
evaluated), ``tiny`` (2 of the val houses, the tests'); 10 episodes a house by default.
MiniWorld is imported, and its OpenGL context opened, only when a scene first renders, and
in the process that renders it.

>>> suite = MiniWorldHouses(EnvOptions(split="tiny"))
>>> len(suite), suite.episode_count(0), suite.name
(2, 10, 'miniworld-tiny')
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from kgnav.envs.miniworld_house import (
    AGENT_RADIUS,
    CLASSES,
    SUCCESS_DISTANCE,
    House,
    generate_episodes,
    generate_house,
    miniworld_dir,
)
from kgnav.envs.registry import EnvOptions, register_env
from kgnav.envs.spec import ActionSpec, CameraSpec, EnvSpec
from kgnav.errors import KgnavError
from kgnav.sim.dynamics import ACTION_NAMES, STOP, Dynamics, Odometry
from kgnav.sim.env import noisy_depth
from kgnav.sim.metrics import dts, softspl, spl
from kgnav.sim.noise import NoiseSpec, resolve_noise

__all__ = ["SPLITS", "MiniWorldHouses", "MiniWorldNav"]

#: split -> house seeds
SPLITS: dict[str, tuple[int, ...]] = {
    "val": tuple(range(10)),
    "train": tuple(range(1000, 1040)),
    "calib": tuple(range(500, 510)),
    "tiny": (0, 1),
}
EPISODES_PER_HOUSE = 10


def camera_spec(width: int = 160, height: int = 120) -> CameraSpec:
    return CameraSpec(int(width), int(height), vfov_deg=60.0, pitch_deg=-10.0, height_m=1.0,
                      min_depth=0.1, max_depth=5.0)


@register_env("miniworld")
class MiniWorldHouses:
    """The houses of a split (``options.split``: :data:`SPLITS`)."""

    #: The learned segmenter and state encoder trained on MiniWorld's frames
    #: (``kgnav/weights/``; rebuilt by ``kgnav train-segmenter --env miniworld --steps 6000``,
    #: docs/segmenter.md, and by ``train-encoder --env miniworld`` with the loop threshold
    #: from ``relocation-bench --write-loop-threshold``, docs/bring-your-own-simulator.md).
    default_weights = {"segmenter": "segmenter-miniworld.npz",
                       "encoder": "encoder-miniworld.npz"}
    #: It applies the motion, pose-sensor and depth noise ``options.noise`` asks for.
    applies_noise = True

    def __init__(self, options: EnvOptions):
        if options.scenes_dir is not None:
            raise KgnavError("environment 'miniworld' generates its houses: it takes --split "
                             f"({', '.join(SPLITS)}), not --scenes-dir")
        if options.split not in SPLITS:
            raise KgnavError(f"unknown split {options.split!r} of environment 'miniworld' "
                             f"(known: {', '.join(SPLITS)})")
        self.noise = resolve_noise(options.noise, options.actuation_noise,
                                   options.odometry_noise)
        miniworld_dir()  # a one-line error now, not in a worker, when MiniWorld is missing
        self.options = options
        self.seeds = SPLITS[options.split]
        self.name = f"miniworld-{options.split}"

    def __len__(self) -> int:
        return len(self.seeds)

    def episode_count(self, k: int, n: int | None = None) -> int:
        return min(n, EPISODES_PER_HOUSE) if n else EPISODES_PER_HOUSE

    def make(self, k: int, n: int | None = None) -> MiniWorldNav:
        o = self.options
        seed = self.seeds[k]
        house = generate_house(seed, f"mw{seed:04d}")
        return MiniWorldNav(house, generate_episodes(house, self.episode_count(k, n)),
                            o.width, o.height, o.max_steps, noise=self.noise)


class MiniWorldNav:
    """ObjectNav in one MiniWorld house (the protocol of :mod:`kgnav.envs`, every hook)."""

    def __init__(self, house: House, episodes, width: int = 160, height: int = 120,
                 max_steps: int = 500, actuation_noise: float = 0.0,
                 odometry_noise: float = 0.0, noise: str | NoiseSpec | None = None):
        if not episodes:
            raise KgnavError(f"house {house.name!r}: no episodes")
        self.house, self.episodes = house, list(episodes)
        self.nav = house.nav
        self.max_steps = int(max_steps)
        self.noise_spec = resolve_noise(noise, float(actuation_noise), float(odometry_noise))
        self.noise = self.noise_spec.actuation
        self.odometry_noise = float(odometry_noise)
        self._depth_rng: np.random.Generator | None = None
        self.env_spec = EnvSpec("miniworld", camera_spec(width, height), ActionSpec(),
                                classes=CLASSES, semantic=True, max_steps=self.max_steps,
                                agent_radius=AGENT_RADIUS)
        self._renderer = None
        self._class_of = np.array([0] + [CLASSES.index(o.cls) + 1 for o in house.objects],
                                  np.int32)
        self._world = self.episodes[0].start
        self._semantic = True
        self.trajectory: list[tuple[float, float, float]] = []

    # ------------------------------------------------------------------ protocol
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        options = options or {}
        i = int(options.get("episode", 0))
        self.i = i
        self._semantic = bool(options.get("semantic", True))
        self.episode = self.episodes[i]
        rng = np.random.default_rng([0 if seed is None else int(seed), 0x4D57])
        self.dynamics = Dynamics(self.nav, self.noise, np.random.default_rng(rng.integers(2**31)))
        self.odometry = Odometry(model=self.noise_spec.odometry,
                                 rng=np.random.default_rng(rng.integers(2**31)))
        self._depth_rng = (np.random.default_rng([0 if seed is None else int(seed), 0x4D57, 0xD3])
                           if self.noise_spec.depth > 0 else None)
        self._start = tuple(float(v) for v in self.episode.start)
        self._world = self._start
        self._steps, self._path, self._done, self._stopped = 0, 0.0, False, False
        self.trajectory = [self._world]
        self._d_init = self.geodesic_distance(*self._start[:2])
        return self._observe(np.zeros(3)), {"goal_class": self.episode.goal_class}

    def step(self, action):
        if self._done:
            raise RuntimeError("episode is over: call reset() first")
        a = int(action)
        if not 0 <= a < len(ACTION_NAMES):
            raise ValueError(f"unknown action {action!r} (0 stop, 1 forward, 2 left, 3 right)")
        self._steps += 1
        before = self._world
        res = self.dynamics.step(before, a)
        self._world = res.pose
        self._path += res.travelled
        self.trajectory.append(self._world)
        pose = (self.odometry.update(before, self._world, res.blocked) if a != STOP
                else np.array(self.odometry.pose, np.float64))
        self._stopped = a == STOP
        truncated = not self._stopped and self._steps >= self.max_steps
        self._done = self._stopped or truncated
        return self._observe(pose), 0.0, self._stopped, truncated, self._info(res.collided)

    # ------------------------------------------------------------------ ground truth
    @property
    def scene_name(self) -> str:
        return self.house.name

    @property
    def world_pose(self) -> tuple[float, float, float]:
        return self._world

    def episode_start(self, i: int):
        return self.episodes[i].start

    def scene_objects(self):
        return self.house.objects

    def navigable_map(self):
        return self.nav

    def geodesic_distance(self, x: float, y: float, cls: str | None = None) -> float:
        return self.nav.geodesic_distance(x, y, cls or self.episode.goal_class)

    def l2_distance_to_goal(self, x: float | None = None, y: float | None = None) -> float:
        if x is None or y is None:
            x, y = self._world[:2]
        return self.nav.l2_to_class(x, y, self.episode.goal_class)

    def start_frame_to_world(self, x: float, y: float) -> tuple[float, float]:
        sx, sy, st = self._start
        c, s = math.cos(st), math.sin(st)
        return sx + c * x - s * y, sy + s * x + c * y

    def render_at(self, x: float, y: float, theta: float, semantic: bool = True):
        """(RGB, z-depth clipped to the camera's range, semantic (H, W, 2) or None unless
        ``semantic``) from a world pose."""
        if self._renderer is None:
            from kgnav.envs.miniworld_render import MiniWorldRenderer

            self._renderer = MiniWorldRenderer(self.house, self.env_spec.camera)
        rgb, z, ids = self._renderer.render(x, y, theta, labels=semantic)
        cam = self.env_spec.camera
        depth = np.clip(z, cam.min_depth, cam.max_depth).astype(np.float32)
        return rgb, depth, None if ids is None else np.stack([self._class_of[ids], ids], -1)

    def topdown(self, path=None, agent_map=None, map_resolution: float = 0.05,
                map_origin=(0.0, 0.0), **_kw):
        """MiniWorld's view from above with this episode's start (green), trajectory (blue)
        and goal instances (red); a PNG at ``path`` when given. ``agent_map`` (the agent's
        explored cells, in the episode-start frame) is not drawn."""
        import cv2

        from kgnav.sim.topdown import write_png

        self.render_at(*self._world, semantic=False)  # opens the renderer if needed
        img, sc = self._renderer.top_view()
        img = np.ascontiguousarray(img)

        def px(x, y):
            return (int(round(sc["x_offset"] + x * sc["x_scale"])),
                    int(round(sc["z_offset"] - y * sc["z_scale"])))

        for o in self.house.objects_of(self.episode.goal_class):
            cv2.rectangle(img, px(o.x0, o.y1), px(o.x1, o.y0), (220, 30, 30), 2)
        pts = np.array([px(x, y) for x, y, _ in self.trajectory], np.int32)
        cv2.polylines(img, [pts], False, (30, 60, 230), 2, cv2.LINE_AA)
        cv2.circle(img, px(*self._start[:2]), 5, (30, 180, 30), -1)
        if path is not None:
            write_png(img, path)
        return img

    # ------------------------------------------------------------------ internals
    def _observe(self, pose) -> dict[str, Any]:
        rgb, depth, sem = self.render_at(*self._world, semantic=self._semantic)
        if self._depth_rng is not None:
            cam = self.env_spec.camera
            depth = noisy_depth(depth, self.noise_spec.depth, self._depth_rng, cam.min_depth,
                                cam.max_depth)
        obs = {"rgb": rgb, "depth": depth, "pose": np.asarray(pose, np.float64),
               "objectgoal": np.int64(CLASSES.index(self.episode.goal_class) + 1)}
        if sem is not None:
            obs["semantic"] = sem
        return obs

    def _info(self, collided: bool) -> dict[str, Any]:
        x, y, _t = self._world
        d = self.geodesic_distance(x, y)
        l2 = self.l2_distance_to_goal(x, y)
        ok = self._stopped and l2 <= SUCCESS_DISTANCE
        return {
            "episode_id": self.episode.episode_id,
            "success": bool(ok),
            "spl": spl(ok, self._d_init, self._path),
            "softspl": softspl(d, self._d_init, self._d_init, self._path)
            if math.isfinite(d) else 0.0,
            "dts": dts(l2),
            "path_length": self._path,
            "shortest_path_length": self._d_init,
            "distance_to_goal": d,
            "collided": collided,
            "world_pose": np.array(self._world, np.float64),
        }
