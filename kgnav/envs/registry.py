"""Environments by name: ``register_env`` adds one, ``make_env`` builds its scenes.

A name is found among the registered ones, those that installed packages declare under the
entry-point group ``kgnav.envs`` (``[project.entry-points."kgnav.envs"] mysim =
"mysim_kgnav:MySimScenes"``), or, written ``module:attribute``, imported from that module (a
quick way to try an adapter: ``kgnav eval --env my_adapter:MyScenes``).

A registered factory takes :class:`EnvOptions` (what ``kgnav eval`` was asked for: split or
directory, image size, step limit, noise; a factory uses what applies to it) and returns an
:class:`EnvSuite`: its scenes, how many episodes each has, and one
:class:`~kgnav.envs.protocol.NavEnv` per scene. kgnav's own simulator is ``kgnav`` (the
default); it registers on first use so that nothing here imports it.

>>> "kgnav" in env_names()
True
>>> suite = make_env("kgnav", EnvOptions(split="val-small"))
>>> len(suite), suite.name, suite.episode_count(0, 3)
(11, 'val-small', 3)
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

from kgnav.envs.protocol import NavEnv
from kgnav.errors import KgnavError
from kgnav.registry import Registry


@dataclass(frozen=True)
class EnvOptions:
    """What a run asks of an environment. ``split``: a named set of scenes (the environment's
    own names; kgnav's are ``val``, ``train``, ...); ``scenes_dir``: a directory of scenes
    instead; ``width`` × ``height``: the image size; ``max_steps``: actions per episode;
    ``noise``: a noise spec (:func:`kgnav.sim.noise.parse_noise`: ``"locobot"``,
    ``"locobot,depth=0.01"``, ...; None: :data:`kgnav.sim.noise.DEFAULT_NOISE`);
    ``actuation_noise``, ``odometry_noise``: the older generic motion and pose-sensor noise
    levels (with a named model in ``noise``, leave them 0). An environment whose factory
    applies them says so with ``applies_noise = True`` (:func:`env_applies_noise`); the
    benchmark gives one that does not no noise by default, and refuses to ask it for any."""

    split: str = "val"
    scenes_dir: str | None = None
    width: int = 160
    height: int = 120
    max_steps: int = 500
    actuation_noise: float = 0.0
    odometry_noise: float = 0.0
    noise: str | None = None


class EnvSuite(Protocol):
    """The scenes ``0 .. len - 1`` of an environment."""

    name: str  # names the scene set in config.json (a split, a directory)

    def __len__(self) -> int: ...

    def episode_count(self, k: int, n: int | None = None) -> int:
        """Episodes of scene ``k`` a run uses: the first ``n`` (None: the default)."""
        ...

    def make(self, k: int, n: int | None = None) -> NavEnv:
        """Scene ``k`` with its first ``n`` episodes (indices ``0 .. n - 1`` at ``reset``)."""
        ...


#: Environments by name, ``factory(options: EnvOptions) -> EnvSuite``: kgnav's own simulator
#: (a plug-in module, so code that never asks for it does not import it) and the installed
#: packages' ``kgnav.envs`` entry points.
REGISTRY: Registry[Callable[[EnvOptions], EnvSuite]] = Registry(
    "environment", plugins=("kgnav.envs.kgnav_sim",), entry_point_group="kgnav.envs")
ENVS = REGISTRY.factories
register_env = REGISTRY.register

DEFAULT_ENV = "kgnav"


def env_names() -> list[str]:
    """Every registered environment name, the plugins' and entry points' included."""
    return REGISTRY.names()


def find_env(name: str) -> Callable[[EnvOptions], EnvSuite]:
    """The factory of environment ``name`` (see the module doc), or a one-line error."""
    if name not in ENVS and ":" in name:
        module, _, attr = name.partition(":")
        try:
            factory = getattr(importlib.import_module(module), attr)
        except (ImportError, AttributeError) as e:
            raise KgnavError(f"environment {name!r} cannot be imported: "
                             f"{type(e).__name__}: {e}") from None
        if not callable(factory):
            raise KgnavError(f"environment {name!r} is not a factory (callable)")
        ENVS[name] = factory
    return REGISTRY.get(name)


def env_weights(name: str) -> dict[str, Path]:
    """The learned weights environment ``name`` names as its own, by network (``segmenter``,
    ``encoder``): its factory's ``default_weights`` mapping, file names relative to kgnav's
    shipped weights (``kgnav/weights/``) or absolute paths. A run on that environment uses them
    unless given others; an environment that names none gets kgnav's shipped weights."""
    from kgnav.nets.weights import SHIPPED

    named = getattr(find_env(name), "default_weights", None) or {}
    return {net: Path(f) if Path(f).is_absolute() else SHIPPED / f for net, f in named.items()}


def env_applies_noise(name: str) -> bool:
    """Whether environment ``name`` applies the noise :class:`EnvOptions` asks for (its
    factory's ``applies_noise``; kgnav's simulator and MiniWorld do). A run must not record a
    noise an environment silently ignored."""
    return bool(getattr(find_env(name), "applies_noise", False))


def make_env(name: str = DEFAULT_ENV, options: EnvOptions | None = None) -> EnvSuite:
    """The scenes of environment ``name`` for ``options`` (default :class:`EnvOptions`)."""
    return find_env(name)(options or EnvOptions())
