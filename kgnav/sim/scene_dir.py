"""A split of your own: a directory of scene files and their episode files.

Layout: ``DIR/<name>.scene.json`` (format ``kgnav-scene``) and ``DIR/<name>.episodes.json``
(format ``kgnav-episodes``) per house; houses are taken in name order. :func:`generate_split`
writes one (``kgnav scenes generate``), :func:`validate_split` checks one without changing it
(``kgnav scenes validate``), and ``kgnav eval --scenes-dir DIR`` runs the benchmark on it.

>>> import tempfile
>>> d = tempfile.mkdtemp()
>>> names = generate_split(d, count=1, seed=9000, rooms=(8, 8), episodes=3)
>>> SceneDir(d).names, len(SceneDir(d).episodes(0))
(['h9000'], 3)
>>> validate_split(d)
[]
"""

from __future__ import annotations

import math
import os
from pathlib import Path

from kgnav.errors import SceneFileError
from kgnav.sim.episodes import (
    Episode,
    generate_episodes,
    generate_scene,
    load_episodes,
    save_episodes,
)
from kgnav.sim.house import GENERATOR, Scene
from kgnav.sim.house_v2 import GENERATOR_V2, MAX_ROOMS, MIN_ROOMS
from kgnav.sim.navmesh import NavMap
from kgnav.sim.scene_io import load_scene, save_scene

SCENE_SUFFIX = ".scene.json"
EPISODES_SUFFIX = ".episodes.json"


class SceneDir:
    """The houses and episodes of a split directory (see the module docstring).

    :class:`SceneFileError` when the directory is missing or holds no scene, and when a scene
    or its episode file is missing or invalid (on first access).
    """

    def __init__(self, path: str | os.PathLike[str]):
        self.path = Path(path)
        if not self.path.is_dir():
            raise SceneFileError(self.path, "not a directory")
        self.names = sorted(p.name[: -len(SCENE_SUFFIX)]
                            for p in self.path.glob(f"*{SCENE_SUFFIX}") if p.is_file())
        if not self.names:
            raise SceneFileError(self.path, f"no scene files (*{SCENE_SUFFIX})")
        self._scenes: dict[int, Scene] = {}

    def __len__(self) -> int:
        return len(self.names)

    def scene_path(self, k: int) -> Path:
        return self.path / f"{self.names[k]}{SCENE_SUFFIX}"

    def episodes_path(self, k: int) -> Path:
        return self.path / f"{self.names[k]}{EPISODES_SUFFIX}"

    def scene(self, k: int) -> Scene:
        if k not in self._scenes:
            s = load_scene(self.scene_path(k))
            if s.name != self.names[k]:
                raise SceneFileError(self.scene_path(k),
                                     f"holds scene {s.name!r}, not {self.names[k]!r}")
            self._scenes[k] = s
        return self._scenes[k]

    def scenes(self, n: int | None = None) -> list[Scene]:
        """The first ``n`` houses (all by default); :class:`SceneFileError` when it holds
        fewer."""
        if n is None:
            n = len(self)
        if n > len(self):
            raise SceneFileError(self.path, f"holds {len(self)} houses, not the {n} asked for")
        return [self.scene(k) for k in range(n)]

    def episodes(self, k: int, n: int | None = None) -> list[Episode]:
        """The first ``n`` episodes of house ``k`` (all by default)."""
        path = self.episodes_path(k)
        if not path.is_file():
            raise SceneFileError(path, "missing: every scene needs its episode file")
        eps = load_episodes(path)
        if n is not None:
            if n > len(eps):
                raise SceneFileError(path, f"holds {len(eps)} episodes, {n} asked for")
            eps = eps[:n]
        return eps


def generate_split(path: str | os.PathLike[str], count: int, seed: int,
                   rooms: tuple[int, int] = (MIN_ROOMS, MAX_ROOMS), max_side: float = 40.0,
                   episodes: int = 100, generator: str = GENERATOR_V2,
                   progress=None) -> list[str]:
    """Write ``count`` houses (seeds ``seed``, ``seed + 1``, ...) with ``episodes`` episodes
    each into directory ``path`` (created); returns their names. ``rooms`` bounds the room
    count (``house-v2``: within 8..30, drawn per house from its seed)."""
    import numpy as np

    check_split_args(count, rooms, episodes, generator)
    lo, hi = rooms
    out = Path(path)
    out.mkdir(parents=True, exist_ok=True)
    names = []
    for s in range(seed, seed + count):
        n_rooms = int(np.random.default_rng([s, 7]).integers(lo, hi + 1))
        kw = {"max_side": max_side} if generator == GENERATOR_V2 else {}
        scene = generate_scene(generator, s, f"h{s}", n_rooms=n_rooms, **kw)
        save_scene(scene, out / f"{scene.name}{SCENE_SUFFIX}")
        eps = generate_episodes(scene, episodes)
        save_episodes(eps, out / f"{scene.name}{EPISODES_SUFFIX}", "", scene.name, generator)
        names.append(scene.name)
        if progress is not None:
            progress(scene.name)
    return names


def check_split_args(count: int, rooms: tuple[int, int], episodes: int, generator: str) -> None:
    """ValueError naming the first argument of :func:`generate_split` that cannot work."""
    lo, hi = rooms
    if generator == GENERATOR_V2 and not MIN_ROOMS <= lo <= hi <= MAX_ROOMS:
        raise ValueError(f"rooms must be A..B within {MIN_ROOMS}..{MAX_ROOMS}, got {lo}..{hi}")
    if generator == GENERATOR and not 4 <= lo <= hi <= 12:
        raise ValueError(f"rooms must be A..B within 4..12 for {GENERATOR}, got {lo}..{hi}")
    if generator not in (GENERATOR, GENERATOR_V2):
        raise ValueError(f"unknown generator {generator!r}")
    if count < 1 or episodes < 1:
        raise ValueError("count and episodes must be at least 1")


def validate_split(path: str | os.PathLike[str]) -> list[str]:
    """Every problem of a split directory, one line each (empty: it can be run). Checks that
    each scene loads, has an episode file for it, and that every episode starts on navigable
    floor with a reachable goal class at the recorded geodesic distance (within 5 %)."""
    try:
        sd = SceneDir(path)
    except SceneFileError as e:
        return [str(e)]
    problems = []
    for k, name in enumerate(sd.names):
        try:
            scene, eps = sd.scene(k), sd.episodes(k)
        except SceneFileError as e:
            problems.append(str(e))
            continue
        nav = NavMap.from_scene(scene)
        where = sd.episodes_path(k)
        for e in eps:
            if e.scene != name:
                problems.append(f"{where}: episode {e.episode_id} is of scene {e.scene!r}")
                continue
            x, y, _t = e.start
            if not nav.is_navigable(x, y):
                problems.append(f"{where}: episode {e.episode_id} starts off the navigable floor")
                continue
            if not scene.objects_of(e.goal_class):
                problems.append(f"{where}: episode {e.episode_id}: no {e.goal_class} in the house")
                continue
            d = nav.geodesic_distance(x, y, e.goal_class)
            if not math.isfinite(d):
                problems.append(f"{where}: episode {e.episode_id}: goal unreachable")
            elif abs(d - e.geodesic_distance) > 0.05 * max(d, 1.0):
                problems.append(f"{where}: episode {e.episode_id}: geodesic distance "
                                f"{e.geodesic_distance} recorded, {d:.3f} measured")
    return problems
