"""ObjectNav metrics exactly as the paper defines them ("Evaluation Metrics").

Per episode ``i`` (the benchmark averages them over ``N`` episodes):

* Success ``S_i``: ``stop`` called within 1 m (L2, to the closest point of a goal instance's
  footprint) of an instance of the goal class.
* SPL: ``S_i * l_i / max(p_i, l_i)``; ``l_i`` geodesic shortest path from the start to the
  success region, ``p_i`` the length of the path actually travelled.
* SoftSPL: ``(1 - d_T / d_init) * l_i / max(p_i, l_i)`` with geodesic ``d_T`` (final position to
  the success region) and ``d_init`` (start to the success region); the first factor is
  clipped at 0 (Habitat's SoftSPL) and ``d_T / d_init`` taken as 0 when ``d_init`` is 0.
* DTS: ``max(||x_i - g_i||_2 - d, 0)``, L2 from the final position to the closest goal
  instance footprint minus the success threshold ``d`` = 1 m.

>>> spl(True, 4.0, 5.0)
0.8
>>> dts(3.5)
2.5
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

SUCCESS_DISTANCE = 1.0


def success(stop_called: bool, l2_to_goal: float, threshold: float = SUCCESS_DISTANCE) -> bool:
    """True when the agent stopped within ``threshold`` metres (L2) of a goal instance."""
    return bool(stop_called) and l2_to_goal <= threshold


def spl(success_: bool, shortest: float, travelled: float) -> float:
    """``S * l / max(p, l)``; 1.0 for a successful episode whose shortest path is 0."""
    if not success_:
        return 0.0
    den = max(travelled, shortest)
    return 1.0 if den <= 0 else shortest / den


def softspl(d_final: float, d_init: float, shortest: float, travelled: float) -> float:
    """``max(1 - d_T / d_init, 0) * l / max(p, l)`` (geodesic distances)."""
    progress = 1.0 if d_init <= 0 else max(1.0 - d_final / d_init, 0.0)
    den = max(travelled, shortest)
    eff = 1.0 if den <= 0 else shortest / den
    return progress * eff


def dts(l2_to_goal: float, threshold: float = SUCCESS_DISTANCE) -> float:
    """Distance to success: ``max(||x - g||_2 - d, 0)``."""
    return max(l2_to_goal - threshold, 0.0)


def path_length(positions: Iterable[Sequence[float]]) -> float:
    """Sum of the straight segments between consecutive (x, y) positions."""
    total, prev = 0.0, None
    for p in positions:
        if prev is not None:
            total += math.hypot(p[0] - prev[0], p[1] - prev[1])
        prev = p
    return total


@dataclass(frozen=True)
class EpisodeMetrics:
    """The four metrics of one episode plus the numbers they come from."""

    success: bool
    spl: float
    softspl: float
    dts: float
    shortest_path: float  # l: geodesic start -> success region
    path_length: float  # p
    d_init: float  # geodesic start -> success region
    d_final: float  # geodesic end -> success region
    l2_final: float  # L2 end -> closest goal footprint


def episode_metrics(stop_called: bool, d_init: float, d_final: float, l2_final: float,
                    travelled: float, shortest: float | None = None) -> EpisodeMetrics:
    """All metrics of one episode from its distances (``shortest`` defaults to ``d_init``)."""
    ll = d_init if shortest is None else shortest
    ok = success(stop_called, l2_final)
    return EpisodeMetrics(ok, spl(ok, ll, travelled), softspl(d_final, d_init, ll, travelled),
                          dts(l2_final), ll, travelled, d_init, d_final, l2_final)


def mean_metrics(results: Iterable[EpisodeMetrics]) -> dict[str, float]:
    """Averages over episodes: ``{"success", "spl", "softspl", "dts", "episodes"}``."""
    rs = list(results)
    n = len(rs)
    if n == 0:
        return {"success": 0.0, "spl": 0.0, "softspl": 0.0, "dts": 0.0, "episodes": 0}
    return {
        "success": sum(r.success for r in rs) / n,
        "spl": sum(r.spl for r in rs) / n,
        "softspl": sum(r.softspl for r in rs) / n,
        "dts": sum(r.dts for r in rs) / n,
        "episodes": n,
    }
