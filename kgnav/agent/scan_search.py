"""Global scan-to-map search: where in a stored model the episode's recent walls fit best.

Feature matching proposes a relocation only where a stored *state* looks like the current view.
An episode that walks through rooms a model mapped from afar (through a doorway, across a hall)
may never stand where a stored state stood, and one whose nearest-looking stored states are
look-alike places never gets its right place offered (docs/memory.md, "Why an episode does not
relocate"). This module asks geometry instead: it slides the episode's recent obstacle points
over the stored model's occupancy at every translation and a ring of headings, scoring each
placement by how close the points land to stored obstacles (correlative scan matching, as
Olson's real-time correlative scan matching or Cartographer's global localisation do), and
returns the best distinct placements. Each is only a hypothesis: the caller verifies it like a
feature match (:meth:`kgnav.agent.relocation.Relocalizer.verify`).

The score of a placement is the mean, over the points, of a likelihood field
``exp(-d² / 2σ²)`` (``d``: distance to the nearest stored obstacle, 0 where the model knows
nothing), computed for all translations of one heading at once with
:func:`cv2.matchTemplate` on a coarse grid.

>>> import numpy as np
>>> from kgnav.memory.geometry import OccupancyGrid
>>> from kgnav.agent.relocation import StoredGeometry
>>> hits = np.zeros((60, 80), np.uint16); free = np.ones((60, 80), np.uint16)
>>> hits[5, 5:75] = hits[55, 5:75] = hits[5:56, 5] = hits[5:56, 74] = 5  # a 3.5 x 2.5 m room
>>> hits[5:30, 40] = 5  # a half wall, so that the room is not symmetric
>>> geo = StoredGeometry(OccupancyGrid(free, hits, 0.0, 0.0, 0.05))
>>> walls = np.argwhere(hits > 0)[:, ::-1] * 0.05 + 0.025  # (x, y) of the stored walls
>>> ends = walls - (1.0, 0.5)  # the same walls seen from a frame 1 m left, 0.5 m down
>>> best = search(geo, ends)[0]
>>> [round(v, 1) for v in best.transform[:2]], round(best.transform[2], 2)
([1.0, 0.5], 0.0)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from kgnav.common import se2


@dataclass(frozen=True)
class Placement:
    """A placement of the episode's points in a stored model: ``transform`` (episode → model
    frame) and ``score``, the points' mean likelihood there (0 to 1)."""

    transform: tuple[float, float, float]
    score: float


def likelihood(geo, resolution: float, sigma: float) -> tuple[np.ndarray, float, float, float]:
    """The stored model's likelihood field on a grid of ``resolution`` (m): ``exp(-d²/2σ²)``
    of the distance ``d`` to the nearest stored obstacle where the model knows the cell, 0
    elsewhere (a point landing where the model never looked neither supports nor refutes).
    Returns the field, its corner ``(x0, y0)`` and its cell size; cached on ``geo``."""
    key = (round(resolution, 6), round(sigma, 6))
    cache = geo.__dict__.setdefault("_likelihood", {})
    if key not in cache:
        g = geo.grid
        field = np.exp(-np.square(np.minimum(geo.dist, 10 * sigma)) / (2 * sigma * sigma))
        field = np.where(geo.known, field, 0.0).astype(np.float32)
        f = max(int(round(resolution / g.resolution)), 1)
        h, w = field.shape
        # block maxima, not means: a wall one fine cell thick must keep its peak when coarsened
        hp, wp = -(-h // f) * f, -(-w // f) * f
        padded = np.zeros((hp, wp), np.float32)
        padded[:h, :w] = field
        coarse = padded.reshape(hp // f, f, wp // f, f).max(axis=(1, 3))
        cache[key] = (coarse, float(g.x0), float(g.y0), f * g.resolution)
    coarse, x0, y0, res = cache[key]
    return coarse, x0, y0, res


def search(geo, ends: np.ndarray, *, resolution: float = 0.2, headings: int = 36,
           sigma: float = 0.25, peaks: int = 3, separation: float = 1.0) -> list[Placement]:
    """The best placements of the points ``ends`` (episode frame, ``(N, 2)``) in the stored
    model ``geo`` (a :class:`~kgnav.agent.relocation.StoredGeometry`), best first: for each of
    ``headings`` evenly spaced headings, the ``peaks`` best translations at least
    ``separation`` m apart. Coarse (``resolution`` m, ``360/headings``°): a verifier refines.
    Empty when the model knows no obstacle or there are no points."""
    ends = np.asarray(ends, float).reshape(-1, 2)
    if len(ends) == 0 or geo.grad_x is None:
        return []
    field, gx0, gy0, res = likelihood(geo, resolution, sigma)
    centre = ends.mean(axis=0)
    out: list[Placement] = []
    sep = max(int(math.ceil(separation / res)), 1)
    for k in range(headings):
        theta = 2 * math.pi * k / headings
        p = se2.apply_to_points((0.0, 0.0, theta), ends - centre)
        lo = p.min(axis=0)
        cells = np.rint((p - lo) / res).astype(np.int64)  # a point at its cell's centre
        tw, th = int(cells[:, 0].max()) + 1, int(cells[:, 1].max()) + 1
        tmpl = np.zeros((th, tw), np.float32)
        np.add.at(tmpl, (cells[:, 1], cells[:, 0]), 1.0)
        # pad so that every placement overlapping the model at all is scored
        img = cv2.copyMakeBorder(field, th - 1, th - 1, tw - 1, tw - 1, cv2.BORDER_CONSTANT,
                                 value=0.0)
        score = cv2.matchTemplate(img, tmpl, cv2.TM_CCORR) / len(ends)
        for _ in range(peaks):
            iy, ix = np.unravel_index(int(np.argmax(score)), score.shape)
            s = float(score[iy, ix])
            if s <= 0:
                break
            # template cell (0, 0), centred on ``lo``, lands on the centre of the model's
            # coarse cell (ix - tw + 1, iy - th + 1)
            sx = gx0 + (ix - tw + 1.5) * res - lo[0]
            sy = gy0 + (iy - th + 1.5) * res - lo[1]
            c, sn = math.cos(theta), math.sin(theta)
            rc = (c * centre[0] - sn * centre[1], sn * centre[0] + c * centre[1])
            out.append(Placement((float(sx - rc[0]), float(sy - rc[1]),
                                  float(se2.wrap_angle(theta))), s))
            score[max(iy - sep, 0):iy + sep + 1, max(ix - sep, 0):ix + sep + 1] = 0
    out.sort(key=lambda q: -q.score)
    return out


def distinct(placements: list[Placement], separation: float = 1.0,
             turn: float = math.radians(20)) -> list[Placement]:
    """``placements`` (best first) less those within ``separation`` m and ``turn`` radians of
    a better one: the alternatives that really are elsewhere."""
    kept: list[Placement] = []
    for q in placements:
        if all(math.dist(q.transform[:2], k.transform[:2]) > separation
               or se2.angle_diff(q.transform[2], k.transform[2]) > turn for k in kept):
            kept.append(q)
    return kept
