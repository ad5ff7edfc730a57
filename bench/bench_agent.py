"""Speed of the whole agent loop on one CPU core, and where the time goes per stage.

    .venv/bin/python bench/bench_agent.py               # 160x120, a few val episodes
    .venv/bin/python bench/bench_agent.py --episodes 2  # quicker

Stages: simulator (render + step), segmenter, state features, state creator, map update, model
update (add state + transition, relocation), reasoning (goal query, global policy, FMM planner).
Target: at least 100 steps/s at 160x120 for the memory-less agent. ``--segmenter`` picks the
segmenter (default: the learned network, the benchmark's default).
"""

from __future__ import annotations

import argparse
import time
from collections import defaultdict

import _one_core  # noqa: F401  (must come before numpy)
from _table import print_table

from kgnav.agent.camera import Camera
from kgnav.agent.features import make_extractor
from kgnav.agent.loop import ObjectNavAgent
from kgnav.agent.segmenter import make_segmenter
from kgnav.errors import KgnavError
from kgnav.sim import ObjectNavEnv

TIMES: dict[str, float] = defaultdict(float)


def timed(name: str, fn):
    def wrapper(*a, **kw):
        t = time.perf_counter()
        try:
            return fn(*a, **kw)
        finally:
            TIMES[name] += time.perf_counter() - t

    return wrapper


class _Timed:
    """Times calls of a callable object while passing every attribute through."""

    def __init__(self, name, obj):
        self._name, self._obj = name, obj

    def __call__(self, *a, **kw):
        return timed(self._name, self._obj)(*a, **kw)

    def __getattr__(self, attr):
        return getattr(self._obj, attr)


def run(extractor: str, width: int, height: int, scenes: int, episodes: int,
        segmenter: str = "learned") -> list:
    TIMES.clear()
    steps = 0
    t0 = time.perf_counter()
    for s in range(scenes):
        env = ObjectNavEnv("val", s, width, height)
        env.step = timed("simulator", env.step)
        agent = ObjectNavAgent(Camera.from_env(env), make_segmenter(segmenter),
                               make_extractor(extractor))
        agent.segmenter = _Timed("segmenter", agent.segmenter)
        agent.extractor = _Timed("state features", agent.extractor)
        agent.state_creator = _Timed("state creator", agent.state_creator)
        agent.map_builder.update = timed("map update", agent.map_builder.update)
        agent.reason = timed("reasoning + planning", agent.reason)
        for e in range(episodes):
            obs, _ = env.reset(seed=e, options={"episode": e})
            agent.reset(env.goal_class, seed=e, scene=env.scene.name, episode=e)
            done = False
            while not done:
                obs, _r, term, trunc, _i = env.step(agent.act(obs))
                done = term or trunc
                steps += 1
    total = time.perf_counter() - t0
    # model update = model_knowledge minus the map update inside it
    rows = []
    accounted = sum(TIMES.values())
    for name, t in sorted(TIMES.items(), key=lambda kv: -kv[1]):
        rows.append([name, 1000 * t / steps, 100 * t / total])
    rows.append(["model update + glue", 1000 * (total - accounted) / steps,
                 100 * (total - accounted) / total])
    rows.append(["total", 1000 * total / steps, 100.0])
    return rows, steps / total, steps


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=int, default=3)
    ap.add_argument("--episodes", type=int, default=3, help="per scene")
    ap.add_argument("--width", type=int, default=160)
    ap.add_argument("--height", type=int, default=120)
    ap.add_argument("--segmenter", default="learned", help="learned, or a noise preset")
    args = ap.parse_args()
    summary = []
    for name in ("opencv-gist", "kgnav-encoder"):
        try:
            make_extractor(name)
        except KgnavError:
            continue
        rows, rate, steps = run(name, args.width, args.height, args.scenes, args.episodes,
                                args.segmenter)
        print_table(f"agent loop, {name}, {args.segmenter} segmenter, {args.width}x{args.height}, "
                    f"{steps} steps "
                    f"({rate:.0f} steps/s)", ["stage", "ms/step", "% of time"], rows)
        summary.append([name, f"{args.width}x{args.height}", steps, rate])
    print_table("whole loop (target >= 100 steps/s at 160x120)",
                ["features", "resolution", "steps", "steps/s"], summary)


if __name__ == "__main__":
    main()
