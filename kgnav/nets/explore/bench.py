"""Measuring exploration policies: explored area after 100 / 250 / 500 actions, and paired
comparisons of two ``kgnav eval`` runs that differ only in the global policy.

:func:`coverage_bench` plays every policy from the same starts (the first episodes of each house
of a split) in the :class:`~kgnav.nets.explore.mapenv.MapExploreEnv` and records the explored area
at the marks and the time of each ``select`` call. ``oracle`` is a greedy look-ahead on the ground
truth (:class:`GreedyOracle`): at every decision it tries goals on the policy grid and takes
the one that reveals the most; it bounds what a goal choice every 25 actions can achieve.

>>> r = coverage_bench(["random-goal"], split="val", houses=1, episodes=1, max_steps=60,
...                    marks=(30, 60))
>>> sorted(r["policies"]["random-goal"]["explored"])
['30', '60']
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import numpy as np

from kgnav.agent.planner import FMMPlanner
from kgnav.agent.policy import make_policy
from kgnav.benchmark.stats import paired_bootstrap
from kgnav.nets.explore.mapenv import MapExploreEnv
from kgnav.nets.explore.net import ExploreArch

MARKS = (100, 250, 500)


class GreedyOracle:
    """Coverage upper reference: at each decision, the goal of a ``stride``-subsampled policy
    grid whose decision would reveal the most (simulated on the ground truth by
    :meth:`MapExploreEnv.preview`)."""

    name = "oracle"

    def __init__(self, env: MapExploreEnv, arch: ExploreArch | None = None, stride: int = 2):
        self.env = env
        self.arch = arch or ExploreArch()
        self.stride = int(stride)

    def reset(self, seed: int) -> None:
        pass

    def select(self, m, pose, goal_class, planner):
        agent = m.to_cell(pose[0], pose[1])
        g = self.arch.grid
        best, best_gain, seen = None, -1.0, set()
        for a in range(g):
            for b in range(g):
                if a % self.stride or b % self.stride:
                    continue
                di, dj = self.arch.goal_offset(a * g + b)
                cell = (agent[0] + di, agent[1] + dj)
                snapped = self.env._snap(cell)
                if snapped in seen:
                    continue
                seen.add(snapped)
                gain = self.env.preview(cell)
                if gain > best_gain:
                    best, best_gain = cell, gain
        return best


def coverage_bench(policies: list[str], *, split: str = "val", houses: int | None = None,
                   episodes: int = 2, oracle_episodes: int | None = None, seed: int = 1,
                   max_steps: int = 500, marks: tuple[int, ...] = MARKS,
                   progress: Callable[[str], None] | None = None) -> dict:
    """Explored area (m²) at ``marks`` per policy name (``oracle`` for :class:`GreedyOracle`),
    from the starts of the first ``episodes`` episodes of the first ``houses`` houses of
    ``split`` (``oracle_episodes``: fewer for the slow oracle). Returns per policy the mean
    area per mark, the per-episode values (keyed ``house/episode``) and select-call times."""
    from kgnav.sim.episodes import SPLITS, episodes_for, load_scene_of

    n_houses = len(SPLITS[split]) if houses is None else min(houses, len(SPLITS[split]))
    scenes = [load_scene_of(split, k) for k in range(n_houses)]
    env = MapExploreEnv(scenes, max_steps=max_steps, marks=marks)
    out: dict = {"split": split, "houses": n_houses, "episodes_per_house": episodes,
                 "seed": seed, "max_steps": max_steps, "marks": list(marks), "policies": {}}
    for name in policies:
        per_house = episodes if name != "oracle" or oracle_episodes is None else oracle_episodes
        policy = GreedyOracle(env) if name == "oracle" else make_policy(name)
        planner = FMMPlanner()
        values: dict[str, dict[str, float]] = {}
        times: list[float] = []
        for k in range(n_houses):
            for e, ep in enumerate(episodes_for(split, k, per_house)):
                m = env.reset(k, ep.start)
                policy.reset(int(np.random.SeedSequence([seed, k, e]).generate_state(1)[0]))
                planner.reset()
                while not env.done:
                    t0 = time.perf_counter()
                    cell = policy.select(m, env.pose, None, planner)
                    times.append(time.perf_counter() - t0)
                    env.step(cell if cell is not None else m.to_cell(*env.pose[:2]))
                values[f"{k}/{e}"] = {str(t): env.coverage.get(t, env.explored_m2)
                                      for t in marks}
                if progress is not None:
                    progress(name)
        ms = np.array(times) * 1000
        out["policies"][name] = {
            "episodes": len(values),
            "explored": {str(t): float(np.mean([v[str(t)] for v in values.values()]))
                         for t in marks},
            "per_episode": values,
            "ms_per_decision": {"median": float(np.median(ms)), "p90": float(np.quantile(ms, 0.9)),
                                "calls": len(ms)},
        }
    return out


def paired(a: dict[str, float], b: dict[str, float], seed: int = 0) -> dict:
    """Mean of ``a[k] - b[k]`` over the keys both hold, with a 95 % paired bootstrap interval."""
    keys = sorted(a.keys() & b.keys())
    d = [float(a[k]) - float(b[k]) for k in keys]
    lo, hi = paired_bootstrap(d, seed=seed)
    return {"diff": float(np.mean(d)) if d else math.nan, "low": lo, "high": hi,
            "pairs": len(keys)}


def compare_runs(base: list[dict], other: list[dict], metrics=("success", "spl", "softspl"),
                 seed: int = 0) -> dict:
    """Per variant present in both ``episodes.jsonl`` record lists: each run's mean of
    ``metrics`` and the paired difference ``other - base`` over the same (house, episode)."""
    def by(records):
        out: dict = {}
        for r in records:
            out.setdefault(r["variant"], {})[(r["scene"], r["episode"])] = r
        return out

    a, b = by(base), by(other)
    res = {}
    for v in [v for v in a if v in b]:
        row = {}
        for m in metrics:
            xa = {f"{k[0]}/{k[1]}": float(r[m]) for k, r in a[v].items()}
            xb = {f"{k[0]}/{k[1]}": float(r[m]) for k, r in b[v].items()}
            row[m] = {"base": float(np.mean(list(xa.values()))),
                      "other": float(np.mean(list(xb.values()))),
                      **paired(xb, xa, seed)}
        res[v] = row
    return res
