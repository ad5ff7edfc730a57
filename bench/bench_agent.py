"""Speed of the whole agent loop on one CPU core, and where the time goes per stage.

    .venv/bin/python bench/bench_agent.py               # 160x120, a few val episodes
    .venv/bin/python bench/bench_agent.py --episodes 2  # quicker
    .venv/bin/python bench/bench_agent.py --split val-small

Stages: simulator (render + step), segmenter, state features, state creator, map update, model
update (add state + transition, relocation), reasoning (goal query, global policy, FMM planner).
With ``--memory-episodes``, the checks before merging at each episode's end (whole-episode
verification, objects, late match) are timed apart: once per episode, not per step; with
``--noise`` (e.g. ``locobot``) the episodes drift and the drift correction inside those checks
(loop closures and the GTSAM pose graph, docs/drift.md) is timed on its own too.
Target: at least 100 steps/s at 160x120 for the memory-less agent. ``--segmenter`` picks the
segmenter (default: the learned network, the benchmark's default).

Stages are timed in CPU time of this (single) thread, so other work on a shared machine does
not inflate them; the wall-clock rate is printed beside it. On an idle machine the two agree.
"""

from __future__ import annotations

import argparse
import time
from collections import defaultdict

import _one_core  # noqa: F401  (must come before numpy)
from _table import print_table

from kgnav.agent.camera import Camera
from kgnav.agent.features import loop_threshold, make_extractor
from kgnav.agent.loop import AgentConfig, ObjectNavAgent
from kgnav.agent.memory import Memory
from kgnav.agent.relocation import RelocationConfig
from kgnav.agent.segmentation import make_segmenter
from kgnav.errors import KgnavError
from kgnav.memory.merge import merge
from kgnav.memory.posegraph import DriftModel
from kgnav.sim import ObjectNavEnv
from kgnav.sim.noise import parse_noise

TIMES: dict[str, float] = defaultdict(float)
MERGE_CHECKS: list[float] = []  # CPU seconds of Relocalizer.mergeable per episode (not a step)
CLOSE_LOOPS: list[float] = []  # ... of which the drift correction (Relocalizer.close_loops)
SEARCHES: list[float] = []  # CPU s of each scan search (RelocationConfig.scan_search), in-loop


def timed(name: str, fn):
    def wrapper(*a, **kw):
        t = time.thread_time()
        try:
            return fn(*a, **kw)
        finally:
            TIMES[name] += time.thread_time() - t

    return wrapper


class _Timed:
    """Times calls of a callable object while passing every attribute through."""

    def __init__(self, name, obj):
        self._name, self._obj = name, obj

    def __call__(self, *a, **kw):
        return timed(self._name, self._obj)(*a, **kw)

    def __getattr__(self, attr):
        return getattr(self._obj, attr)


def _config(noise: str, relocation: dict | None = None) -> AgentConfig:
    """The agent's settings: with a drifting pose sensor, episodes are bent onto the memory
    before merging (as ``kgnav eval`` does); ``relocation``: RelocationConfig settings."""
    drift = DriftModel() if parse_noise(noise).odometry.active else None
    return AgentConfig(relocation=RelocationConfig(drift=drift, **(relocation or {})))


def _memory_of(env, extractor: str, segmenter: str, episodes: int,
               noise: str = "none", relocation: dict | None = None) -> Memory:
    """A memory of the house: the models of its first episodes, merged where they relocate
    (as Soft Incremental builds it), built outside the timing."""
    models: dict = {}
    ext = make_extractor(extractor)
    for e in range(episodes):
        agent = ObjectNavAgent(Camera.from_env(env), make_segmenter(segmenter), ext,
                               memory=Memory(models, threshold=loop_threshold(ext))
                               if models else None, config=_config(noise, relocation))
        obs, _ = env.reset(seed=100 + e, options={"episode": e})
        agent.reset(env.goal_class, seed=100 + e, scene=env.scene.name, episode=e,
                    model_id=f"m{e}")
        done = False
        while not done:
            obs, _r, term, trunc, _i = env.step(agent.act(obs))
            done = term or trunc
        r = agent.mergeable()
        if r is not None:
            models[r.model_id] = merge(models[r.model_id], agent.model_, transform=r.transform)
        else:
            models[agent.model_.model_id] = agent.model_
    return Memory(models, threshold=loop_threshold(ext))


def run(extractor: str, width: int, height: int, scenes: int, episodes: int, split: str,
        segmenter: str = "learned", memory_episodes: int = 0, noise: str = "none",
        relocation: dict | None = None) -> tuple:
    TIMES.clear()
    MERGE_CHECKS.clear()
    CLOSE_LOOPS.clear()
    SEARCHES.clear()
    steps = 0
    memories = {}
    for s in range(scenes):  # generate (and cache) the houses, build memories, untimed
        env = ObjectNavEnv(split, s, width, height, noise=noise)
        if memory_episodes:
            memories[s] = _memory_of(env, extractor, segmenter, memory_episodes, noise,
                                     relocation)
    t0, c0 = time.perf_counter(), time.thread_time()
    for s in range(scenes):
        env = ObjectNavEnv(split, s, width, height, noise=noise)
        env.step = timed("simulator", env.step)
        agent = ObjectNavAgent(Camera.from_env(env), make_segmenter(segmenter),
                               make_extractor(extractor), memory=memories.get(s),
                               config=_config(noise, relocation))
        if agent.relocalizer is not None:
            close = agent.relocalizer.close_loops

            def close_loops(*a, _close=close, **kw):
                c = time.thread_time()
                try:
                    return _close(*a, **kw)
                finally:
                    CLOSE_LOOPS.append(time.thread_time() - c)
            agent.relocalizer.close_loops = close_loops
            search = agent.relocalizer._search

            def searched(step, _search=search, _rel=agent.relocalizer):
                n, c = _rel.decisions["scan search"], time.thread_time()
                _search(step)
                if _rel.decisions["scan search"] > n:  # a search ran (not only its check)
                    SEARCHES.append(time.thread_time() - c)
            agent.relocalizer._search = searched
        agent.segmenter = _Timed("segmenter", agent.segmenter)
        agent.extractor = _Timed("state features", agent.extractor)
        agent.state_creator = _Timed("state creator", agent.state_creator)
        agent.map_builder.update = timed("map update", agent.map_builder.update)
        agent.reason = timed("reasoning + planning", agent.reason)
        for e in range(memory_episodes, memory_episodes + episodes):
            obs, _ = env.reset(seed=e, options={"episode": e})
            agent.reset(env.goal_class, seed=e, scene=env.scene.name, episode=e)
            done = False
            while not done:
                obs, _r, term, trunc, _i = env.step(agent.act(obs))
                done = term or trunc
                steps += 1
            if agent.memory is not None:  # the checks before merging, once per episode
                c = time.thread_time()
                agent.mergeable()
                MERGE_CHECKS.append(time.thread_time() - c)
    wall = time.perf_counter() - t0
    total = time.thread_time() - c0 - sum(MERGE_CHECKS)
    # model update = model_knowledge minus the map update inside it
    rows = []
    accounted = sum(TIMES.values())
    for name, t in sorted(TIMES.items(), key=lambda kv: -kv[1]):
        rows.append([name, 1000 * t / steps, 100 * t / total])
    rows.append(["model update + glue", 1000 * (total - accounted) / steps,
                 100 * (total - accounted) / total])
    rows.append(["total", 1000 * total / steps, 100.0])
    return rows, steps / total, steps / wall, steps


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=int, default=3)
    ap.add_argument("--episodes", type=int, default=3, help="per scene")
    ap.add_argument("--width", type=int, default=160)
    ap.add_argument("--height", type=int, default=120)
    ap.add_argument("--split", default="val")
    ap.add_argument("--extractors", default="opencv-gist,kgnav-encoder")
    ap.add_argument("--segmenter", default="learned", help="learned, or a noise preset")
    ap.add_argument("--noise", default="none",
                    help="motion and pose-sensor noise (kgnav eval --noise), e.g. locobot")
    ap.add_argument("--memory-episodes", type=int, default=0,
                    help="with memory: the house's first N episodes build it (untimed), the "
                         "next --episodes are timed with it (Soft Incremental)")
    ap.add_argument("--relocation", action="append", default=[], metavar="KEY=VALUE",
                    help="a RelocationConfig setting, e.g. scan_search=10 (repeatable; "
                         "integers and floats only)")
    args = ap.parse_args()
    relocation = {}
    for kv in args.relocation:
        key, _, value = kv.partition("=")
        if not value:
            ap.error(f"--relocation takes KEY=VALUE, got {kv!r}")
        relocation[key] = float(value) if "." in value else int(value)
    summary = []
    memory = f", memory of {args.memory_episodes} episodes" if args.memory_episodes else ""
    for name in args.extractors.split(","):
        try:
            make_extractor(name)
        except KgnavError:
            continue
        rows, rate, wall_rate, steps = run(name, args.width, args.height, args.scenes,
                                           args.episodes, args.split, args.segmenter,
                                           args.memory_episodes, args.noise, relocation)
        print_table(f"agent loop, {name}, {args.segmenter} segmenter, {args.split}{memory}, "
                    f"{args.width}x{args.height}, {steps} steps ({rate:.0f} steps/s CPU)",
                    ["stage", "ms/step", "% of time"], rows)
        merge_ms = "–"
        if MERGE_CHECKS:
            mean = sum(MERGE_CHECKS) / len(MERGE_CHECKS)
            merge_ms = f"{1000 * max(MERGE_CHECKS):.0f} / {1000 * mean:.0f}"
        close_ms = "–"
        if CLOSE_LOOPS:
            close_ms = (f"{1000 * max(CLOSE_LOOPS):.0f} / "
                        f"{1000 * sum(CLOSE_LOOPS) / len(CLOSE_LOOPS):.0f}")
        search_ms = "–"
        if SEARCHES:
            search_ms = f"{len(SEARCHES)}: {1000 * sum(SEARCHES) / len(SEARCHES):.0f}"
        summary.append([name, args.segmenter, args.split, args.noise, args.memory_episodes,
                        f"{args.width}x{args.height}", steps, rate, wall_rate, merge_ms,
                        close_ms, search_ms])
    print_table("whole loop (target >= 100 steps/s at 160x120)",
                ["features", "segmenter", "split", "noise", "memory eps", "resolution", "steps",
                 "steps/s (CPU)", "steps/s (wall)", "merge check ms (max / mean)",
                 "drift correction ms (max / mean)", "scan searches: ms each"], summary)


if __name__ == "__main__":
    main()
