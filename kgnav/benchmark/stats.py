"""Paired comparisons of variants: the difference of a metric on the same episodes, with a
seeded bootstrap confidence interval.

Every variant of a run meets the same episodes with the same segmenter noise, so the fair
comparison is per episode: ``d_i = metric(variant, episode i) − metric(base, episode i)``. The
interval resamples the episodes (percentile bootstrap, 95 % by default).

>>> recs = [{"variant": v, "scene": "h", "episode": i, "success": s, "spl": 0.5 * s}
...         for v, outcomes in (("ans", [0, 1, 0, 0]), ("si", [1, 1, 1, 0]))
...         for i, s in enumerate(outcomes)]
>>> d = paired_differences(recs, "ans", seed=0)["si"]["success"]
>>> d["diff"], d["pairs"], d["low"] <= d["diff"] <= d["high"]
(0.5, 4, True)
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

METRICS = ("success", "spl")


def paired_bootstrap(diffs, n_boot: int = 2000, level: float = 0.95, seed: int = 0
                     ) -> tuple[float, float]:
    """Percentile bootstrap interval of the mean of ``diffs`` (resampling them)."""
    d = np.asarray(diffs, float)
    if len(d) == 0:
        return float("nan"), float("nan")
    rng = np.random.default_rng(seed)
    means = d[rng.integers(0, len(d), size=(n_boot, len(d)))].mean(axis=1)
    a = (1.0 - level) / 2.0
    lo, hi = np.quantile(means, [a, 1.0 - a])
    return float(lo), float(hi)


def paired_differences(records: Iterable[dict], base: str = "ans", metrics=METRICS,
                       seed: int = 0, n_boot: int = 2000, level: float = 0.95
                       ) -> dict[str, dict[str, dict]]:
    """For every variant other than ``base``: per metric ``{"diff", "low", "high", "pairs"}``
    over the episodes both ran (matched by scene and episode) and that have the metric (an
    environment without its ground truth records None). Empty without ``base``."""
    by: dict[str, dict] = {}
    for r in records:
        by.setdefault(r["variant"], {})[(r.get("scene"), r.get("episode"))] = r
    if base not in by:
        return {}
    out: dict[str, dict[str, dict]] = {}
    for name, recs in by.items():
        if name == base:
            continue
        keys = sorted(recs.keys() & by[base].keys())
        out[name] = {}
        for m in metrics:
            have = [k for k in keys
                    if recs[k].get(m) is not None and by[base][k].get(m) is not None]
            d = [float(recs[k][m]) - float(by[base][k][m]) for k in have]
            lo, hi = paired_bootstrap(d, n_boot, level, seed)
            out[name][m] = {"diff": float(np.mean(d)) if d else float("nan"),
                            "low": lo, "high": hi, "pairs": len(have)}
    return out
