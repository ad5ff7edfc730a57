"""Speed of the segmenters on one CPU core, per 160×120 frame, and of the agent loop with them.

    .venv/bin/python bench/bench_segmenter.py                # shipped network + noise presets
    .venv/bin/python bench/bench_segmenter.py --frames 100 --agent-episodes 0   # quicker

Pins the process to one core and single-threaded BLAS/torch before numpy is imported. Frames
are rendered from the val houses (half aimed at objects). For the learned segmenter the time is
split into its stages: preprocessing (downscale to 80×60, tensors), the network, per-pixel class
and confidence, components and maps. Each figure is the median over frames of the best of
``--repeats`` calls. Targets: the network segmenter ≤ 4 ms per frame; the whole agent loop with
it ≥ 100 steps/s.
"""

from __future__ import annotations

import argparse
import time

import _one_core  # noqa: F401  (must come before numpy)
import numpy as np
import torch
from _table import print_table
from bench_agent import run as run_agent

from kgnav.agent.segmentation import make_segmenter
from kgnav.nets.segnet.bench import render_frames
from kgnav.nets.segnet.net import preprocess


def best_ms(fn, repeats: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return 1e3 * best


def median_ms(fn, frames, repeats: int) -> float:
    for k in range(min(10, len(frames))):  # warm-up
        fn(k)
    return float(np.median([best_ms(lambda k=k: fn(k), repeats) for k in range(len(frames))]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--agent-scenes", type=int, default=3)
    ap.add_argument("--agent-episodes", type=int, default=2, help="per scene; 0: skip")
    args = ap.parse_args()
    torch.set_num_threads(1)
    fr = render_frames("val", args.frames, seed=1)
    seg = make_segmenter("learned")
    net = seg.net

    def network(k):
        x, d = preprocess(fr.rgb[k], fr.depth[k], seg.arch)
        with torch.inference_mode():
            net(x, d)

    rows = [
        ["learned: preprocess", median_ms(
            lambda k: preprocess(fr.rgb[k], fr.depth[k], seg.arch), fr, args.repeats)],
        ["learned: + network", median_ms(network, fr, args.repeats)],
        ["learned: + class / confidence", median_ms(
            lambda k: seg.probabilities(fr.rgb[k], fr.depth[k]), fr, args.repeats)],
        ["learned: whole call (+ components, maps)", median_ms(
            lambda k: seg(fr.rgb[k], fr.depth[k]), fr, args.repeats)],
    ]
    for preset in ("clean", "default", "heavy"):
        s = make_segmenter(preset)
        s.reset(0, "bench")
        rows.append([f"{preset} (noise on ground truth)", median_ms(
            lambda k, s=s: s(fr.rgb[k], fr.depth[k], fr.semantic[k]), fr, args.repeats)])
    print_table(f"segmenter, one core, 160x120, median over {len(fr)} val frames of the best of "
                f"{args.repeats} (target: learned <= 4 ms)", ["stage / segmenter", "ms/frame"],
                rows)
    if args.agent_episodes:
        summary = []
        for name in ("learned", "default"):
            stages, rate, steps = run_agent("opencv-gist", 160, 120, args.agent_scenes,
                                            args.agent_episodes, segmenter=name)
            print_table(f"agent loop, segmenter {name}, opencv-gist, 160x120, {steps} steps "
                        f"({rate:.0f} steps/s)", ["stage", "ms/step", "% of time"], stages)
            summary.append([name, steps, rate])
        print_table("whole agent loop with each segmenter (target >= 100 steps/s)",
                    ["segmenter", "steps", "steps/s"], summary)


if __name__ == "__main__":
    main()
