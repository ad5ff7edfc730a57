"""Global exploration policies: explored area after 100/250/500 actions on the val houses, time
per decision on one core, and the ObjectNav comparison of two ``kgnav eval`` runs.

    .venv/bin/python bench/bench_policy.py                         # frontier, ppo, random, oracle
    .venv/bin/python bench/bench_policy.py --episodes 1 --oracle-episodes 0     # quicker
    .venv/bin/python bench/bench_policy.py --compare export/eval_frontier export/eval_ppo

Pins the process to one core and single-threaded BLAS/torch before numpy is imported. The
coverage part plays every policy from the same starts (the first ``--episodes`` episodes of each
val house) in the map-level environment (:mod:`kgnav.nets.explore.mapenv`): the agent follows the
planner's path on the ground truth and maps by 2-D ray casting, exactly as the learned policy was
trained; ``oracle`` is the greedy ground-truth look-ahead (:class:`kgnav.nets.explore.bench.
GreedyOracle`). ms/decision is the time of one ``select`` call (frontier: clustering and a Fast
Marching over the explored area; ppo: the map crop, the network and the reachability snap).

``--compare BASE OTHER`` reads two ``kgnav eval`` output directories that differ only in
``--policy`` and prints, per variant in both, each run's Success / SPL / SoftSPL and the paired
difference OTHER − BASE over the same episodes, with a 95 % bootstrap interval.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import _one_core  # noqa: F401  (must come before numpy)
import torch

from kgnav.cli.policy import coverage_table
from kgnav.nets.explore.bench import compare_runs, coverage_bench


def compare(base: Path, other: Path) -> None:
    def read(d: Path) -> tuple[list[dict], dict]:
        recs = [json.loads(line) for line in (d / "episodes.jsonl").read_text().splitlines()]
        cfg = json.loads((d / "config.json").read_text())
        return recs, cfg

    (ra, ca), (rb, cb) = read(base), read(other)
    name_a, name_b = ca.get("policy") or "frontier", cb.get("policy") or "frontier"
    res = compare_runs(ra, rb)
    print(f"\n{other.name} ({name_b}) − {base.name} ({name_a}), same episodes; "
          f"bootstrap 95 % interval")
    head = f"{'variant':8} {'metric':8} {name_a:>9} {name_b:>9}  {'difference [95 % CI]':28} pairs"
    print(head)
    print("-" * len(head))
    for v, row in res.items():
        for m, d in row.items():
            print(f"{v:8} {m:8} {d['base']:9.3f} {d['other']:9.3f}  "
                  f"{d['diff']:+.3f} [{d['low']:+.3f}, {d['high']:+.3f}]{'':6} {d['pairs']}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--policies", default="frontier,ppo,random-goal,oracle")
    ap.add_argument("--houses", type=int, default=None, help="first K val houses (all)")
    ap.add_argument("--episodes", type=int, default=3, help="starts per house")
    ap.add_argument("--oracle-episodes", type=int, default=1,
                    help="starts per house for the oracle (0: leave it out)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--json", default=None, help="also write the report here")
    ap.add_argument("--compare", nargs=2, metavar=("BASE", "OTHER"), type=Path)
    args = ap.parse_args()
    torch.set_num_threads(1)
    if args.compare:
        compare(*args.compare)
        return
    names = [p for p in args.policies.split(",") if p and not (
        p == "oracle" and args.oracle_episodes == 0)]
    report = coverage_bench(names, split="val", houses=args.houses, episodes=args.episodes,
                            oracle_episodes=args.oracle_episodes or None, seed=args.seed)
    print(coverage_table(report))
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
