"""kgnav's embedded simulator (:class:`kgnav.sim.ObjectNavEnv`) as the environment ``kgnav``.

>>> from kgnav.envs import make_env
>>> env = make_env("kgnav", EnvOptions(split="val-small", width=64, height=48)).make(0, 2)
>>> env.env_spec.camera.width, env.env_spec.actions.turn_deg, env.env_spec.semantic
(64, 30.0, True)
"""

from __future__ import annotations

from kgnav.envs.registry import EnvOptions, register_env
from kgnav.sim.env import ObjectNavEnv
from kgnav.sim.noise import resolve_noise
from kgnav.sim.sources import scene_source

__all__ = ["KgnavScenes"]


@register_env("kgnav")
class KgnavScenes:
    """The houses of a built-in split (``options.split``) or a directory written by
    ``kgnav scenes generate`` (``options.scenes_dir``)."""

    #: It applies the motion, pose-sensor and depth noise ``options.noise`` asks for.
    applies_noise = True

    def __init__(self, options: EnvOptions):
        resolve_noise(options.noise, options.actuation_noise,
                      options.odometry_noise)  # a bad spec: one line now, not in a worker
        self.options = options
        self.source = scene_source(options.split, options.scenes_dir)
        self.name = self.source.name if options.scenes_dir is None else options.scenes_dir

    def __len__(self) -> int:
        return len(self.source)

    def episode_count(self, k: int, n: int | None = None) -> int:
        return len(self.source.episodes(k, n))

    def make(self, k: int, n: int | None = None) -> ObjectNavEnv:
        o, src = self.options, self.source
        return ObjectNavEnv(src.name, src.scene(k), o.width, o.height,
                            episodes=src.episodes(k, n), max_steps=o.max_steps,
                            actuation_noise=o.actuation_noise,
                            odometry_noise=o.odometry_noise, noise=o.noise)
