"""A long life: does a house's memory stay true over many episodes, or do errors pile up?

    .venv/bin/python bench/bench_long_life.py                       # 3 train houses x 50
    .venv/bin/python bench/bench_long_life.py --scenes 2 --episodes 20 --first 5
    .venv/bin/python bench/bench_long_life.py --noise none --out /tmp/life

Runs ``si`` twice on the same houses with the benchmark's defaults (``--noise locobot`` unless
told otherwise): once for the first ``--first`` episodes of each house, once for all
``--episodes``. Every episode is seeded from (seed, house, episode), so the long run's first
episodes are the short run's, and the two memories are the same house's memory after its first
episodes and after its last. The table compares, per house and pooled, what issue 29 asks to
stay no worse: the stored objects' precision, recall and copies, the stored states' pose error
against the truth (median and 95th percentile), the number of models, and the success of the
first and of the last ``--first`` episodes. Each run's ``episodes.jsonl`` and ``summary.json``
stay under ``--out``.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from _table import print_table

from kgnav.benchmark.runner import EvalConfig, run_eval


def _memory_rows(label: str, memory: dict) -> list[list]:
    rows = []
    for name, h in [*sorted(memory["houses"].items()), ("pooled", memory["pooled"])]:
        pose = h.get("pose_error_m") or {}
        models = h.get("models", h.get("houses_with_one_model", "-"))
        if name == "pooled":
            models = sum(int(k) * v for k, v in h.get("models_per_house", {}).items())
        rows.append([name, label, h.get("objects", "-"), h.get("precision", "-"),
                     h.get("recall", "-"), h.get("copies", "-"), models,
                     pose.get("median", "-"), pose.get("p95", "-")])
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--split", default="train")
    ap.add_argument("--scenes", type=int, default=3)
    ap.add_argument("--episodes", type=int, default=50)
    ap.add_argument("--first", type=int, default=10,
                    help="compare the memory after this many episodes with the last one")
    ap.add_argument("--noise", default=None, help="noise spec [default: the benchmark's]")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=None, help="keep both runs here")
    args = ap.parse_args()
    if not 0 < args.first < args.episodes:
        ap.error("--first must be between 0 and --episodes")
    out = args.out or Path(tempfile.mkdtemp(prefix="kgnav-life-"))
    summaries, records = {}, {}
    for n in (args.first, args.episodes):
        cfg = EvalConfig(split=args.split, scenes=args.scenes, episodes=n, variants=("si",),
                         workers=args.workers, seed=args.seed, noise=args.noise)
        recs, summary = run_eval(cfg, out / f"first{n}", progress=True)
        summaries[n], records[n] = summary["si"], [r for r in recs if r["variant"] == "si"]
    print(f"noise {cfg.noise}, {args.scenes} {args.split} houses, si; runs under {out}")
    rows = []
    for n in (args.first, args.episodes):
        rows += _memory_rows(f"after {n}", summaries[n]["memory"])
    rows.sort(key=lambda r: (r[0] == "pooled", r[0]))
    print_table("Memory after the first episodes and after the last",
                ["house", "memory", "objects", "precision", "recall", "copies", "models",
                 "pose err median (m)", "pose err p95 (m)"], rows)
    last = [r for r in records[args.episodes] if r["episode"] >= args.episodes - args.first]
    first = records[args.first]
    print_table("Success of the first and the last episodes of each house",
                ["episodes", "n", "success", "spl"],
                [[f"first {args.first}", len(first), sum(r["success"] for r in first) / len(first),
                  sum(r["spl"] for r in first) / len(first)],
                 [f"last {args.first}", len(last), sum(r["success"] for r in last) / len(last),
                  sum(r["spl"] for r in last) / len(last)]])


if __name__ == "__main__":
    main()
