"""The embedded ObjectNav simulator: procedural houses, a numpy ray caster, episodes, metrics.

>>> from kgnav.sim import ObjectNavEnv
>>> env = ObjectNavEnv(split="val", scene=0, width=160, height=120)
>>> obs, info = env.reset(seed=0)
>>> obs, reward, terminated, truncated, info = env.step(1)  # 0 stop, 1 forward, 2 left, 3 right
"""

from kgnav.sim.dynamics import (
    ACTION_NAMES,
    FORWARD_STEP,
    MOVE_FORWARD,
    STOP,
    TURN_ANGLE,
    TURN_LEFT,
    TURN_RIGHT,
    Dynamics,
    NoiseModel,
    Odometry,
    OdometryModel,
    StepResult,
    compose,
    relative_pose,
    wrap_angle,
)
from kgnav.sim.env import ObjectNavEnv
from kgnav.sim.episodes import (
    MAX_STEPS,
    SPLITS,
    Episode,
    cache_dir,
    episodes_for,
    generate_episodes,
    load_episodes,
    load_scene_of,
    load_split,
    save_episodes,
)
from kgnav.sim.house import (
    AGENT_RADIUS,
    GRID_RES,
    ROOM_KINDS,
    Door,
    ObjectInstance,
    Room,
    Scene,
    Texture,
    Wall,
    generate_house,
)
from kgnav.sim.metrics import (
    SUCCESS_DISTANCE,
    EpisodeMetrics,
    dts,
    episode_metrics,
    mean_metrics,
    path_length,
    softspl,
    spl,
    success,
)
from kgnav.sim.navmesh import NavMap
from kgnav.sim.render import CAMERA_HEIGHT, HFOV_DEG, MAX_DEPTH, MIN_DEPTH, Renderer
from kgnav.sim.scene_io import load_scene, save_scene, scene_from_dict, scene_to_dict
from kgnav.sim.topdown import draw_topdown

__all__ = [
    "ACTION_NAMES",
    "AGENT_RADIUS",
    "CAMERA_HEIGHT",
    "Door",
    "Dynamics",
    "Episode",
    "EpisodeMetrics",
    "FORWARD_STEP",
    "GRID_RES",
    "HFOV_DEG",
    "MAX_DEPTH",
    "MAX_STEPS",
    "MIN_DEPTH",
    "MOVE_FORWARD",
    "NavMap",
    "NoiseModel",
    "ObjectInstance",
    "ObjectNavEnv",
    "Odometry",
    "OdometryModel",
    "ROOM_KINDS",
    "Renderer",
    "Room",
    "SPLITS",
    "STOP",
    "SUCCESS_DISTANCE",
    "Scene",
    "StepResult",
    "TURN_ANGLE",
    "TURN_LEFT",
    "TURN_RIGHT",
    "Texture",
    "Wall",
    "cache_dir",
    "compose",
    "draw_topdown",
    "dts",
    "episode_metrics",
    "episodes_for",
    "generate_episodes",
    "generate_house",
    "load_episodes",
    "load_scene",
    "load_scene_of",
    "load_split",
    "mean_metrics",
    "path_length",
    "relative_pose",
    "save_episodes",
    "save_scene",
    "scene_from_dict",
    "scene_to_dict",
    "softspl",
    "spl",
    "success",
    "wrap_angle",
]
