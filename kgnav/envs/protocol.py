"""The environment protocol: what kgnav's agent and benchmark need from a simulator.

An environment is a gymnasium-style object for one scene (a house) holding several episodes:

* ``env_spec``: an :class:`~kgnav.envs.spec.EnvSpec` (camera, actions, class vocabulary);
* ``reset(seed=..., options={"episode": i}) -> (obs, info)`` starts episode ``i``; with
  ``options["semantic"] = False`` the episode's observations need not carry ``semantic``
  (the benchmark asks so when nothing in the run reads it; an environment for which labels
  cost time skips them, one for which they are free may ignore the option);
* ``step(action) -> (obs, reward, terminated, truncated, info)``; ``terminated`` after
  ``stop``, ``truncated`` at the step limit.

Observations (:data:`OBSERVATION_KEYS`, checked by :func:`check_observation`):

============= ============== =====================================================================
key           dtype, shape   meaning
============= ============== =====================================================================
``rgb``       uint8 (H,W,3)  the colour frame
``depth``     float (H,W)    z-depth in metres (along the optical axis), clipped to the camera's
                             [min_depth, max_depth]; ``max_depth`` means no return within range
``pose``      float (3,)     (x, y, θ) relative to the episode start, in the start's frame: x
                             forward, y left, metres; θ radians counter-clockwise; (0, 0, 0) at
                             reset
``objectgoal`` int           the goal class, 1-based id into ``env_spec.classes``
``semantic``  int (H,W,2)    only if ``env_spec.semantic`` (and the episode did not decline it):
                             channel 0 class id (0 none), channel 1 instance id (0 none); ground
                             truth for the noise segmenters and some metrics
============= ============== =====================================================================

At an episode's end ``info["success"]`` (bool) is required. Everything else is ground truth
used only for metrics and failure analysis, never by the agent; an environment that lacks it
gets those numbers reported as missing (``null``), never invented (:data:`GROUND_TRUTH_HOOKS`).

>>> import numpy as np
>>> from kgnav.envs.spec import CameraSpec, EnvSpec
>>> spec = EnvSpec("toy", CameraSpec(4, 3, hfov_deg=90.0), classes=("box",))
>>> obs = {"rgb": np.zeros((3, 4, 3), np.uint8), "depth": np.ones((3, 4), np.float32),
...        "pose": np.zeros(3), "objectgoal": 1}
>>> check_observation(obs, spec)
>>> try:
...     check_observation({**obs, "depth": np.ones((3, 4))}, spec)
... except EnvProtocolError as e:
...     print(e)
environment 'toy': observation 'depth' must be float32, got float64
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np

from kgnav.envs.spec import EnvSpec, EnvSpecError

#: Observation keys every environment provides, and ``semantic`` when its spec says so.
OBSERVATION_KEYS = ("rgb", "depth", "pose", "objectgoal")

#: Optional ground truth an environment may offer, and what is missing without it. Methods and
#: attributes of the environment, or keys of the ``info`` dict a step returns.
GROUND_TRUTH_HOOKS: dict[str, str] = {
    "info['spl'], info['softspl'], info['dts']": "those metrics (null in episodes.jsonl, and "
                                                 "the variant's mean null)",
    "info['path_length'], info['shortest_path_length']": "the path lengths (null)",
    "info['episode_id']": "the episode id in episodes.jsonl (null)",
    "scene_name": "a scene name (else '<env>-<k>'; relocations count as same-house by it)",
    "episode_start(i)": "the world start pose of episode i: the relocation errors "
                        "(error_m, error_deg; wrong_merges counts only the other house's) and "
                        "memory fidelity",
    "start_frame_to_world(x, y), l2_distance_to_goal(x, y)": "failure analysis: the target's "
                                                             "distance to a real goal; failures "
                                                             "other than Exploration are null",
    "scene_objects()": "memory fidelity (the real instances: id, cls, distance_to(x, y)) "
                       "and goal_in_memory (null without it or episode_start)",
    "obs['semantic'] instances": "which real instances the episodes saw (fidelity recall)",
    "navigable_map(), world_pose": "the oracle variant",
    "topdown(path, ...)": "the --show pictures",
    "max_steps (writable)": "pre-exploration (hp/sp) longer than one episode",
}


def episode_seed(seed: int, scene: int, episode: int) -> int:
    """The seed a run passes to ``reset`` for episode ``episode`` of scene ``scene``: one
    independent stream per episode, so a variant, a worker or a resumed run meets the same
    episode whatever ran before it."""
    return int(np.random.SeedSequence([seed, scene, episode]).generate_state(1)[0])


class EnvProtocolError(EnvSpecError):
    """An environment broke the protocol (a missing key, a wrong dtype or shape)."""


@runtime_checkable
class NavEnv(Protocol):
    """One scene of an environment, its episodes served by ``reset`` (see the module doc)."""

    env_spec: EnvSpec

    def reset(self, *, seed: int | None = None, options: dict | None = None
              ) -> tuple[dict[str, Any], dict[str, Any]]: ...

    def step(self, action: int) -> tuple[dict[str, Any], float, bool, bool, dict[str, Any]]: ...


def check_env(env, name: str = "") -> EnvSpec:
    """The spec of ``env``, or a one-line :class:`EnvProtocolError` saying what is missing."""
    who = name or type(env).__name__
    spec = getattr(env, "env_spec", None)
    if not isinstance(spec, EnvSpec):
        raise EnvProtocolError(f"environment {who!r} has no env_spec (a kgnav.envs.EnvSpec), "
                               f"got {type(spec).__name__}")
    for m in ("reset", "step"):
        if not callable(getattr(env, m, None)):
            raise EnvProtocolError(f"environment {who!r} has no {m}() method")
    return spec


def check_observation(obs, spec: EnvSpec, semantic: bool | None = None) -> None:
    """Raise a one-line :class:`EnvProtocolError` if ``obs`` breaks the protocol of ``spec``:
    a missing key, a wrong dtype or shape, a goal outside the vocabulary. ``semantic``: whether
    the episode asked for the semantic frame (None: ``spec.semantic``); one that did not ask
    may lack it, and one it carries anyway is still checked."""

    def bad(msg: str) -> EnvProtocolError:
        return EnvProtocolError(f"environment {spec.name!r}: {msg}")

    if not isinstance(obs, dict):
        raise bad(f"observation must be a dict, got {type(obs).__name__}")
    asked = spec.semantic if semantic is None else spec.semantic and semantic
    keys = OBSERVATION_KEYS + (("semantic",) if asked else ())
    missing = [k for k in keys if k not in obs]
    if missing:
        raise bad(f"observation has no {', '.join(map(repr, missing))} "
                  f"(has: {', '.join(map(str, obs)) or 'nothing'})")
    H, W = spec.camera.height, spec.camera.width
    _array(obs, "rgb", np.uint8, (H, W, 3), bad)
    _array(obs, "depth", np.float32, (H, W), bad)
    pose = obs["pose"]
    if np.shape(pose) != (3,) or np.asarray(pose).dtype.kind != "f":
        raise bad(f"observation 'pose' must be 3 floats (x, y, theta), got {_desc(pose)}")
    goal = obs["objectgoal"]
    if np.ndim(goal) > 1 or np.size(goal) != 1 or np.asarray(goal).dtype.kind not in "iu":
        raise bad(f"observation 'objectgoal' must be one integer class id, got {_desc(goal)}")
    k = int(np.asarray(goal).reshape(-1)[0])
    if not 1 <= k <= len(spec.classes):
        raise bad(f"observation 'objectgoal' {k} is no class id (1..{len(spec.classes)})")
    if spec.semantic and "semantic" in obs:
        sem = obs["semantic"]
        if not isinstance(sem, np.ndarray) or sem.shape != (H, W, 2) or sem.dtype.kind not in "iu":
            raise bad(f"observation 'semantic' must be an integer ({H}, {W}, 2) array, "
                      f"got {_desc(sem)}")


def _array(obs, key: str, dtype, shape: tuple[int, ...], bad) -> None:
    a = obs[key]
    if not isinstance(a, np.ndarray):
        raise bad(f"observation {key!r} must be a numpy array, got {type(a).__name__}")
    if a.dtype != dtype:
        raise bad(f"observation {key!r} must be {np.dtype(dtype).name}, got {a.dtype}")
    if a.shape != shape:
        raise bad(f"observation {key!r} must have shape {shape} (the declared camera), "
                  f"got {a.shape}")


def _desc(a: object) -> str:
    return f"{a.dtype} {a.shape}" if isinstance(a, np.ndarray) else repr(a)[:40]
