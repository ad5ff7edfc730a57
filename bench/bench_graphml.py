"""GraphML save/load of large Abstract Models. Target: a 1e4-state model saves and loads in < 1 s.

    python bench/bench_graphml.py [--steps 11500] [--dims 2048,512] [--repeat 5]
    python bench/bench_graphml.py --peak-mb 200      # peak memory of loading a ~200 MB file
    python bench/bench_graphml.py --peak-mb 200 --peak-dim 32   # ... of many small states

The model is what the agent records on a long walk through a 20 m x 20 m synthetic house with 150
objects: every state has features, a pose, its object views (about five) and transitions. Times
are the best of ``--repeat`` runs on one core (the process is pinned); a save includes the fsync.
``*_cpu_s`` is the process's CPU time for the same call (``time.process_time``): on a shared
machine, where the wall clock also counts the time other processes hold the core, it is the
closer figure for a quiet core. ``load_xml_s`` is the general XML reader, which files kgnav did
not write in its own layout take.

``--peak-mb`` writes a model of about that size, then loads it in a fresh process per reader and
reports the process's peak resident memory (VmHWM) beside its memory before the load; also for
the same file with the graph's attributes after its nodes, as networkx writes them.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import _one_core  # noqa: F401  (must come before numpy)
from _table import print_table

from kgnav.memory.graphml import read as graphml_read
from kgnav.memory.graphml import write_model
from kgnav.memory.model import AbstractModel
from kgnav.memory.synthetic import SyntheticWorld

# run in a fresh process: load the file with one reader, print memory before and at the peak
_PEAK = """
import json, sys, time
sys.path[:0] = {path!r}
from kgnav import AbstractModel
from kgnav.memory.graphml import read as gr
def vm(key):
    for line in open("/proc/self/status"):
        if line.startswith(key):
            return int(line.split()[1]) / 1024
before = vm("VmRSS:")
t = time.perf_counter()
if {xml!r}:
    m = AbstractModel.from_graph(gr._XmlReader({file!r}, 1 << 40).read())
else:
    m = AbstractModel.load({file!r}, max_bytes=1 << 40)
print(json.dumps(dict(before=before, peak=vm("VmHWM:"), s=time.perf_counter() - t,
                      states=m.n_states)))
"""


def walk(steps: int, dim: int):
    world = SyntheticWorld(seed=0, size=(20.0, 20.0), n_objects=150, feature_dim=dim)
    return world.explore(steps, seed=0)


def speed(args) -> None:
    rows = []
    for dim in (int(d) for d in args.dims.split(",")):
        model = walk(args.steps, dim)
        views = sum(1 for _, _, k in model.graph.edges(keys=True) if k == "sees")
        with tempfile.TemporaryDirectory() as tmp:
            path = os.path.join(tmp, "m.graphml")
            saves, loads, xml_loads, save_cpu, load_cpu = [], [], [], [], []
            for _ in range(args.repeat):
                t, c = time.perf_counter(), time.process_time()
                write_model(model, path)
                saves.append(time.perf_counter() - t)
                save_cpu.append(time.process_time() - c)
                t, c = time.perf_counter(), time.process_time()
                back = AbstractModel.load(path)
                loads.append(time.perf_counter() - t)
                load_cpu.append(time.process_time() - c)
                t = time.perf_counter()
                back_xml = graphml_read._XmlReader(path, 1 << 40).read()
                xml_loads.append(time.perf_counter() - t)
            assert back == model and AbstractModel.from_graph(back_xml) == model
            size = os.path.getsize(path) / 1e6
        rows.append([model.n_states, dim, views, model.n_transitions, round(size, 1),
                     min(saves), min(save_cpu), min(loads), min(load_cpu), min(xml_loads),
                     model.n_states / min(loads)])
    load = " ".join(open("/proc/loadavg").read().split()[:3]) if os.path.exists(
        "/proc/loadavg") else "?"
    print_table(f"GraphML save/load, best of {args.repeat} (seconds; load average {load})",
                ["states", "dim", "views", "transitions", "MB", "save_s", "save_cpu_s", "load_s",
                 "load_cpu_s", "load_xml_s", "states/s load"], rows, args.json)


def _attributes_last(src: str, dst: str) -> None:
    """``src`` with the graph's attributes moved after its nodes and edges, where networkx
    writes them (the general reader takes such a file)."""
    with open(src) as fh:
        text = fh.read()
    start = text.index('<graph edgedefault="directed">\n') + len('<graph edgedefault="directed">\n')
    stop = text.index("\n", start) + 1
    close = text.rindex("</graph>")
    with open(dst, "w") as fh:
        fh.write(text[:start] + text[stop:close] + text[start:stop] + text[close:])


def peak(args) -> None:
    # 1e4 steps of 2048-d features with their views make about 128 MB; of 32-d, about 18 MB
    per_1e4 = 18.2 + 109.8 * args.peak_dim / 2048
    steps = int(args.steps * args.peak_mb / per_1e4)
    model = walk(steps, args.peak_dim)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "big.graphml")
        write_model(model, path)
        size = os.path.getsize(path) / 1e6
        del model
        late = os.path.join(tmp, "late.graphml")
        _attributes_last(path, late)
        here = os.path.dirname(os.path.abspath(__file__))
        src = [os.path.dirname(here), here]
        for name, file, xml in (("load", path, False), ("xml", path, True),
                                ("load, attributes last", late, False)):
            code = _PEAK.format(path=src, file=file, xml=xml)
            out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                                 check=True).stdout
            r = json.loads(out)
            added = r["peak"] - r["before"]
            rows.append([name, round(size, 1), r["states"], round(r["s"], 2),
                         round(r["before"]), round(r["peak"]), round(added),
                         round(added / size, 2)])
    print_table("Peak memory loading one file (MB; a fresh process per reader)",
                ["reader", "file_MB", "states", "load_s", "rss_before", "peak_rss", "added",
                 "added/file"],
                rows, args.json)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=11500, help="walk length (about 1e4 states)")
    ap.add_argument("--dims", default="2048,512")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--peak-mb", type=float, default=None,
                    help="instead: peak memory of loading a file of about this size")
    ap.add_argument("--peak-dim", type=int, default=2048,
                    help="feature size of --peak-mb's model (32: many small states)")
    ap.add_argument("--json", default=None, help="also write the rows here")
    args = ap.parse_args()
    if args.peak_mb:
        peak(args)
    else:
        speed(args)


if __name__ == "__main__":
    main()
