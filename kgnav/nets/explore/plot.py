"""The training curve of an exploration policy: explored area and return per PPO iteration."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np


def plot_curve(curve: list[dict], path: str | os.PathLike[str], title: str = "",
               window: int = 10) -> Path:
    """Write a PNG of a :attr:`~kgnav.nets.explore.train.PPOTrainer.curve`: left, the mean explored
    area after 100 / 250 / 500 actions of the training episodes (moving average over
    ``window`` iterations, raw values faint); right, the mean episode return and the policy's
    entropy. matplotlib's object API with the Agg canvas (no display needed)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from kgnav.common.atomic import atomic_open

    fig = Figure(figsize=(11, 4.2), layout="constrained")
    FigureCanvasAgg(fig)
    ax_a, ax_r = fig.subplots(1, 2)
    steps = np.array([c["step"] for c in curve], float)
    keys = sorted((k for k in (curve[0] if curve else {}) if k.startswith("explored_")),
                  key=lambda k: int(k.split("_")[1]))
    for n, k in enumerate(keys):
        v = np.array([c[k] for c in curve], float)
        ax_a.plot(steps, v, color=f"C{n}", alpha=0.25, lw=0.8)
        ax_a.plot(steps, _smooth(v, window), color=f"C{n}", label=f"after {k.split('_')[1]}")
    ax_a.set_xlabel("PPO iteration")
    ax_a.set_ylabel("explored area (m²), training episodes")
    ax_a.legend(loc="lower right")
    ax_a.grid(alpha=0.3)
    if curve:
        ret = np.array([c["return"] for c in curve], float)
        ax_r.plot(steps, ret, color="C0", alpha=0.25, lw=0.8)
        ax_r.plot(steps, _smooth(ret, window), color="C0", label="return")
        ax_e = ax_r.twinx()
        ax_e.plot(steps, [c["entropy"] for c in curve], color="C3", lw=1, label="entropy")
        ax_e.set_ylabel("policy entropy (nats)", color="C3")
    ax_r.set_xlabel("PPO iteration")
    ax_r.set_ylabel("mean episode return", color="C0")
    ax_r.grid(alpha=0.3)
    if title:
        fig.suptitle(title)
    path = Path(path)
    with atomic_open(path, "wb") as fh:
        fig.savefig(fh, format="png", dpi=80)
    return path


def _smooth(v: np.ndarray, window: int) -> np.ndarray:
    """Trailing moving average (shorter at the start)."""
    c = np.cumsum(np.insert(v, 0, 0.0))
    n = np.arange(1, len(v) + 1)
    lo = np.maximum(n - window, 0)
    return (c[n] - c[lo]) / (n - lo)
