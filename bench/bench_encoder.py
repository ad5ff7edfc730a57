"""Speed of the state-feature extractors on one CPU core: ms per 160×120 frame, one frame per
call (what the agent does every step) and batched.

    .venv/bin/python bench/bench_encoder.py                 # shipped encoder and opencv-gist
    .venv/bin/python bench/bench_encoder.py --weights a.npz --weights b.npz   # compare weights

Pins the process to one core and single-threaded BLAS/torch before numpy is imported. Frames
are rendered from the val houses; each timing is the best of ``--repeats`` runs over them.
"""

from __future__ import annotations

import argparse
import time

import _one_core  # noqa: F401  (must come before numpy)
import numpy as np
import torch
from _table import print_table

from kgnav.agent.features import make_extractor
from kgnav.nets.encoder.views import ViewSampler
from kgnav.sim.episodes import load_scene_of


def frames(n: int, seed: int = 0) -> np.ndarray:
    """``n`` RGB frames (160×120) from random poses in the val houses."""
    sampler = ViewSampler([load_scene_of("val", k) for k in range(11)])
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        h = i % len(sampler)
        out.append(sampler.render(h, sampler.random_pose(h, rng)))
    return np.stack(out)


def per_frame_ms(fn, items, repeats: int) -> float:
    """Best-of-``repeats`` milliseconds per item of ``fn`` applied to each item in turn."""
    for it in items[:10]:  # warm-up: allocator, caches, lazy initialisation
        fn(it)
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        for it in items:
            fn(it)
        best = min(best, time.perf_counter() - t)
    return 1000 * best / len(items)


def batched_ms(ext, imgs: np.ndarray, batch: int, repeats: int) -> float:
    chunks = [imgs[i:i + batch] for i in range(0, len(imgs), batch)]
    if hasattr(ext, "batch"):
        return per_frame_ms(ext.batch, chunks, repeats) * len(chunks) / len(imgs)
    return per_frame_ms(lambda c: [ext(f) for f in c], chunks, repeats) * len(chunks) / len(imgs)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=200, help="frames to time on")
    ap.add_argument("--batch", type=int, default=64, help="batch size of the batched timing")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--weights", action="append", default=[],
                    help="encoder weight file(s) to time [default: the shipped weights]")
    ap.add_argument("--json", help="also write the rows to this JSON file")
    args = ap.parse_args()
    torch.set_num_threads(1)
    imgs = frames(args.frames)
    exts = [(f"kgnav-encoder ({w})" if w else "kgnav-encoder",
             make_extractor("kgnav-encoder", weights=w, device="cpu"))
            for w in (args.weights or [None])]
    exts.append(("opencv-gist", make_extractor("opencv-gist")))
    rows = []
    for label, ext in exts:
        single = per_frame_ms(ext, list(imgs), args.repeats)
        batched = batched_ms(ext, imgs, args.batch, args.repeats)
        rows.append([label, ext.dim, single, batched, 100 * single / 10.0])
    print_table(f"state features, one CPU core, {args.frames} frames 160x120 (best of "
                f"{args.repeats})",
                ["extractor", "dim", "ms/frame single", f"ms/frame batch {args.batch}",
                 "% of 10 ms step"], rows, args.json)


if __name__ == "__main__":
    main()
