"""GraphML save/load of large Abstract Models. Target: a 1e4-state model saves and loads in < 1 s.

    python bench/bench_graphml.py [--steps 12000] [--dims 2048,512] [--repeat 3]

The model is what the agent records on a long walk through a 20 m x 20 m synthetic house with 150
objects: every state has features, a pose, its object views (about five) and transitions.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time

from _table import print_table

from kgnav.graphml import read_model, write_model
from kgnav.synthetic import SyntheticWorld


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=11500, help="walk length (about 1e4 states)")
    ap.add_argument("--dims", default="2048,512")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--json", default=None, help="also write the rows here")
    args = ap.parse_args()
    rows = []
    for dim in (int(d) for d in args.dims.split(",")):
        world = SyntheticWorld(seed=0, size=(20.0, 20.0), n_objects=150, feature_dim=dim)
        model = world.explore(args.steps, seed=0)
        views = sum(1 for _, _, k in model.graph.edges(keys=True) if k == "sees")
        with tempfile.TemporaryDirectory() as tmp:
            path = os.path.join(tmp, "m.graphml")
            saves, loads = [], []
            for _ in range(args.repeat):
                t = time.perf_counter()
                write_model(model, path)
                saves.append(time.perf_counter() - t)
                t = time.perf_counter()
                back = read_model(path)
                loads.append(time.perf_counter() - t)
            assert back == model
            size = os.path.getsize(path) / 1e6
        rows.append([model.n_states, dim, views, model.n_transitions, round(size, 1),
                     min(saves), min(loads), model.n_states / min(loads)])
    print_table(f"GraphML save/load, best of {args.repeat} (seconds)",
                ["states", "dim", "views", "transitions", "MB", "save_s", "load_s",
                 "states/s load"], rows, args.json)


if __name__ == "__main__":
    main()
