"""Splits (fixed scene seeds) and deterministic ObjectNav episodes, cached as files.

* ``train``: 20 Matterport3D-scale houses (generator ``house-v2``, seeds 3000..3019); ``val``:
  11 (seeds 4000..4010; the paper's validation set has 11 environments). ``train-small`` and
  ``val-small`` are the first generator's houses (``house-v1``, seeds 1000..1019 and
  2000..2010), kept for quick runs and continuity with earlier results. Scene ``k`` of a split
  is named ``{split}_{k:02d}``.
* Scenes and episode sets are generated on first use and cached under ``$KGNAV_CACHE`` (default
  ``~/.cache/kgnav``) in ``sim/v1/``; a cached file that is unreadable or from another generator
  version is regenerated. Generation is deterministic, so the cache only saves time.
* An episode: start pose on navigable floor, a goal class (one of the six ObjectNav classes
  present in the house) with a reachable instance, geodesic start-to-goal distance in
  [1, 30] m, not already inside the success region. At most 500 actions. In ``house-v2`` houses
  the distance follows a Matterport3D-like spread (:data:`MP3D_DISTANCE`: log-normal, median
  8 m, mean about 9 m, clipped to [1, 30] m) as far as the house allows; ``house-v1`` episodes
  draw start cells uniformly, as before.

>>> from kgnav.sim.episodes import SPLITS
>>> len(SPLITS["val"])
11
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from kgnav.common.classes import OBJECTNAV_CLASSES, class_id
from kgnav.errors import SceneFileError
from kgnav.sim.house import GENERATOR, Scene, generate_house
from kgnav.sim.house_v2 import GENERATOR_V2, generate_large_house
from kgnav.sim.navmesh import NavMap
from kgnav.sim.scene_io import (
    atomic_write_text,
    check_header,
    load_scene,
    read_json,
    save_scene,
)

SPLITS: dict[str, tuple[int, ...]] = {
    "train": tuple(range(3000, 3020)),
    "val": tuple(range(4000, 4011)),
    "train-small": tuple(range(1000, 1020)),
    "val-small": tuple(range(2000, 2011)),
}
#: The generator of each split's houses.
SPLIT_GENERATOR: dict[str, str] = {"train": GENERATOR_V2, "val": GENERATOR_V2,
                                   "train-small": GENERATOR, "val-small": GENERATOR}
EPISODES_FORMAT = "kgnav-episodes"
EPISODES_VERSION = 1
#: Episodes per scene when none is asked for. ``val``'s 100 x 11 houses make a paired
#: difference in success of 3 points significant when a quarter of the pairs disagree (see the
#: docs/benchmark.md, "Enough episodes").
DEFAULT_EPISODES_PER_SCENE = {"train": 50, "val": 100, "train-small": 50, "val-small": 20}
MAX_STEPS = 500
MIN_GEODESIC, MAX_GEODESIC = 1.0, 30.0
#: Start-to-goal geodesic distances of ``house-v2`` episodes: log-normal (median m, sigma).
MP3D_DISTANCE = (8.0, 0.55)


@dataclass(frozen=True)
class Episode:
    """One ObjectNav episode in a scene. ``start`` is the world pose (x, y, theta)."""

    episode_id: str
    scene: str
    start: tuple[float, float, float]
    goal_class: str
    geodesic_distance: float  # start -> success region of goal_class (m)
    euclidean_distance: float  # start -> closest goal footprint (m)
    max_steps: int = MAX_STEPS


def cache_dir() -> Path:
    """Root of the simulator cache: ``$KGNAV_CACHE/sim/v1`` (default ``~/.cache/kgnav``)."""
    root = os.environ.get("KGNAV_CACHE") or os.path.join(os.path.expanduser("~"), ".cache",
                                                          "kgnav")
    return Path(root) / "sim" / "v1"


def scene_name(split: str, index: int) -> str:
    return f"{split}_{index:02d}"


def _check_split(split: str, index: int | None = None) -> None:
    if split not in SPLITS:
        raise ValueError(f"unknown split {split!r} (known: {', '.join(SPLITS)})")
    if index is not None and not 0 <= index < len(SPLITS[split]):
        raise ValueError(f"split {split!r} has scenes 0..{len(SPLITS[split]) - 1}, got {index}")


def load_scene_of(split: str, index: int, cache: bool = True) -> Scene:
    """Scene ``index`` of ``split``: from the cache, else generated from its seed (and cached)."""
    _check_split(split, index)
    name = scene_name(split, index)
    seed = SPLITS[split][index]
    path = cache_dir() / "scenes" / f"{name}.json"
    if cache and path.exists():
        try:
            s = load_scene(path)
            if s.generator == SPLIT_GENERATOR[split] and s.seed == seed and s.name == name:
                return s
        except SceneFileError:
            pass  # stale or damaged cache entry: regenerate below
    s = generate_scene(SPLIT_GENERATOR[split], seed, name)
    if cache:
        try:
            save_scene(s, path)
        except OSError:
            pass  # a read-only cache must not stop the simulator
    return s


def generate_scene(generator: str, seed: int, name: str | None = None, **kw) -> Scene:
    """A house of the named generator (``house-v1`` or ``house-v2``) from ``seed``."""
    if generator == GENERATOR:
        return generate_house(seed, name=name, **kw)
    if generator == GENERATOR_V2:
        return generate_large_house(seed, name=name, **kw)
    raise ValueError(f"unknown house generator {generator!r} (known: {GENERATOR}, {GENERATOR_V2})")


def load_split(split: str, cache: bool = True) -> list[Scene]:
    """Every scene of ``split`` (see :data:`SPLITS`)."""
    _check_split(split)
    return [load_scene_of(split, i, cache) for i in range(len(SPLITS[split]))]


def generate_episodes(scene: Scene, n: int, seed: int = 0,
                      classes: tuple[str, ...] = OBJECTNAV_CLASSES,
                      min_geodesic: float = MIN_GEODESIC,
                      max_geodesic: float = MAX_GEODESIC,
                      spread: str | None = None) -> list[Episode]:
    """``n`` deterministic episodes in ``scene`` (same arguments, same episodes).

    ``spread``: how start-to-goal distances are drawn. ``"uniform"`` picks a (goal class, start
    cell) pair uniformly (the ``house-v1`` episodes); ``"mp3d"`` draws a target distance from
    :data:`MP3D_DISTANCE` and a start whose distance is within 10 % of it (another draw when
    the house has none). Default: ``"mp3d"`` for ``house-v2`` houses, else ``"uniform"``.
    """
    spread = spread or ("mp3d" if scene.generator == GENERATOR_V2 else "uniform")
    if spread not in ("uniform", "mp3d"):
        raise ValueError(f"unknown distance spread {spread!r} (known: uniform, mp3d)")
    nav = NavMap.from_scene(scene)
    rng = np.random.default_rng([seed, scene.seed])
    usable = []
    for c in classes:
        if scene.objects_of(c):
            f = nav.distance_field(c)
            ok = nav.grid & (f >= min_geodesic) & (f <= max_geodesic)
            if ok.any():
                cells = np.argwhere(ok)  # row-major: the uniform draw's order
                d = f[ok]
                order = np.argsort(d, kind="stable")
                usable.append((c, f, cells, cells[order], d[order]))
    if not usable:
        raise ValueError(f"scene {scene.name!r} has no reachable goal of classes {classes}")
    out: list[Episode] = []
    for k in range(n):
        if spread == "uniform":
            c, f, cells, _by_d, _d = usable[int(rng.integers(len(usable)))]
            i, j = cells[int(rng.integers(len(cells)))]
        else:
            c, f, i, j = _draw_far(rng, usable, min_geodesic, max_geodesic)
        x, y = nav.to_world(int(i), int(j))
        theta = float(rng.uniform(-math.pi, math.pi))
        out.append(Episode(
            episode_id=f"{scene.name}_ep{k:04d}",
            scene=scene.name,
            start=(round(x, 4), round(y, 4), round(theta, 6)),
            goal_class=c,
            geodesic_distance=round(float(f[i, j]), 4),
            euclidean_distance=round(nav.l2_to_class(x, y, c), 4),
        ))
    return out


def _draw_far(rng, usable, lo: float, hi: float):
    """One (class, field, row, col) whose distance is near a draw of :data:`MP3D_DISTANCE`."""
    median, sigma = MP3D_DISTANCE
    for _ in range(200):
        target = float(np.clip(rng.lognormal(math.log(median), sigma), lo, hi))
        tol = max(0.25, 0.1 * target)
        for q in rng.permutation(len(usable)):
            c, f, _cells, cells, d = usable[int(q)]
            a, b = np.searchsorted(d, [target - tol, target + tol])
            if b > a:
                i, j = cells[int(rng.integers(a, b))]
                return c, f, i, j
    c, f, cells, _by_d, _d = usable[int(rng.integers(len(usable)))]  # pragma: no cover
    i, j = cells[int(rng.integers(len(cells)))]
    return c, f, i, j


def episodes_to_dict(episodes: list[Episode], split: str = "", scene: str = "",
                     generator: str = GENERATOR) -> dict[str, Any]:
    return {
        "format": EPISODES_FORMAT,
        "version": EPISODES_VERSION,
        "generator": generator,
        "split": split,
        "scene": scene,
        "episodes": [asdict(e) for e in episodes],
    }


def save_episodes(episodes: list[Episode], path, split: str = "", scene: str = "",
                  generator: str = GENERATOR) -> None:
    """Save an episode list as a versioned JSON file (atomically); ``generator`` names the
    houses' generator (a cached file of another generator is regenerated)."""
    atomic_write_text(path, json.dumps(episodes_to_dict(episodes, split, scene, generator),
                                       indent=1))


def load_episodes(path) -> list[Episode]:
    """Load and validate an episode file; :class:`SceneFileError` if it cannot be used."""
    path = os.fspath(path)
    data = read_json(path)
    check_header(data, path, EPISODES_FORMAT, EPISODES_VERSION)
    try:
        eps = []
        for e in data["episodes"]:
            start = tuple(float(v) for v in e["start"])
            if len(start) != 3 or not all(math.isfinite(v) for v in start):
                raise ValueError(f"episode {e.get('episode_id')!r}: bad start {e['start']!r}")
            class_id(e["goal_class"])  # UnknownClassError is a ValueError: reported below
            eps.append(Episode(str(e["episode_id"]), str(e["scene"]), start, e["goal_class"],
                               float(e["geodesic_distance"]), float(e["euclidean_distance"]),
                               int(e.get("max_steps", MAX_STEPS))))
        return eps
    except (KeyError, TypeError, ValueError) as e:
        what = f"missing field {e}" if isinstance(e, KeyError) else str(e)
        raise SceneFileError(path, f"invalid episodes: {what}") from None


def episodes_for(split: str, scene: int, n: int | None = None, cache: bool = True,
                 seed: int = 0) -> list[Episode]:
    """The episode set of scene ``scene`` of ``split`` (default count per split:
    :data:`DEFAULT_EPISODES_PER_SCENE`), from the cache or generated deterministically."""
    _check_split(split, scene)
    n = DEFAULT_EPISODES_PER_SCENE[split] if n is None else int(n)
    name = scene_name(split, scene)
    path = cache_dir() / "episodes" / f"{name}_n{n}_s{seed}.json"
    if cache and path.exists():
        try:
            with open(path, encoding="utf-8") as f:
                gen = json.load(f).get("generator")
            if gen == SPLIT_GENERATOR[split]:
                return load_episodes(path)
        except (SceneFileError, OSError, ValueError, AttributeError):
            pass
    eps = generate_episodes(load_scene_of(split, scene, cache), n, seed=seed)
    if cache:
        try:
            save_episodes(eps, path, split, name, SPLIT_GENERATOR[split])
        except OSError:
            pass
    return eps
