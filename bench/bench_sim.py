"""Speed of the embedded simulator on one CPU core: render + step, by resolution and by the
number of objects in view.

    .venv/bin/python bench/bench_sim.py            # full table
    .venv/bin/python bench/bench_sim.py --quick    # fewer steps

Pins the process to one core and single-threaded BLAS before numpy is imported.
"""

from __future__ import annotations

import argparse
import os
import time

import _one_core  # noqa: F401  (must come before numpy)
import numpy as np

from kgnav.sim import (
    Episode,
    ObjectInstance,
    ObjectNavEnv,
    Renderer,
    Room,
    Scene,
    Texture,
    Wall,
)


def bench_env(width: int, height: int, steps: int) -> tuple[float, float]:
    """(steps/s, mean objects in view) of env.step with random non-stop actions, scene val_00."""
    env = ObjectNavEnv(split="val", scene=0, width=width, height=height)
    rng = np.random.default_rng(0)
    actions = rng.choice([1, 1, 2, 3], size=steps)
    env.reset(seed=0)
    env.step(1)
    seen = 0
    t0 = time.perf_counter()
    for a in actions:
        obs, _, term, trunc, _ = env.step(int(a))
        seen += len(np.unique(obs["semantic"][..., 1])) - 1
        if term or trunc:
            env.reset()
    dt = time.perf_counter() - t0
    # np.unique is measurement overhead: time it separately and subtract
    sem = obs["semantic"][..., 1]
    t1 = time.perf_counter()
    for _ in range(steps):
        np.unique(sem)
    dt -= time.perf_counter() - t1
    return steps / dt, seen / steps


def objects_scene(n: int) -> Scene:
    """A 12 m x 12 m room with ``n`` boxes of mixed heights scattered in front of (3, 6)."""
    size, h = 12.0, 0.05
    walls = (Wall(-h, -h, size + h, h), Wall(-h, size - h, size + h, size + h),
             Wall(-h, -h, h, size + h), Wall(size - h, -h, size + h, size + h))
    room = Room(0, "living_room", 0.0, 0.0, size, size, (200, 190, 170), (110, 80, 50),
                Texture(1, 0.4, 0.1), Texture(3, 0.2, 0.1))
    rng = np.random.default_rng(n)
    objs = []
    while len(objs) < n:
        x, y = rng.uniform(4.0, 8.0), rng.uniform(3.5, 8.5)
        if abs(y - 6.0) > (x - 3.0) * 0.8:  # keep inside the 79 degree field of view
            continue
        w, d = rng.uniform(0.2, 0.5, 2)
        top = float(rng.choice([0.45, 0.8, 1.2, 2.0]))
        objs.append(ObjectInstance(len(objs) + 1, "chair", 0, x, y, x + w, y + d, 0.0, top,
                                   tuple(int(v) for v in rng.integers(0, 255, 3))))
    return Scene(f"objects_{n}", 0, size, size, (room,), (), walls, tuple(objs))


def bench_objects(n: int, width: int, height: int, frames: int) -> tuple[float, float]:
    """(frames/s, objects visible) rendering ``n`` boxes in view, plus the env step overhead."""
    scene = objects_scene(n)
    ep = Episode("b", scene.name, (3.0, 6.0, 0.0), "chair", 0.0, 0.0)
    env = ObjectNavEnv(scene=scene, episodes=[ep], width=width, height=height)
    env.reset(seed=0)
    r: Renderer = env.renderer
    poses = [(3.0, 6.0, a) for a in np.linspace(-0.05, 0.05, frames)]
    visible = len(np.unique(r.render(*poses[0])[2][..., 1])) - 1
    t0 = time.perf_counter()
    for p in poses:
        env._world = p
        env.step(2 if len(poses) % 2 else 3)  # a turn: render + step with no motion
        env._done = False
    return frames / (time.perf_counter() - t0), visible


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true", help="fewer steps (noisier numbers)")
    args = ap.parse_args()
    k = 0.25 if args.quick else 1.0
    cpu = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else "?"
    print(f"kgnav.sim benchmark, one core (affinity {cpu}), OMP_NUM_THREADS="
          f"{os.environ.get('OMP_NUM_THREADS')}")
    print()
    print("| resolution | steps/s (render + step) | ms/step | objects in view (mean) |")
    print("|---|---|---|---|")
    for (w, h), n in (((160, 120), 3000), ((320, 240), 1000), ((640, 480), 300)):
        sps, seen = bench_env(w, h, max(int(n * k), 20))
        print(f"| {w}x{h} | {sps:.0f} | {1e3 / sps:.2f} | {seen:.1f} |")
    print()
    print("| objects in front | visible | steps/s 160x120 | steps/s 640x480 |")
    print("|---|---|---|---|")
    for n in (0, 10, 40):
        a, vis = bench_objects(n, 160, 120, max(int(1500 * k), 20))
        b, _ = bench_objects(n, 640, 480, max(int(200 * k), 10))
        print(f"| {n} | {vis} | {a:.0f} | {b:.0f} |")


if __name__ == "__main__":
    main()
