"""The benchmark's figures (matplotlib, PNG): the paper's Figures 5, 6 and 7/8 analogues.

* :func:`success_curve`: success against episode index, moving average of window 5, one line
  per variant (Figure 5: with memory, success should climb as episodes accumulate);
* :func:`failure_bars`: failed episodes per failure class and variant (Figure 6);
* :func:`side_by_side`: top-down pictures of one episode for two variants (Figures 7 and 8).
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping

import matplotlib

matplotlib.use("Agg")  # files only, never a window
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from kgnav.benchmark.failures import FAILURE_CLASSES  # noqa: E402
from kgnav.common.atomic import atomic_open  # noqa: E402


def moving_average(values, window: int = 5) -> np.ndarray:
    """Trailing moving average; the first ``window - 1`` points average what exists so far.

    >>> moving_average([1, 0, 1, 1], 2).tolist()
    [1.0, 0.5, 0.5, 1.0]
    """
    v = np.asarray(values, float)
    c = np.cumsum(np.insert(v, 0, 0.0))
    n = np.minimum(np.arange(1, len(v) + 1), window)
    return (c[1:] - c[np.arange(1, len(v) + 1) - n]) / n


def _save(fig, path) -> None:
    with atomic_open(path, "wb") as f:
        fig.savefig(f, format="png", dpi=120, bbox_inches="tight")
    plt.close(fig)


def success_curve(records: Iterable[dict], path: str | os.PathLike, window: int = 5) -> None:
    """Success (moving average) against episode index, per variant, in run order."""
    by: dict[str, list[float]] = {}
    for r in records:
        by.setdefault(r["variant"], []).append(float(r["success"]))
    fig, ax = plt.subplots(figsize=(7, 4))
    for name, vals in by.items():
        ax.plot(np.arange(1, len(vals) + 1), moving_average(vals, window), label=name)
    ax.set_xlabel("episode (run order)")
    ax.set_ylabel(f"success (moving average, window {window})")
    ax.set_ylim(-0.02, 1.02)
    ax.grid(alpha=0.3)
    ax.legend()
    _save(fig, path)


def failure_bars(summary: Mapping[str, Mapping], path: str | os.PathLike) -> None:
    """Failed episodes per class (Last Mile, Hallucination, ...) for each variant."""
    names = [n for n in summary if n != "oracle"] or list(summary)
    x = np.arange(len(FAILURE_CLASSES))
    width = 0.8 / max(len(names), 1)
    fig, ax = plt.subplots(figsize=(8, 4))
    for k, name in enumerate(names):
        counts = [summary[name]["failures"].get(c, 0) for c in FAILURE_CLASSES]
        ax.bar(x + (k - (len(names) - 1) / 2) * width, counts, width, label=name)
    ax.set_xticks(x, FAILURE_CLASSES)
    ax.set_ylabel("failed episodes")
    ax.legend()
    ax.grid(axis="y", alpha=0.3)
    _save(fig, path)


def side_by_side(images: Mapping[str, np.ndarray], path: str | os.PathLike,
                 title: str = "") -> None:
    """RGB images next to each other, each titled with its key."""
    fig, axes = plt.subplots(1, len(images), figsize=(6 * len(images), 6), squeeze=False)
    for ax, (name, img) in zip(axes[0], images.items(), strict=True):
        ax.imshow(img)
        ax.set_title(name)
        ax.axis("off")
    if title:
        fig.suptitle(title)
    _save(fig, path)
