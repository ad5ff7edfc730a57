"""Where a benchmark run's houses and episodes come from: a built-in split or a directory.

>>> src = scene_source("val-small")
>>> len(src), src.name, src.default_episodes
(11, 'val-small', 20)
"""

from __future__ import annotations

import os
from typing import Protocol

from kgnav.errors import KgnavError
from kgnav.sim.episodes import (
    DEFAULT_EPISODES_PER_SCENE,
    SPLITS,
    Episode,
    episodes_for,
    load_scene_of,
)
from kgnav.sim.house import Scene
from kgnav.sim.scene_dir import SceneDir


class SceneSource(Protocol):
    """Houses ``0 .. len - 1`` and their episodes."""

    name: str
    default_episodes: int | None  # per house when none is asked for (None: all there are)

    def __len__(self) -> int: ...

    def scene(self, k: int) -> Scene: ...

    def episodes(self, k: int, n: int | None = None) -> list[Episode]: ...


class BuiltinSplit:
    """A split of :data:`kgnav.sim.episodes.SPLITS`, generated and cached on first use."""

    def __init__(self, split: str):
        if split not in SPLITS:
            raise KgnavError(f"unknown split {split!r} (known: {', '.join(SPLITS)})")
        self.name = split
        self.default_episodes = DEFAULT_EPISODES_PER_SCENE[split]

    def __len__(self) -> int:
        return len(SPLITS[self.name])

    def scene(self, k: int) -> Scene:
        return load_scene_of(self.name, k)

    def episodes(self, k: int, n: int | None = None) -> list[Episode]:
        return episodes_for(self.name, k, n)


class DirectorySplit(SceneDir):
    """A split directory (see :mod:`kgnav.sim.scene_dir`) as a scene source."""

    default_episodes = None

    def __init__(self, path: str | os.PathLike[str]):
        super().__init__(path)
        self.name = str(path)


def scene_source(split: str = "val", scenes_dir: str | os.PathLike[str] | None = None
                 ) -> SceneSource:
    """``scenes_dir`` when given (a directory written by ``kgnav scenes generate``), else the
    built-in ``split``."""
    return DirectorySplit(scenes_dir) if scenes_dir is not None else BuiltinSplit(split)
