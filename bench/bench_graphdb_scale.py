"""The memory as a graph database at scale: a store of 1e6 states x 512-d features, 1e5 objects.

    python bench/bench_graphdb_scale.py                      # 200 models x 5000 states (~40 min)
    python bench/bench_graphdb_scale.py --states 20000 --models 4   # a quick look (~1 min)

What it does, timing each step:

1. writes ``--models`` synthetic houses as a GraphML directory (each state sees ``--sees``
   objects, consecutive states are joined by a transition; ``--objects`` objects in all);
2. ``kgnav store convert`` of that directory into a LadybugDB database (the command itself);
3. fits the relocator from the database in a fresh process (``Relocator.open``: features streamed
   from the ``State`` table, no model loaded; the index is saved beside the database), for the
   exact and the HNSW backend (which keeps its rows in a temporary file beside the index while
   it fits), and reports the process's peak memory added by the fit against the raw feature
   bytes (target at most 1.5x);
4. reopens each saved index in a fresh process and times relocation queries (target p50 < 2 ms;
   recall@1 of HNSW against exact);
5. times every store-wide question of :mod:`kgnav.memory.store_query` on the database, each call
   opening the database as a user's call would (target p50 < 50 ms).

``--keep DIR`` keeps the directory, the database and the indexes there (default: a temporary
directory, removed at the end).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np
from _table import print_table

from kgnav import AbstractModel, Detection, ModelStore
from kgnav.memory.synthetic import SyntheticWorld

SIZE = 20.0  # metres: a large house's floor
_HERE = os.path.dirname(os.path.abspath(__file__))
_SRC = [os.path.dirname(_HERE), _HERE]

# a fresh process: fit (or reopen) the relocator over the database, memory before and at peak
_FIT = """
import json, sys, time
sys.path[:0] = {src!r}
import numpy as np
from kgnav import ModelStore, Relocator
def vm(key):
    for line in open("/proc/self/status"):
        if line.startswith(key):
            return int(line.split()[1]) / 1024
store = ModelStore({db!r})
before = vm("VmRSS:")
t = time.perf_counter()
r = Relocator.open(store, path={index!r}, backend={backend!r})
took = time.perf_counter() - t
peak = vm("VmHWM:")
queries = np.load({queries!r})
answers, times = [], []
for q in queries:
    t = time.perf_counter()
    best = r.nearest(q, 1)
    times.append(time.perf_counter() - t)
    answers.append(list(best[0][:2]))
ms = np.array(times) * 1e3
print(json.dumps(dict(before=before, peak=peak, s=took, states=r.n_states_, answers=answers,
                      p50=float(np.percentile(ms, 50)), p99=float(np.percentile(ms, 99)))))
"""


def walk(k: int, n: int) -> np.ndarray:
    """The ``(n, 3)`` poses of house ``k``'s walk."""
    rng = np.random.default_rng(k)
    # reflected at the walls, not clipped: a clipped walk piles its poses up in the corners,
    # where they merge into few states (a quarter of them did in the first run of this bench)
    span = SIZE - 1.0
    folded = np.abs((np.cumsum(rng.normal(0, 0.3, size=(n, 2)), 0) + span / 2) % (2 * span)
                    - span)
    return np.column_stack([0.5 + span - folded, rng.uniform(-math.pi, math.pi, n)])


def house(k: int, n: int, n_obj: int, dim: int, sees: int) -> AbstractModel:
    """A walk of ``n`` states through synthetic house ``k``; state ``i`` sees objects
    ``i*sees .. i*sees+sees-1`` (mod ``n_obj``), so every object is seen from about
    ``n*sees/n_obj`` states."""
    w = SyntheticWorld(seed=k, size=(SIZE, SIZE), n_objects=n_obj, feature_dim=dim)
    poses = walk(k, n)
    pos = poses[:, :2]
    feats = w.features_batch(poses)
    obj = np.array([(o.x, o.y) for o in w.objects])
    seen = (np.arange(n)[:, None] * sees + np.arange(sees)[None]) % n_obj
    m = AbstractModel(feature_dim=dim, model_id=f"house-{k:04d}")
    prev = None
    for i in range(n):
        dets = [Detection(w.objects[j].cls, (w.objects[j].x, w.objects[j].y, w.objects[j].z),
                          (0, 0, 10, 10), float(np.hypot(*(obj[j] - pos[i])))) for j in seen[i]]
        s = m.add_state(feats[i], tuple(poses[i]), dets, step=i)
        if prev is not None and prev != s:
            m.add_transition(prev, "move_forward", s)
        prev = s
    return m


def p50_ms(fn, calls) -> tuple[float, float]:
    times = []
    for args in calls:
        t = time.perf_counter()
        fn(*args)
        times.append(time.perf_counter() - t)
    ms = np.array(times) * 1e3
    return float(np.percentile(ms, 50)), float(np.percentile(ms, 99))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--states", type=int, default=1_000_000)
    ap.add_argument("--models", type=int, default=200)
    ap.add_argument("--objects", type=int, default=100_000)
    ap.add_argument("--dim", type=int, default=512)
    ap.add_argument("--sees", type=int, default=2, help="objects seen from each state")
    ap.add_argument("--queries", type=int, default=200)
    ap.add_argument("--calls", type=int, default=20, help="calls of each store-wide question")
    ap.add_argument("--backends", default="exact,hnsw")
    ap.add_argument("--keep", default=None, help="keep the stores and indexes in this directory")
    ap.add_argument("--reuse", action="store_true",
                    help="with --keep: use the database a previous run left there (steps 3-5)")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    from tqdm import tqdm

    from kgnav.memory import store_query as sq

    work = args.keep or tempfile.mkdtemp(prefix="kgnav-scale-")
    os.makedirs(work, exist_ok=True)
    directory, db = os.path.join(work, "memory"), os.path.join(work, "memory.lbug")
    reuse = args.reuse and args.keep and os.path.exists(db)
    if not reuse:
        shutil.rmtree(directory, ignore_errors=True)
    for p in ([] if reuse else [db, db + ".wal"]) + [
            os.path.join(work, f"relocator-{b}.npz") for b in args.backends.split(",")]:
        if os.path.exists(p):
            os.remove(p)
    per, n_obj = args.states // args.models, args.objects // args.models
    steps, rows = [], []
    try:
        if not reuse:
            # 1. the GraphML directory
            t = time.perf_counter()
            store = ModelStore(directory)
            for k in tqdm(range(args.models), desc="houses", unit="model"):
                store.save(house(k, per, n_obj, args.dim, args.sees))
            steps.append(["write GraphML directory", time.perf_counter() - t,
                          sum(os.path.getsize(os.path.join(directory, f))
                              for f in os.listdir(directory)) / 1e6])
            # 2. kgnav store convert
            t = time.perf_counter()
            subprocess.run([sys.executable, "-m", "kgnav.cli", "store", "convert", directory,
                            db], check=True,
                           env={**os.environ, "PYTHONPATH": os.pathsep.join(_SRC)})
            steps.append(["kgnav store convert -> database", time.perf_counter() - t, 0.0])
        size = sum(os.path.getsize(p) for p in (db, db + ".wal") if os.path.exists(p)) / 1e6
        steps.append(["database size", 0.0, size])
        dbs = ModelStore(db)
        (n_states,), (n_objects,), (n_sees,) = (dbs.cypher(q)[1][0] for q in (
            "MATCH (s:State) RETURN count(*)", "MATCH (o:Object) RETURN count(*)",
            "MATCH ()-[v:Sees]->() RETURN count(*)"))
        raw_mb = n_states * args.dim * 4 / 2**20
        # 3-4. the relocator: fit from the database, then reopen, in fresh processes
        # queries revisit the houses: a stored pose moved by 0.1 m and 3 degrees, as an agent
        # coming back to a place would see it (a query far from every state matches nothing,
        # and which of many equally far states is "nearest" says nothing about the index)
        rng = np.random.default_rng(1)
        qs = []
        for k in rng.integers(0, args.models, args.queries):
            w = SyntheticWorld(seed=int(k), size=(SIZE, SIZE), n_objects=n_obj,
                               feature_dim=args.dim)
            p = walk(int(k), per)[rng.integers(per)] + [*rng.normal(0, 0.1, 2), 0.05]
            qs.append(w.features_batch(p[None])[0])
        queries = os.path.join(work, "queries.npy")
        np.save(queries, np.array(qs, np.float32))
        reference = None
        for backend in args.backends.split(","):
            index = os.path.join(work, f"relocator-{backend}.npz")
            for phase in ("fit", "reopen"):
                code = _FIT.format(src=_SRC, db=db, index=index, backend=backend,
                                   queries=queries)
                r = json.loads(subprocess.run([sys.executable, "-c", code], check=True,
                                              capture_output=True, text=True).stdout)
                if reference is None:
                    reference = r["answers"]
                recall = float(np.mean([a == b for a, b in zip(r["answers"], reference,
                                                                strict=True)]))
                added = r["peak"] - r["before"]
                rows.append([backend, phase, r["states"], round(r["s"], 1), round(added),
                             round(added / raw_mb, 2), round(r["p50"], 3), round(r["p99"], 3),
                             recall])
            steps.append([f"index file ({backend})", 0.0, os.path.getsize(index) / 1e6])
        # 5. store-wide questions on the database
        _, objs = dbs.cypher("MATCH (o:Object) RETURN o.model, o.id, o.cls LIMIT 2000")
        _, sts = dbs.cypher("MATCH (s:State) RETURN s.model, s.id LIMIT 2000")
        pick = rng.permutation(len(objs))[: args.calls]
        spick = rng.permutation(len(sts))[: args.calls]
        classes = sorted({o[2] for o in objs})
        questions = [
            ("find_objects(cls)", sq.find_objects,
             [(dbs, classes[i % len(classes)]) for i in range(args.calls)]),
            ("models_with_classes_near(a, b, 3 m)", sq.models_with_classes_near,
             [(dbs, classes[i % len(classes)], classes[(i + 1) % len(classes)], 3.0)
              for i in range(args.calls)]),
            ("states_that_saw(model, object)", sq.states_that_saw,
             [(dbs, objs[i][0], objs[i][1]) for i in pick]),
            ("class_inventories()", sq.class_inventories, [(dbs,)] * args.calls),
            ("objects_near_state(model, state, 3)", sq.objects_near_state,
             [(dbs, sts[i][0], sts[i][1], 3) for i in spick]),
        ]
        qrows = [[name, *p50_ms(fn, calls)] for name, fn, calls in questions]
        with dbs.reading():  # the same calls, the database opened once
            for row, (_, fn, calls) in zip(qrows, questions, strict=True):
                row.extend(p50_ms(fn, calls))
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)
    load = " ".join(open("/proc/loadavg").read().split()[:3])
    print_table(f"Store: {n_states} states x {args.dim}-d ({raw_mb:.0f} MB of features), "
                f"{n_objects} objects, {n_sees} sightings, {args.models} models "
                f"(load average {load})", ["step", "seconds", "MB on disk"],
                [[s, round(t, 1), round(mb, 1)] for s, t, mb in steps], None)
    print_table("Relocator from the database (fresh process each; added = peak RSS - RSS "
                "before, MB; ratio = added / feature bytes)",
                ["backend", "phase", "states", "seconds", "added_MB", "ratio", "p50_ms",
                 "p99_ms", "recall@1"], rows, None)
    print_table(f"Store-wide questions, {args.calls} calls each (ms): each call opening the "
                "database, and inside one store.reading() block", ["question", "p50_ms",
                "p99_ms", "p50_in_block_ms", "p99_in_block_ms"], qrows, None)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"steps": steps, "relocator": rows, "questions": qrows}, fh, indent=1)


if __name__ == "__main__":
    main()
