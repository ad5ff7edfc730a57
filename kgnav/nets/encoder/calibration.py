"""The relocation benchmark: do two views match exactly when they show the same place?

**Views.** ``n_pos`` places are spread round-robin over the houses of a split (``val``: never
seen in training). Each place is seen three times: the anchor ``A`` (uniform over the navigable
floor, any heading), ``B`` within 0.5 m and 30° of it, and a near miss ``C`` of the same house:
moved 1–2 m keeping the heading, or turned more than 90° on the spot (half each).

**Pairs** (definitions in :mod:`kgnav.nets.encoder.views`), per place ``i``:

* ``positive``: (A_i, B_i);
* ``same-house near``: (A_i, C_i);
* ``same-house``: (A_i, B_j), j another place of the same house that is a negative for i;
* ``other-house``: (A_i, B_j) for ``other_random`` random places j of other houses;
* ``other-house look-alike``: (A_i, B_j) for the ``lookalike`` places j of other houses whose
  depth profile (median depth of 16 column bands) is closest to A_i's — views of the same
  geometry, e.g. both facing a wall at 40 cm, which is where house colours and textures alone
  must tell the houses apart. Chosen from geometry only, so the pair set is the same for every
  extractor.

A pair *matches* when the cosine distance of the two feature vectors is below the threshold.
Precision and recall are over these pairs (by default six negatives per positive: one near
miss, one same-house, two random and two look-alike other-house pairs); the threshold is
**calibrated** as the largest one at which precision is at least ``target_precision`` (0.99).
The ROC is over the same pairs.

**Retrieval**, the agent's situation: every A view queries the store of all B and C views of all
houses, as the relocator does; its nearest stored view is accepted when closer than the
threshold, and correct when it is not a negative for the query (same house, within 1 m, 90°).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from kgnav.nets.encoder.views import (
    NEG_DIST,
    NEG_TURN,
    NEGATIVE,
    POS_DIST,
    POS_TURN,
    ViewSampler,
    relation_matrix,
    relations,
)

KINDS = ("positive", "same-house near", "same-house", "other-house", "other-house look-alike")
TARGET_PRECISION = 0.99
CALIBRATION_SEED = 0  # the draw of val views the shipped threshold is calibrated on


@dataclass
class PairSet:
    """Rendered views and labelled pairs of them. Views are indexed ``3 i + (0, 1, 2)`` for the
    A, B, C views of place ``i``."""

    houses: np.ndarray  # (V,) house index per view
    poses: np.ndarray  # (V, 3)
    pairs: np.ndarray  # (P, 2) view indices
    kinds: np.ndarray  # (P,) index into KINDS
    features: dict[str, np.ndarray] = field(default_factory=dict)  # extractor → (V, dim)
    ms_per_frame: dict[str, float] = field(default_factory=dict)
    scene_names: list[str] = field(default_factory=list)

    @property
    def labels(self) -> np.ndarray:
        return (self.kinds == 0).astype(np.int8)

    @property
    def n_places(self) -> int:
        return len(self.houses) // 3

    def counts(self) -> dict[str, int]:
        return {k: int((self.kinds == i).sum()) for i, k in enumerate(KINDS)}


def _depth_profile(depth: np.ndarray, bands: int = 16) -> np.ndarray:
    w = depth.shape[1] // bands * bands
    cols = depth[:, :w].reshape(depth.shape[0], bands, -1)
    return np.log(np.median(cols, axis=(0, 2)))


def build_pairs(sampler: ViewSampler, extractors: Sequence, n_pos: int = 1000, seed: int = 1,
                other_random: int = 2, lookalike: int = 2, chunk: int = 256,
                progress: Callable[[int, int], None] | None = None) -> PairSet:
    """Render the views of ``n_pos`` places, embed them with every extractor, pair them.

    Frames are not kept: each chunk is embedded by every extractor (``batch`` when it has one)
    as soon as it is rendered. ``progress(done, total)`` counts views.
    """
    if n_pos < 1 or len(sampler) < 2:
        raise ValueError("need at least one place and two houses")
    rng = np.random.default_rng([seed, 7])
    houses = np.arange(n_pos) % len(sampler)
    poses = []
    for h in houses:
        h = int(h)
        a = sampler.random_pose(h, rng)
        b = sampler.pose_near(h, a, rng) or sampler.pose_near(h, a, rng, dist=(0.0, 0.0))
        c = None
        if rng.random() < 0.5:
            c = sampler.pose_near(h, a, rng, dist=(NEG_DIST + 0.05, 2 * NEG_DIST),
                                  turn=(0.0, POS_TURN))
        c = c or sampler.pose_near(h, a, rng, dist=(0.0, POS_DIST),
                                   turn=(NEG_TURN + 0.05, math.pi))
        c = c or sampler.pose_near(h, a, rng, dist=(0.0, 0.0), turn=(NEG_TURN + 0.05, math.pi))
        # views walked through an environment may have no turned view at that spot: a view
        # farther off; failing that A itself, whose near-miss pair is then dropped below
        c = c or sampler.pose_near(h, a, rng, dist=(NEG_DIST + 0.05, 4 * NEG_DIST),
                                   turn=(0.0, math.pi)) or a
        poses += [a, b, c]
    v_houses = np.repeat(houses, 3)
    v_poses = np.array(poses, float)
    n_views = len(v_poses)
    feats = {e.name: np.zeros((n_views, e.dim), np.float32) for e in extractors}
    spent = dict.fromkeys(feats, 0.0)
    profiles = np.zeros((n_views, 16))
    for start in range(0, n_views, chunk):
        idx = range(start, min(start + chunk, n_views))
        frames = []
        for v in idx:
            rgb, depth = sampler.render_depth(int(v_houses[v]), tuple(v_poses[v]))
            frames.append(rgb)
            profiles[v] = _depth_profile(depth)
        frames = np.stack(frames)
        for e in extractors:
            t = time.perf_counter()
            if hasattr(e, "batch"):
                feats[e.name][idx.start:idx.stop] = e.batch(frames)
            else:
                feats[e.name][idx.start:idx.stop] = np.stack([e(f) for f in frames])
            spent[e.name] += time.perf_counter() - t
        if progress is not None:
            progress(idx.stop, n_views)

    rel = relation_matrix(v_houses[0::3], v_poses[0::3], v_houses[1::3], v_poses[1::3])
    pairs, kinds = [], []
    place = np.arange(n_pos)
    for i in place:
        pairs += [(3 * i, 3 * i + 1), (3 * i, 3 * i + 2)]
        kinds += [0, 1]
        same = place[(houses == houses[i]) & (rel[i] == NEGATIVE)]
        if len(same):
            pairs.append((3 * i, 3 * int(rng.choice(same)) + 1))
            kinds.append(2)
        other = place[houses != houses[i]]
        for j in rng.choice(other, size=min(other_random, len(other)), replace=False):
            pairs.append((3 * i, 3 * int(j) + 1))
            kinds.append(3)
        d = np.abs(profiles[3 * other + 1] - profiles[3 * i]).sum(axis=1)
        for j in other[np.argsort(d, kind="stable")[:lookalike]]:
            pairs.append((3 * i, 3 * int(j) + 1))
            kinds.append(4)
    # a pair drawn as a negative must really be one (e.g. a C view that came out too close)
    pairs_a = np.array(pairs, int)
    kinds_a = np.array(kinds, np.int8)
    a, b = pairs_a[:, 0], pairs_a[:, 1]
    r = relations(v_houses[a], v_poses[a], v_houses[b], v_poses[b])
    ok = (kinds_a == 0) | (r == NEGATIVE)
    names = [s.name for s in sampler.scenes]
    return PairSet(v_houses, v_poses, pairs_a[ok], kinds_a[ok], feats,
                   {k: 1000 * v / n_views for k, v in spent.items()}, names)


# ---------------------------------------------------------------------- metrics
def pair_distances(features: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """Cosine distance of each pair of unit feature rows."""
    a, b = features[pairs[:, 0]], features[pairs[:, 1]]
    return 1.0 - np.einsum("ij,ij->i", a, b, dtype=np.float64)


def _cuts(dist: np.ndarray, labels: np.ndarray):
    """Cumulative (tp, fp, threshold) at every cut between distinct sorted distances.

    Entry k: matches are the pairs with distance < threshold[k] (cut after the k-th distinct
    value, halfway to the next one); entry 0 is "no match".
    """
    order = np.argsort(dist, kind="stable")
    d, y = dist[order], labels[order].astype(np.int64)
    last = np.flatnonzero(np.r_[d[1:] != d[:-1], True])  # last index of each distinct value
    tp = np.r_[0, np.cumsum(y)[last]]
    fp = np.r_[0, np.cumsum(1 - y)[last]]
    nxt = np.r_[d[last[1:]], d[-1] + 1e-6] if len(d) else np.zeros(0)
    thr = np.r_[d[0] / 2 if len(d) else 0.0, (d[last] + nxt) / 2]
    return tp, fp, thr


def calibrate(dist: np.ndarray, labels: np.ndarray,
              target_precision: float = TARGET_PRECISION) -> float:
    """The largest threshold at which precision over the pairs is ≥ ``target_precision``.

    >>> calibrate(np.array([0.1, 0.2, 0.3, 0.4]), np.array([1, 1, 0, 1]), 0.99)
    0.25
    """
    tp, fp, thr = _cuts(dist, labels)
    with np.errstate(invalid="ignore", divide="ignore"):
        prec = tp / (tp + fp)
    ok = np.flatnonzero((tp > 0) & (prec >= target_precision))
    return float(thr[ok[-1]]) if len(ok) else float(thr[0])


def at_threshold(dist: np.ndarray, labels: np.ndarray, threshold: float) -> dict:
    """Precision, recall and false-positive rate of "match = distance < threshold"."""
    m = dist < threshold
    pos = labels == 1
    tp, fp = int((m & pos).sum()), int((m & ~pos).sum())
    return {
        "precision": tp / (tp + fp) if tp + fp else 1.0,
        "recall": tp / max(int(pos.sum()), 1),
        "fpr": fp / max(int((~pos).sum()), 1),
        "matches": tp + fp,
    }


def roc_points(dist: np.ndarray, labels: np.ndarray, max_points: int = 200) -> list[list[float]]:
    """ROC as [fpr, tpr, threshold] rows (match = distance < threshold), thinned to about
    ``max_points`` rows spread evenly along the curve's length."""
    tp, fp, thr = _cuts(dist, labels)
    p, n = max(int(labels.sum()), 1), max(int((labels == 0).sum()), 1)
    fpr, tpr = fp / n, tp / p
    arc = np.r_[0, np.cumsum(np.hypot(np.diff(fpr), np.diff(tpr)))]
    keep = np.unique(np.r_[np.searchsorted(arc, np.linspace(0, arc[-1], max_points)),
                           len(arc) - 1])
    keep = keep[keep < len(arc)]
    return [[round(float(fpr[k]), 6), round(float(tpr[k]), 6), round(float(thr[k]), 6)]
            for k in keep]


def retrieval(ps: PairSet, name: str, threshold: float) -> dict:
    """Nearest-neighbour relocation of every A view among all B and C views."""
    f = ps.features[name]
    q = np.arange(0, len(f), 3)
    store = np.sort(np.r_[q + 1, q + 2])
    sims = f[q] @ f[store].T
    nn = np.argmax(sims, axis=1)
    dist = 1.0 - sims[np.arange(len(q)), nn]
    j = store[nn]
    rel = relations(ps.houses[q], ps.poses[q], ps.houses[j], ps.poses[j])
    correct = rel != NEGATIVE
    acc = dist < threshold
    n_acc = int(acc.sum())
    return {
        "queries": len(q),
        "store": len(store),
        "accepted": n_acc,
        "precision": float((acc & correct).sum() / n_acc) if n_acc else 1.0,
        "recall": float((acc & correct).sum() / len(q)),
        "nearest_correct": float(correct.mean()),
        "wrong_house": int((acc & (ps.houses[q] != ps.houses[j])).sum()),
    }


def evaluate(ps: PairSet, name: str, threshold: float | None = None,
             threshold_source: str = "", target_precision: float = TARGET_PRECISION) -> dict:
    """Every number of the benchmark for one extractor of ``ps``.

    ``threshold`` is the one to report at (e.g. the extractor's stored default); when None, the
    threshold calibrated on these pairs is used.
    """
    from sklearn.metrics import roc_auc_score

    dist = pair_distances(ps.features[name], ps.pairs)
    labels = ps.labels
    cal = calibrate(dist, labels, target_precision)
    if threshold is None:
        threshold, threshold_source = cal, f"calibrated on these pairs (precision >= " \
                                           f"{target_precision})"
    res = {"threshold": round(float(threshold), 6), "threshold_source": threshold_source}
    res.update(at_threshold(dist, labels, threshold))
    res["counts"] = {"positive": int(labels.sum()), "negative": int((labels == 0).sum())}
    res["auc"] = float(roc_auc_score(labels, -dist))
    res["calibrated_threshold"] = round(cal, 6)
    res["calibrated"] = at_threshold(dist, labels, cal)
    # the whole trade-off in four numbers: the best recall at a few precision levels
    res["recall_at_precision"] = {
        str(p): at_threshold(dist, labels, calibrate(dist, labels, p))["recall"]
        for p in (0.9, 0.95, 0.98, 0.99)}
    res["fpr_by_kind"] = {k: float((dist[ps.kinds == i] < threshold).mean())
                          for i, k in enumerate(KINDS) if i and (ps.kinds == i).any()}
    res["retrieval"] = retrieval(ps, name, threshold)
    res["ms_per_frame_batched"] = round(ps.ms_per_frame.get(name, math.nan), 4)
    res["roc"] = roc_points(dist, labels)
    return res
