"""Relocator: build time, single-query latency, recall@1 of the approximate backend vs exact.

    python bench/bench_relocator.py [--sizes 1000,10000,200000] [--dim 2048] [--queries 300]

Stored states are several environments' worth of clustered 2048-d features (20 synthetic worlds,
random poses in each); queries are views from new poses in the same worlds. Target: p50 below
1 ms at 2e5 states with recall@1 >= 0.99.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from _table import print_table

from kgnav import AbstractModel, Relocator
from kgnav.memory.synthetic import clustered_features


def models_from(feats: np.ndarray, which: np.ndarray) -> list[AbstractModel]:
    out = []
    for w in np.unique(which):
        rows = np.flatnonzero(which == w)
        m = AbstractModel(feature_dim=feats.shape[1], model_id=f"world{w}")
        for k, r in enumerate(rows):  # distinct poses so no state is deduplicated
            m.add_state(feats[r], (float(k), 0.0, 0.0), step=k)
        out.append(m)
    return out


def latency(relocator: Relocator, queries: np.ndarray):
    times, answers = [], []
    for q in queries:
        t = time.perf_counter()
        best = relocator.nearest(q, 1)
        times.append(time.perf_counter() - t)
        answers.append(best[0][:2])
    ms = np.array(times) * 1e3
    return float(np.percentile(ms, 50)), float(np.percentile(ms, 99)), answers


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="1000,10000,200000")
    ap.add_argument("--dim", type=int, default=2048)
    ap.add_argument("--worlds", type=int, default=20)
    ap.add_argument("--queries", type=int, default=300)
    ap.add_argument("--threads", type=int, default=1, help="faiss OpenMP threads")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    try:
        import faiss

        faiss.omp_set_num_threads(args.threads)
        backends = ["exact", "hnsw"]
    except ImportError:
        backends = ["exact"]
    rows = []
    for n in (int(s) for s in args.sizes.split(",")):
        feats, which, _ = clustered_features(n, args.dim, n_worlds=args.worlds, seed=0)
        queries, _, _ = clustered_features(args.queries, args.dim, n_worlds=args.worlds, seed=0)
        # same worlds (seed 0), new poses: clustered_features draws fresh poses per call size
        models = models_from(feats, which)
        del feats
        reference = None
        for backend in backends:
            t = time.perf_counter()
            reloc = Relocator(backend=backend).fit(models)
            build_s = time.perf_counter() - t
            p50, p99, answers = latency(reloc, queries)
            if backend == "exact":
                reference, recall = answers, 1.0
            else:
                recall = float(np.mean([a == b for a, b in zip(answers, reference, strict=True)]))
            rows.append([n, backend, round(build_s, 2), p50, p99, recall])
            del reloc
        del models
    print_table(
        f"Relocator, {args.dim}-d features, {args.worlds} worlds, {args.queries} queries",
        ["states", "backend", "build_s", "p50_ms", "p99_ms", "recall@1"], rows, args.json,
    )


if __name__ == "__main__":
    main()
