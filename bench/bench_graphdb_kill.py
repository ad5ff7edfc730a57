"""kill -9 during graph-database saves: how many trials leave a model that is neither the old
nor the new version (the target is none).

A writer process saves two versions of one model in turn, printing ``begin`` / ``end`` around
each save; the parent kills it at a random moment and reads the model back. A trial counts as
"mid-save" when the last line the writer printed was ``begin``.

    .venv/bin/python bench/bench_graphdb_kill.py --trials 50
"""

from __future__ import annotations

import argparse
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _table import print_table

from kgnav import ModelStore
from kgnav.memory.synthetic import SyntheticWorld

_WRITER = """
import sys
from kgnav import ModelStore
from kgnav.memory.synthetic import SyntheticWorld
store = ModelStore(sys.argv[1])
walks = [SyntheticWorld(seed=s, size=(15.0, 15.0), n_objects=40, feature_dim=512).explore(
    int(sys.argv[2]), seed=s) for s in (5, 6)]
for w in walks:
    w.graph.graph["model_id"] = "h"
print("ready", flush=True)
i = 0
while True:
    print("begin", flush=True)
    store.save(walks[i % 2])
    print("end", flush=True)
    i += 1
"""


def versions(steps: int):
    out = []
    for s in (5, 6):
        w = SyntheticWorld(seed=s, size=(15.0, 15.0), n_objects=40, feature_dim=512).explore(
            steps, seed=s)
        w.graph.graph["model_id"] = "h"
        out.append(w)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=50)
    ap.add_argument("--steps", type=int, default=600, help="states of each version (about)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    rng = random.Random(args.seed)
    old, new = versions(args.steps)
    whole = corrupt = mid = 0
    save_s = []
    with tempfile.TemporaryDirectory() as tmp:
        for trial in range(args.trials):
            root = Path(tmp) / f"t{trial}.lbug"
            t = time.perf_counter()
            ModelStore(root).save(old)
            save_s.append(time.perf_counter() - t)
            proc = subprocess.Popen([sys.executable, "-c", _WRITER, str(root), str(args.steps)],
                                    stdout=subprocess.PIPE, text=True)
            assert proc.stdout.readline().strip() == "ready"
            time.sleep(rng.uniform(0.05, 3.0))
            proc.send_signal(signal.SIGKILL)
            lines = proc.stdout.read().split()
            proc.wait()
            mid += bool(lines) and lines[-1] == "begin" or not lines
            try:
                back = ModelStore(root).load("h")
                ok = back == old or back == new
            except Exception:  # noqa: BLE001 - any failure to read is a corrupt trial
                ok = False
            whole += ok
            corrupt += not ok
    print_table(f"kill -9 during saves ({old.n_states} / {new.n_states} states, 512-d)",
                ["trials", "killed mid-save", "whole model after", "corrupt", "save_s (min)"],
                [[args.trials, mid, whole, corrupt, round(min(save_s), 3)]])


if __name__ == "__main__":
    main()
