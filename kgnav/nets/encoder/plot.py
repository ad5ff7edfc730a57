"""The relocation benchmark's figure: ROC curves, and precision/recall against the threshold."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np


def plot_roc(results: dict[str, dict], path: str | os.PathLike[str], title: str = "") -> Path:
    """Write a PNG: left, ROC (log false-positive rate) with each extractor's operating point;
    right, precision and recall against the cosine-distance threshold.

    ``results`` maps an extractor name to :func:`kgnav.nets.encoder.calibration.evaluate`'s output.
    Uses matplotlib's object API with the Agg canvas (no pyplot state, no display needed).
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 4.5), layout="constrained")
    FigureCanvasAgg(fig)
    ax_roc, ax_thr = fig.subplots(1, 2)
    for k, (name, r) in enumerate(results.items()):
        colour = f"C{k}"
        roc = np.asarray(r["roc"], float).reshape(-1, 3)
        fpr, tpr, thr = roc[:, 0], roc[:, 1], roc[:, 2]
        ax_roc.plot(np.maximum(fpr, 1e-5), tpr, color=colour,
                    label=f"{name} (AUC {r['auc']:.3f})")
        ax_roc.plot(max(r["fpr"], 1e-5), r["recall"], "o", color=colour)
        ax_thr.plot(thr, tpr, color=colour, label=f"{name} recall")
        prec = _precision_curve(r, roc)
        ax_thr.plot(thr, prec, "--", color=colour, label=f"{name} precision")
        ax_thr.axvline(r["threshold"], color=colour, lw=0.8, alpha=0.6)
    ax_roc.set_xscale("log")
    ax_roc.set_xlim(1e-5, 1)
    ax_roc.set_ylim(0, 1.01)
    ax_roc.set_xlabel("false-positive rate (log)")
    ax_roc.set_ylabel("true-positive rate (recall)")
    ax_roc.set_title("ROC (dot: chosen threshold)")
    ax_roc.grid(alpha=0.3)
    ax_roc.legend(loc="lower right", fontsize=8)
    ax_thr.set_xlabel("cosine-distance threshold (match: distance < threshold)")
    ax_thr.set_ylim(0, 1.01)
    ax_thr.set_xlim(0, max(1.0, *(r["threshold"] * 1.5 for r in results.values())))
    ax_thr.set_title("precision and recall (vertical: chosen threshold)")
    ax_thr.grid(alpha=0.3)
    ax_thr.legend(loc="lower right", fontsize=8)
    if title:
        fig.suptitle(title)
    path = Path(path)
    fig.savefig(path, dpi=110)
    return path


def _precision_curve(r: dict, roc: np.ndarray) -> np.ndarray:
    """Precision along the ROC points, from the pair counts behind the rates."""
    n_pos = r["counts"]["positive"]
    n_neg = r["counts"]["negative"]
    tp, fp = roc[:, 1] * n_pos, roc[:, 0] * n_neg
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(tp + fp > 0, tp / (tp + fp), 1.0)
