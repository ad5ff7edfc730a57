"""Scaling of ``kgnav eval`` over its engines: throughput, Ray's overhead, data sent per round.

    .venv/bin/python bench/bench_engines.py                      # all three parts
    .venv/bin/python bench/bench_engines.py --part throughput    # the same run on each engine
    .venv/bin/python bench/bench_engines.py --part overhead      # Ray's cost per task
    .venv/bin/python bench/bench_engines.py --part memory        # si over 11 houses x 20 episodes

throughput: the same benchmark run (``--split val-small --scenes 3 --episodes 4 --variants
ans,si`` by default) with the local engine on 1 and 2 processes and Ray on 2 CPUs, each in a
fresh process (no engine inherits another's warm caches); episodes/s over the whole run
(Ray's start and stop included, and apart), and whether episodes.jsonl is the same bytes.

overhead: Ray's cost per task, from tasks that do nothing (with and without a memory-sized
context), against the local engine's fork per round.

memory: ``si`` over ``--memory-split`` (11 houses x 20 episodes), recording for every round what
an engine ships: the context (memory snapshot and co-occurrence) pickled as Ray pickles it
(protocol 5), the tasks, and the outcomes that come back (each episode's model), plus the time
the driver spends between rounds (index the memory, merge, save) and the round's straggler
factor (its longest episode over its mean, in steps).
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _table import print_table

from kgnav.benchmark.engines import LocalEngine, RayEngine
from kgnav.benchmark.runner import (
    EvalConfig,
    _worker_init,
    resolve_extractor,
    run_eval,
    run_variant,
)
from kgnav.benchmark.variants import VARIANTS

RUNS = [("local", 1), ("local", 2), ("ray", 2)]


def _config(args, engine="local", workers=1, **kw) -> EvalConfig:
    return EvalConfig(split=args.split, scenes=args.scenes, episodes=args.episodes,
                      variants=tuple(args.variants.split(",")), max_steps=args.max_steps,
                      segmenter=args.segmenter, engine=engine, workers=workers, **kw)


# ---------------------------------------------------------------------- throughput
def one_run(args) -> None:
    """In a fresh process: one engine's run; prints its timings as JSON."""
    engine, workers, out = args.one
    t0 = time.perf_counter()
    _records, summary = run_eval(_config(args, engine, int(workers)), out, progress=False)
    wall = time.perf_counter() - t0
    episodes = sum(s["episodes"] for s in summary.values())
    # CPU time of this process and the local engine's forked workers (not Ray's: not ours)
    cpu = sum(getattr(resource.getrusage(w), f) for w in (resource.RUSAGE_SELF,
              resource.RUSAGE_CHILDREN) for f in ("ru_utime", "ru_stime"))
    print(json.dumps({"wall": wall, "episodes": episodes, "cpu": cpu,
                      "variant_seconds": {k: s["seconds"] for k, s in summary.items()}}))


def throughput(args) -> None:
    rows, outs = [], []
    tmp = Path(tempfile.mkdtemp(prefix="kgbench"))
    for engine, workers in RUNS:
        out = tmp / f"{engine}{workers}"
        cmd = [sys.executable, __file__, "--one", engine, str(workers), str(out),
               *_run_args(args)]
        load = os.getloadavg()[0]
        res = json.loads(subprocess.run(cmd, check=True, capture_output=True,
                                        text=True).stdout.splitlines()[-1])
        busy = sum(res["variant_seconds"].values())  # the rounds, without engine start/stop
        cpu = round(res["cpu"] / res["episodes"], 2) if engine == "local" else "–"
        rows.append([f"{engine} x{workers}", res["episodes"], round(res["wall"], 1),
                     round(res["episodes"] / res["wall"], 3), round(res["episodes"] / busy, 3),
                     round(res["wall"] - busy, 1), cpu, f"{load:.1f}"])
        outs.append((out / "episodes.jsonl").read_bytes())
    same = all(o == outs[0] for o in outs)
    print_table(f"Throughput: {args.split}, {args.scenes} houses x {args.episodes} episodes, "
                f"{args.variants}, max {args.max_steps} steps, {args.segmenter} segmenter "
                f"(episodes.jsonl identical on all engines: {same})",
                ["engine", "episodes", "wall s", "ep/s", "ep/s in rounds",
                 "outside rounds s", "CPU s/ep", "load avg"], rows)
    per_ep = [(r[2] - r[5]) / r[1] for r in rows]
    print(f"Ray x2 over local x2, per episode (rounds only): {per_ep[2] - per_ep[1]:+.3f} s")


def _run_args(args) -> list[str]:
    return ["--split", args.split, "--scenes", str(args.scenes), "--episodes",
            str(args.episodes), "--variants", args.variants, "--max-steps", str(args.max_steps),
            "--segmenter", args.segmenter]


# ---------------------------------------------------------------------- overhead
def _nothing(context, task):
    return task


def overhead(args, context_bytes: int = 0) -> None:
    import numpy as np

    n, rows = args.tasks, []
    context = {"memory": np.zeros(max(context_bytes // 4, 1), np.float32)}
    size = f"{context_bytes / 1e6:.1f} MB array"
    if args.memory_store:  # a real memory (``--part memory --keep DIR`` writes one)
        from kgnav.agent.memory import Memory
        from kgnav.memory.store import ModelStore

        models, problems = ModelStore(Path(args.memory_store) / "memory" / "si").load_all()
        assert models and not problems, problems
        context = {"memory": Memory(models, threshold=0.1)}
        t = time.perf_counter()
        blob = pickle.dumps(context, protocol=5)
        rows.append([f"pickle a memory of {len(models)} models, "
                     f"{sum(m.n_states for m in models.values())} states "
                     f"({len(blob) / 1e6:.1f} MB)", round((time.perf_counter() - t) * 1000), ""])
        t = time.perf_counter()
        pickle.loads(blob)
        rows.append(["unpickle it", round((time.perf_counter() - t) * 1000), ""])
        size = f"{len(blob) / 1e6:.1f} MB memory"
    _worker_init()  # as run_eval does: torch imported, one thread (forks inherit both)
    with LocalEngine(2, _worker_init) as local:
        t = time.perf_counter()
        for _ in range(20):  # a round of 11 houses: one fork of 2 processes per round
            local.map(_nothing, range(11), context)
        rows.append([f"local x2: fork per round (11 tasks), {size}",
                     round((time.perf_counter() - t) / 20 * 1000, 1), "per round"])
    t = time.perf_counter()
    ray_engine = RayEngine(num_cpus=2, initializer=_worker_init)
    started = time.perf_counter() - t
    try:
        t = time.perf_counter()
        ray_engine.map(_nothing, range(4), None)
        rows.append(["ray: start", round(started * 1000), ""])
        rows.append(["ray: first round (workers start)", round((time.perf_counter() - t) * 1000),
                     ""])
        for ctx, label in ((None, "no context"), (context, size)):
            ray_engine.map(_nothing, range(4), ctx)  # warm, context shipped once
            t = time.perf_counter()
            ray_engine.map(_nothing, range(n), ctx)
            per = (time.perf_counter() - t) / n
            rows.append([f"ray: {n} tasks in one round, {label}", round(per * 1000, 2), "per task"])
            t = time.perf_counter()
            for _ in range(args.rounds):
                ray_engine.map(_nothing, range(11), dict(ctx) if ctx else {})  # new context
            rows.append([f"ray: a round of 11 tasks, {label} shipped anew",
                         round((time.perf_counter() - t) / args.rounds * 1000, 1), "per round"])
    finally:
        t = time.perf_counter()
        ray_engine.close()
        rows.append(["ray: stop", round((time.perf_counter() - t) * 1000), ""])
    print_table(f"Engine overhead (ms), 2 CPUs, load avg {os.getloadavg()[0]:.1f}",
                ["what", "ms", ""], rows)


# ---------------------------------------------------------------------- memory
class MeasuringEngine(LocalEngine):
    """The local engine, recording per round what another engine would ship."""

    def __init__(self):
        super().__init__(1)
        self.rounds: list[dict] = []
        self._last = None

    def map(self, fn, tasks, context=None, bar=None):
        since = time.perf_counter() - self._last if self._last else 0.0  # the driver's work
        tasks = list(tasks)
        t = time.perf_counter()
        blob = pickle.dumps(context, protocol=5)
        pickled = time.perf_counter() - t
        t = time.perf_counter()
        pickle.loads(blob)
        unpickled = time.perf_counter() - t
        t, cpu = time.perf_counter(), time.process_time()
        out = super().map(fn, tasks, context, bar)
        cpu = time.process_time() - cpu
        memory = (context or {}).get("memory")
        self.rounds.append({
            "episodes": len(tasks), "models": len(memory) if memory is not None else 0,
            "states": sum(m.n_states for m in memory.models.values()) if memory else 0,
            "context": len(blob), "pickle_s": pickled, "unpickle_s": unpickled,
            "tasks": sum(len(pickle.dumps(x, protocol=5)) for x in tasks),
            "outcomes": sum(len(pickle.dumps(o, protocol=5)) for o in out),
            "episodes_s": time.perf_counter() - t, "cpu_s": cpu, "between_s": since,
            "straggler": _straggler([o.record["steps"] for o in out])})
        self._last = time.perf_counter()
        return out


def _straggler(steps: list[int]) -> float:
    return max(steps) / (sum(steps) / len(steps)) if steps and sum(steps) else 1.0


def memory(args) -> None:
    cfg = EvalConfig(split=args.memory_split, scenes=args.memory_scenes,
                     episodes=args.memory_episodes, max_steps=args.memory_max_steps,
                     segmenter=args.segmenter, variants=("si",))
    engine = MeasuringEngine()
    _worker_init()  # one torch thread, as in run_eval
    t = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        run_variant(cfg, VARIANTS["si"], resolve_extractor(cfg.extractor),
                    Path(args.keep or tmp), progress=True, engine=engine)
    wall = time.perf_counter() - t
    r = engine.rounds
    rows = [[i, x["models"], x["states"], round(x["context"] / 1e6, 2),
             round(x["tasks"] / 1e3, 1), round(x["outcomes"] / 1e6, 2),
             round(x["pickle_s"], 3), round(x["unpickle_s"], 3), round(x["between_s"], 2),
             round(x["episodes_s"], 1), round(x["cpu_s"] / x["episodes"], 2),
             round(x["straggler"], 2)] for i, x in enumerate(r)]
    print_table(f"si over {cfg.source_name}, {args.memory_scenes} houses x "
                f"{args.memory_episodes} episodes, max {args.memory_max_steps} steps: what a "
                f"round ships ({wall:.0f} s, load avg {os.getloadavg()[0]:.1f})",
                ["round", "models", "states", "context MB", "tasks kB", "outcomes MB",
                 "pickle s", "unpickle s", "driver s", "episodes s", "CPU s/ep", "straggler"], rows,
                json_path=args.json)
    last = r[-1]
    final = last["context"] + last["outcomes"]  # what round N+1 would ship, roughly
    print(f"total shipped over {len(r)} rounds: context {sum(x['context'] for x in r) / 1e6:.1f}"
          f" MB, tasks {sum(x['tasks'] for x in r) / 1e6:.2f} MB, outcomes "
          f"{sum(x['outcomes'] for x in r) / 1e6:.1f} MB; last round {final / 1e6:.1f} MB; "
          f"mean straggler factor {sum(x['straggler'] for x in r) / len(r):.2f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--part", choices=["throughput", "overhead", "memory", "all"], default="all")
    ap.add_argument("--split", default="val-small")
    ap.add_argument("--scenes", type=int, default=3)
    ap.add_argument("--episodes", type=int, default=4)
    ap.add_argument("--variants", default="ans,si")
    ap.add_argument("--max-steps", type=int, default=500)
    ap.add_argument("--segmenter", default="learned")
    ap.add_argument("--tasks", type=int, default=200, help="no-op tasks timed on Ray")
    ap.add_argument("--context-mb", type=float, default=10.0,
                    help="context size for the overhead part")
    ap.add_argument("--memory-split", default="val")
    ap.add_argument("--memory-scenes", type=int, default=11)
    ap.add_argument("--memory-episodes", type=int, default=20)
    ap.add_argument("--memory-max-steps", type=int, default=500)
    ap.add_argument("--rounds", type=int, default=20, help="rounds timed on Ray")
    ap.add_argument("--keep", metavar="DIR", help="memory part: keep its store in DIR")
    ap.add_argument("--memory-store", metavar="DIR",
                    help="overhead part: ship the memory a '--part memory --keep DIR' left")
    ap.add_argument("--json", help="also write the memory part's rows to this JSON file")
    ap.add_argument("--one", nargs=3, metavar=("ENGINE", "WORKERS", "OUT"),
                    help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        return one_run(args)
    if args.part in ("throughput", "all"):
        throughput(args)
    if args.part in ("overhead", "all"):
        overhead(args, int(args.context_mb * 1e6))
    if args.part in ("memory", "all"):
        memory(args)


if __name__ == "__main__":
    main()
