"""The agent's knowledge-extraction segmenter: RGB-D frame -> per-pixel class and instance masks.

A real ObjectNav agent runs a learned segmenter (RedNet in the paper) whose mistakes cause most
failures: stopping at a false positive ("Detection"), storing a wrong object in a model
("Hallucination"), or never seeing the goal ("Exploration"). :class:`NoisySegmenter` takes the
simulator's ground-truth semantic frame and passes it through a seeded noise model
(:class:`SegmenterNoise`) that makes those mistakes:

1. **misses**: each visible instance is dropped with a probability that grows with its median
   depth and for small masks; a few instances per scene are *hard* and missed most of the time;
2. **class confusion**: per-frame flips to a plausibly confusable class (:data:`CONFUSIONS`),
   likelier far away and on small masks, plus *persistent* confusions: some instances are
   labelled as one other class in most frames of every episode, as a network does on a
   particular object;
3. **false positives**: a Poisson number of elliptical blobs per frame, mostly of the six
   ObjectNav goal classes, on vertical surfaces (walls, furniture fronts) at a size plausible
   for their depth; plus persistent *phantoms*: some instances carry a second, wrong-class segment
   on a fixed part of them whenever they are seen, so a hallucinated goal comes back to the same
   place across frames and episodes;
4. **mask degradation**: far and small masks are eroded, dilated into the background, or cut.

Per-frame noise is drawn from ``(seed, reset seed, frame counter)``; persistent effects from a
stable hash of ``(seed, scene, instance id)``, so they survive across episodes in a house.

>>> import numpy as np
>>> seg = make_segmenter("clean")
>>> seg.reset(seed=0, scene="demo")
>>> sem = np.zeros((120, 160, 2), np.int32)
>>> sem[40:80, 50:90] = (1, 7)  # class 1 = chair, ground-truth instance 7
>>> out = seg(np.zeros((120, 160, 3), np.uint8), np.full((120, 160), 2.0, np.float32), sem)
>>> out.segments
[Segment(id=1, cls='chair', bbox=(50, 40, 90, 80), pixels=1600, score=1.0)]
>>> noisy = make_segmenter("default", seed=3)
>>> noisy.name
'gt-noisy'
"""

from __future__ import annotations

import bisect
import functools
import math
import zlib
from collections.abc import Sequence
from dataclasses import dataclass, fields

import cv2
import numpy as np

from kgnav.agent.segmentation import (
    RunStats,
    Segmentation,
    make_segmenter,
    median_depth,
    register_segmenter,
    relabel_ids,
    run_stats,
    segments_from_runs,
)
from kgnav.common.classes import OBJECT_CLASSES, OBJECTNAV_CLASSES
from kgnav.errors import KgnavError

__all__ = [
    "CONFUSIONS",
    "GROUND_TRUTH_SEGMENTERS",
    "SEGMENTER_PRESETS",
    "NoisySegmenter",
    "SegmenterNoise",
    "make_segmenter",
]


# ---------------------------------------------------------------------------------- noise model
#: Plausible confusions: true class -> ((wrong class, relative weight), ...). Every class has at
#: least one entry and never itself; goal classes appear often as targets because those are the
#: mistakes that matter for ObjectNav.
CONFUSIONS: dict[str, tuple[tuple[str, float], ...]] = {
    "chair": (("stool", 0.4), ("sofa", 0.3), ("table", 0.15), ("desk", 0.15)),
    "bed": (("sofa", 0.7), ("table", 0.15), ("chest_of_drawers", 0.15)),
    "plant": (("lamp", 0.6), ("chair", 0.25), ("stool", 0.15)),
    "toilet": (("sink", 0.45), ("bathtub", 0.25), ("chair", 0.2), ("washing_machine", 0.1)),
    "tv_monitor": (("fireplace", 0.35), ("cabinet", 0.25), ("bookshelf", 0.2), ("desk", 0.2)),
    "sofa": (("chair", 0.45), ("bed", 0.4), ("stool", 0.15)),
    "table": (("desk", 0.45), ("counter", 0.25), ("nightstand", 0.15), ("chair", 0.15)),
    "sink": (("counter", 0.35), ("toilet", 0.3), ("bathtub", 0.2), ("stove", 0.15)),
    "bathtub": (("shower", 0.45), ("toilet", 0.25), ("sink", 0.2), ("bed", 0.1)),
    "shower": (("bathtub", 0.6), ("wardrobe", 0.2), ("cabinet", 0.2)),
    "cabinet": (("chest_of_drawers", 0.35), ("wardrobe", 0.25), ("nightstand", 0.2),
                ("counter", 0.2)),
    "chest_of_drawers": (("cabinet", 0.4), ("nightstand", 0.3), ("wardrobe", 0.15),
                         ("desk", 0.15)),
    "wardrobe": (("cabinet", 0.45), ("bookshelf", 0.25), ("fridge", 0.15),
                 ("chest_of_drawers", 0.15)),
    "desk": (("table", 0.6), ("counter", 0.2), ("chest_of_drawers", 0.1), ("cabinet", 0.1)),
    "bookshelf": (("cabinet", 0.5), ("wardrobe", 0.35), ("tv_monitor", 0.15)),
    "fridge": (("wardrobe", 0.4), ("cabinet", 0.3), ("washing_machine", 0.3)),
    "stove": (("counter", 0.45), ("washing_machine", 0.25), ("sink", 0.2), ("cabinet", 0.1)),
    "counter": (("table", 0.3), ("cabinet", 0.3), ("desk", 0.2), ("sink", 0.2)),
    "fireplace": (("tv_monitor", 0.45), ("cabinet", 0.3), ("stove", 0.25)),
    "nightstand": (("chest_of_drawers", 0.4), ("cabinet", 0.3), ("table", 0.2), ("stool", 0.1)),
    "lamp": (("plant", 0.65), ("stool", 0.2), ("nightstand", 0.15)),
    "washing_machine": (("stove", 0.3), ("cabinet", 0.3), ("fridge", 0.25), ("toilet", 0.15)),
    "piano": (("desk", 0.35), ("table", 0.25), ("cabinet", 0.2), ("sofa", 0.2)),
    "stool": (("chair", 0.6), ("table", 0.2), ("nightstand", 0.2)),
}

# physical half-extent (m, width and height) of a false-positive blob per class
_BLOB_HALF_SIZE: dict[str, tuple[float, float]] = {
    "chair": (0.25, 0.45), "bed": (0.9, 0.3), "plant": (0.25, 0.4), "toilet": (0.2, 0.35),
    "tv_monitor": (0.45, 0.28), "sofa": (0.9, 0.4),
}


@dataclass(frozen=True)
class SegmenterNoise:
    """Rates of the ground-truth segmenter's noise model; all zero (except scales) = clean.

    Probabilities are per visible ground-truth instance per frame unless said otherwise.
    ``far`` is the 0..1 distance factor ``clip((median depth - near) / (far - near))`` and
    ``small`` the small-mask factor ``exp(-pixels / (small_area * H * W))``.
    """

    #: m: depth below which distance adds no noise.
    near: float = 1.0
    #: m: depth at which the distance factor saturates (the depth sensor's range).
    far: float = 5.0
    #: mask area, as a fraction of the frame, at which the small factor is 1/e.
    small_area: float = 0.004
    #: miss probability: base, + ``miss_far * far``, + ``miss_small * small``.
    miss: float = 0.03
    miss_far: float = 0.30
    miss_small: float = 0.45
    #: fraction of instances that are persistently hard, and their miss probability.
    hard_fraction: float = 0.05
    hard_miss: float = 0.85
    #: per-frame flip to a class of :data:`CONFUSIONS`: base + ``_far * far`` + ``_small * small``.
    confusion: float = 0.02
    confusion_far: float = 0.12
    confusion_small: float = 0.08
    #: fraction of instances persistently labelled as one confusable class, and the share of
    #: frames in which that wrong label shows (otherwise the per-frame model applies).
    persistent_confusion: float = 0.05
    persistent_consistency: float = 0.85
    #: Poisson mean of false-positive blobs per frame, and the share of them of a goal class.
    fp_rate: float = 0.08
    fp_goal_share: float = 0.75
    #: fraction of instances carrying a persistent phantom (wrong-class segment on part of
    #: them), and the probability it shows when the instance is visible (>= 40 pixels).
    phantom_fraction: float = 0.03
    phantom_rate: float = 0.7
    #: probability that a kept mask is eroded, dilated or cut: base + ``degrade_far * far``.
    degrade: float = 0.05
    degrade_far: float = 0.35
    #: standard deviation of the Gaussian noise on detection scores.
    score_noise: float = 0.05

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v >= 0):
                raise ValueError(f"SegmenterNoise.{f.name} must be a finite number >= 0, got {v!r}")
            if f.name not in ("near", "far", "small_area", "fp_rate") and v > 1:
                raise ValueError(f"SegmenterNoise.{f.name} is a probability, got {v!r}")
        if not self.far > self.near:
            raise ValueError(f"SegmenterNoise.far ({self.far}) must exceed near ({self.near})")
        if self.small_area <= 0:
            raise ValueError("SegmenterNoise.small_area must be > 0")

    @property
    def is_clean(self) -> bool:
        """True when no effect is enabled: the output is the ground truth."""
        scales = ("near", "far", "small_area", "persistent_consistency", "fp_goal_share",
                  "phantom_rate", "score_noise")
        return all(getattr(self, f.name) == 0 for f in fields(self) if f.name not in scales)


_ZERO = dict.fromkeys(
    ("miss", "miss_far", "miss_small", "hard_fraction", "hard_miss", "confusion",
     "confusion_far", "confusion_small", "persistent_confusion", "fp_rate", "phantom_fraction",
     "degrade", "degrade_far"), 0.0)

#: Named noise settings: ``clean`` (exact ground truth), ``default`` (realistic), ``heavy``.
SEGMENTER_PRESETS: dict[str, SegmenterNoise] = {
    "clean": SegmenterNoise(**_ZERO, score_noise=0.0),
    "default": SegmenterNoise(),
    "heavy": SegmenterNoise(
        miss=0.06, miss_far=0.45, miss_small=0.55, hard_fraction=0.10, confusion=0.05,
        confusion_far=0.25, confusion_small=0.15, persistent_confusion=0.12, fp_rate=0.25,
        phantom_fraction=0.06, degrade=0.1, degrade_far=0.5, score_noise=0.08,
    ),
}
_PRESET_NAMES = {"clean": "gt-clean", "default": "gt-noisy", "heavy": "gt-heavy"}

#: The segmenters (names and reported names) built on the simulator's ground-truth semantic
#: frame; they take the environment's camera and vocabulary (``hfov_deg``, ``min_depth``,
#: ``max_depth``, ``classes``).
GROUND_TRUTH_SEGMENTERS = (*SEGMENTER_PRESETS, *_PRESET_NAMES.values())


def _confusion_lists(classes: Sequence[str]) -> list[tuple[list[float], list[int]]]:
    """Per class id: cumulative probabilities and ids of its confusions (row 0 unused). A
    class :data:`CONFUSIONS` does not know, or whose confusions are all outside the
    vocabulary, is confused with any other class of the vocabulary alike."""
    out = []
    for name in (classes[0], *classes):
        row = [(t, p) for t, p in CONFUSIONS.get(name, ()) if t in classes]
        row = row or [(t, 1.0) for t in classes if t != name] or [(name, 1.0)]
        w = np.array([p for _, p in row], float)
        cdf = np.cumsum(w / w.sum()).tolist()
        cdf[-1] = 1.0  # exact: a uniform in [0, 1) always picks an entry
        out.append((cdf, [classes.index(t) + 1 for t, _ in row]))
    return out


def _confuse1(table, c: int, u: float) -> int:
    """A confusable class of class id ``c`` picked by the uniform ``u`` in [0, 1)."""
    cdf, ids = table[c]
    return ids[min(bisect.bisect_right(cdf, u), len(ids) - 1)]


def _stable_seed(*parts: int | str) -> list[int]:
    """Entropy for ``SeedSequence`` from ints and strings (never Python's salted ``hash``)."""
    return [zlib.crc32(p.encode()) if isinstance(p, str) else int(p) % (1 << 64) for p in parts]


# ---------------------------------------------------------------------------------- segmenter
_K3 = np.ones((3, 3), np.uint8)
_TABLE_BLOCK = 1024  # instance ids per block of the persistent-effect table
_PHANTOM_MIN_PIXELS = 40


class NoisySegmenter:
    """Ground-truth segmentation passed through :class:`SegmenterNoise` (see the module doc).

    ``noise`` is a :class:`SegmenterNoise` or a preset name; ``seed`` seeds the noise model (the
    persistent per-object errors depend on it and the scene, not on the episode).
    ``hfov_deg``, ``min_depth`` and ``max_depth`` describe the camera: they size the
    false-positive blobs and tell valid depth from clipped depth. ``classes``: the vocabulary
    the semantic frame's class ids index (an environment's; default kgnav's); confusions and
    false positives stay within it.
    """

    needs_semantic = True  # it is the ground truth, made noisy

    def __init__(
        self,
        noise: SegmenterNoise | str = "default",
        seed: int = 0,
        *,
        hfov_deg: float = 79.0,
        min_depth: float = 0.5,
        max_depth: float = 5.0,
        classes: Sequence[str] = OBJECT_CLASSES,
    ):
        if isinstance(noise, str):
            if noise not in SEGMENTER_PRESETS:
                raise KgnavError(f"unknown segmenter noise preset {noise!r} "
                                 f"(known: {', '.join(SEGMENTER_PRESETS)})")
            noise = SEGMENTER_PRESETS[noise]
        if not isinstance(noise, SegmenterNoise):
            raise ValueError(f"noise must be a SegmenterNoise or a preset name, got {noise!r}")
        self.noise = noise
        self.seed = int(seed)
        preset = next((k for k, v in SEGMENTER_PRESETS.items() if v == noise), None)
        self.name = _PRESET_NAMES[preset] if preset else "gt-noisy-custom"
        self._clean = noise.is_clean
        self.tan_half_fov = math.tan(math.radians(hfov_deg) / 2)
        self.min_depth, self.max_depth = float(min_depth), float(max_depth)
        self.classes = tuple(classes)
        if not self.classes:
            raise ValueError("classes must not be empty")
        n = len(self.classes)
        self._conf = _confusion_lists(self.classes)
        # false-positive class distribution: the goal classes share fp_goal_share
        goal_ids = np.array([self.classes.index(c) + 1 for c in OBJECTNAV_CLASSES
                             if c in self.classes], np.int32)
        if 0 < len(goal_ids) < n:
            p = np.full(n, (1 - noise.fp_goal_share) / (n - len(goal_ids)))
            p[goal_ids - 1] = noise.fp_goal_share / len(goal_ids)
        else:  # no goal classes (or nothing else) in this vocabulary: all alike
            p = np.full(n, 1.0 / n)
        cdf = np.cumsum(p / p.sum())
        cdf[-1] = 1.0
        self._fp_cdf = cdf.tolist()
        self._bitgen = np.random.PCG64()
        self._rng = np.random.Generator(self._bitgen)
        self.scene = None
        self.reset(0, "")

    def __repr__(self) -> str:
        return f"NoisySegmenter({self.name!r}, seed={self.seed})"

    # ------------------------------------------------------------------ episode
    def reset(self, seed: int, scene: str = "") -> None:
        """Start an episode: per-frame noise comes from ``(self.seed, seed, frame counter)``;
        ``scene`` names the house and selects the persistent per-object errors."""
        self.episode_seed = int(seed)
        self._bitgen.state = np.random.PCG64(
            np.random.SeedSequence(_stable_seed(self.seed, seed, 0x5E6))).state
        self._base_state = self._bitgen.state
        self.frame = 0
        if self.scene != str(scene):
            self.scene = str(scene)
            self._table: dict[int, np.ndarray] = {}

    def _persistent(self, ids: list[int]) -> list[list[float]]:
        """8 uniforms per instance, fixed by (seed, scene, instance id): persistent effects."""
        out = []
        for i in ids:
            b, r = divmod(i, _TABLE_BLOCK)
            t = self._table.get(b)
            if t is None:
                rng = np.random.default_rng(_stable_seed(self.seed, self.scene, 0x7AB1E, b))
                t = self._table[b] = rng.random((_TABLE_BLOCK, 8))
            out.append(t[r])
        return np.array(out).tolist() if out else []

    # ------------------------------------------------------------------ frame
    def __call__(
        self, rgb: np.ndarray, depth: np.ndarray, semantic: np.ndarray | None = None
    ) -> Segmentation:
        """Segment one frame (``semantic`` = the simulator's ground truth, required)."""
        H, W = _check_inputs(rgb, depth, semantic)
        inst = np.ascontiguousarray(semantic[..., 1], np.int32)
        frame = self.frame
        self.frame += 1
        gt = run_stats(inst)
        # an instance takes the class of its first pixel; one on class-0 pixels is no object
        gt_cls = semantic.reshape(-1, 2)[gt.first, 0].tolist()
        if gt_cls and max(gt_cls) > len(self.classes):
            raise ValueError(f"semantic class id {max(gt_cls)} out of range "
                             f"(1..{len(self.classes)})")
        med = None if self._clean else median_depth(gt, np.ascontiguousarray(depth).ravel())
        if 0 in gt_cls:
            sel = np.array(gt_cls) > 0
            gt = RunStats(gt.ids[sel], gt.counts[sel], gt.u0[sel], gt.v0[sel], gt.u1[sel],
                           gt.v1[sel], gt.first[sel], gt.top, gt.r_start, gt.r_len,
                           gt.g_start[sel])
            gt_cls = [c for c in gt_cls if c]
            med = None if med is None else med[sel]
        if self._clean:
            k = len(gt_cls)
            return self._compose(inst, depth, gt, list(range(k)), gt_cls, [1.0] * k, [], [])
        self._bitgen.state = self._base_state
        self._bitgen.advance(frame << 64)  # a disjoint substream per frame
        return self._noisy(inst, semantic, depth, gt, gt_cls, med, H, W)

    def _noisy(self, inst, semantic, depth, gt: RunStats, gt_cls: list[int], med, H, W):
        nz, rng = self.noise, self._rng
        k = len(gt_cls)
        counts = gt.counts.tolist()
        per = self._persistent(gt.ids.tolist())
        uu = rng.random((k, 8)).tolist()
        normal = rng.standard_normal(k).tolist()
        inv = 1.0 / (nz.far - nz.near)
        area = nz.small_area * H * W
        kept: list[int] = []
        labels: list[int] = []
        scores: list[float] = []
        ops: list[tuple[int, float]] = []
        extra: list[tuple[np.ndarray, tuple[int, int], int, float]] = []
        for j, (d, n, c, p, u, g) in enumerate(
                zip(med.tolist(), counts, gt_cls, per, uu, normal, strict=True)):
            far = min(max((d - nz.near) * inv, 0.0), 1.0) if d == d else 1.0  # NaN: far
            small = math.exp(-n / area)
            # 3b. a persistent phantom shows on part of the instance, detected or not
            if p[3] < nz.phantom_fraction and n >= _PHANTOM_MIN_PIXELS and u[6] < nz.phantom_rate:
                m = self._phantom_mask(inst, gt, j, p)
                if m is not None:
                    extra.append((*m, self._fp_class(p[7], c), 0.4 + 0.45 * u[7]))
            # 1. misses: hard instances, distance, small masks
            p_miss = nz.hard_miss if p[0] < nz.hard_fraction else (
                nz.miss + nz.miss_far * far + nz.miss_small * small)
            if u[0] < min(p_miss, 0.98):
                continue
            # 2. label: a persistent confusion (shown in most frames), else per-frame flips
            if p[1] < nz.persistent_confusion and u[1] < nz.persistent_consistency:
                lab = _confuse1(self._conf, c, p[2])
            elif u[2] < nz.confusion + nz.confusion_far * far + nz.confusion_small * small:
                lab = _confuse1(self._conf, c, u[3])
            else:
                lab = c
            s = 0.97 - 0.3 * far - 0.25 * small - 0.15 * (lab != c) + nz.score_noise * g
            kept.append(j)
            labels.append(lab)
            scores.append(round(min(max(s, 0.05), 1.0), 4))
            # 4. mask degradation, likelier far away
            if u[4] < nz.degrade + nz.degrade_far * far:
                ops.append((len(kept), u[5]))
        # 3a. false-positive blobs
        for _ in range(int(rng.poisson(nz.fp_rate)) if nz.fp_rate > 0 else 0):
            b = self._blob(semantic, depth, H, W, rng)
            if b is not None:
                extra.append(b)
        return self._compose(inst, depth, gt, kept, labels, scores, ops, extra)

    def _compose(self, inst, depth, gt: RunStats, kept: list[int], labels: list[int],
                 scores: list[float], ops, extra) -> Segmentation:
        """The output maps: kept instances get ids 1..m (ascending ground-truth id), then the
        degradations and the extra (phantom, blob) segments are painted in."""
        m = len(kept)
        kept_ids = gt.ids[kept]
        inst8 = inst.astype(np.uint8) if gt.top < 256 else None
        instances = relabel_ids(inst, kept_ids, range(1, m + 1), gt.top, inst8)
        seg_cls = [0, *labels]
        seg_score = [0.0, *scores]
        for sid, uk in ops:
            j = kept[sid - 1]
            _degrade(instances, (int(gt.u0[j]), int(gt.v0[j]), int(gt.u1[j]), int(gt.v1[j])),
                     sid, uk)
        for mask, (v0, u0), c, s in extra:
            h, w = mask.shape
            instances[v0 : v0 + h, u0 : u0 + w][mask] = len(seg_cls)
            seg_cls.append(c)
            seg_score.append(round(s, 4))
        if ops or extra:  # masks changed: recount from the output map
            n_seg = len(seg_cls)
            classes = relabel_ids(instances, range(n_seg), seg_cls, n_seg - 1,
                               instances.astype(np.uint8) if n_seg < 256 else None)
            st = run_stats(instances)
        else:  # unchanged masks: the ground truth's statistics hold
            classes = relabel_ids(inst, kept_ids, labels, gt.top, inst8)
            st = RunStats(np.arange(1, m + 1), gt.counts[kept], gt.u0[kept], gt.v0[kept],
                           gt.u1[kept], gt.v1[kept], gt.first[kept], m, gt.r_start, gt.r_len,
                           gt.g_start[kept])
        ids = st.ids.tolist()
        return Segmentation(classes, instances, segments_from_runs(st, [seg_cls[i] for i in ids],
                                                          [seg_score[i] for i in ids],
                                                          self.classes))

    # ------------------------------------------------------------------ effects
    def _fp_class(self, u: float, not_cls: int = 0) -> int:
        """A false-positive class (goal-weighted); a confusion of ``not_cls`` if it matches."""
        c = min(bisect.bisect_right(self._fp_cdf, u), len(self.classes) - 1) + 1
        return _confuse1(self._conf, c, u) if c == not_cls else c

    @staticmethod
    def _phantom_mask(inst, gt: RunStats, j: int, p: list[float]):
        """An ellipse at a fixed relative place of the instance's box, on its pixels."""
        u0, v0, u1, v1 = (int(a[j]) for a in (gt.u0, gt.v0, gt.u1, gt.v1))
        bw, bh = u1 - u0, v1 - v0
        m = np.zeros((bh, bw), np.uint8)
        r = 0.25 + 0.2 * p[6]
        cv2.ellipse(m, (int((0.25 + 0.5 * p[4]) * bw), int((0.25 + 0.5 * p[5]) * bh)),
                    (max(1, int(r * bw)), max(1, int(r * bh))), 0, 0, 360, 1, -1)
        mask = (inst[v0:v1, u0:u1] == gt.ids[j]) & m.view(bool)
        if np.count_nonzero(mask) < 8:
            return None
        return mask, (v0, u0)

    def _blob(self, semantic, depth, H, W, rng):
        """A false-positive ellipse on a vertical surface (wall or furniture face), or None.

        A vertical plane has the same z-depth down a pixel column while floor and ceiling do
        not, so comparing depth two rows above and below the centre keeps blobs off them.
        """
        n_try = 8
        vs = rng.integers(2, max(3, H - 2), n_try)
        us = rng.integers(0, W, n_try)
        size_u, cls_u, score_u = rng.random(3).tolist()
        d = depth[vs, us].astype(np.float64)
        up = depth[np.maximum(vs - 2, 0), us]
        dn = depth[np.minimum(vs + 2, H - 1), us]
        ok = ((d > self.min_depth + 1e-3) & (d < self.max_depth - 1e-3)
              & (np.abs(up - dn) <= 0.01 * d + 0.01))
        if not ok.any():
            return None
        i = int(np.argmax(ok))
        v, u, d0 = int(vs[i]), int(us[i]), float(d[i])
        c = self._fp_class(cls_u, int(semantic[v, u, 0]))  # never the true class there
        hw, hh = _BLOB_HALF_SIZE.get(self.classes[c - 1], (0.35, 0.35))
        f = (W / 2) / self.tan_half_fov / d0 * (0.4 + 0.6 * size_u)  # pixels per metre
        ru = int(min(max(2, hw * f), W // 4))
        rv = int(min(max(2, hh * f), H // 4))
        a0, a1 = max(0, u - ru), min(W, u + ru + 1)
        b0, b1 = max(0, v - rv), min(H, v + rv + 1)
        m = np.zeros((b1 - b0, a1 - a0), np.uint8)
        cv2.ellipse(m, (u - a0, v - b0), (ru, rv), 0, 0, 360, 1, -1)
        # a real mask follows the surface it sits on: keep pixels near the centre's depth
        mask = m.view(bool) & (np.abs(depth[b0:b1, a0:a1] - d0) <= 0.15 * d0 + 0.05)
        return mask, (b0, a0), c, 0.3 + 0.5 * score_u


def _degrade(instances: np.ndarray, box: tuple[int, int, int, int], sid: int, uk: float) -> None:
    """Erode, dilate (into background only) or cut segment ``sid`` within ``box`` + 1 px."""
    H, W = instances.shape
    u0, v0, u1, v1 = box
    crop = instances[max(0, v0 - 1) : min(H, v1 + 1), max(0, u0 - 1) : min(W, u1 + 1)]
    mask = crop == sid
    if uk < 0.45:
        keep = cv2.erode(mask.view(np.uint8), _K3, borderType=cv2.BORDER_REPLICATE)
        crop[mask & ~keep.view(bool)] = 0
    elif uk < 0.7:
        grown = cv2.dilate(mask.view(np.uint8), _K3).view(bool)
        crop[grown & (crop == 0)] = sid
    else:  # cut: lose 30-60 % of the box from one side
        f = 0.3 + (uk - 0.7)
        h, w = mask.shape
        side = int(uk * 1000) % 4
        cut = np.zeros_like(mask)
        if side == 0:
            cut[: int(f * h)] = True
        elif side == 1:
            cut[h - int(f * h) :] = True
        elif side == 2:
            cut[:, : int(f * w)] = True
        else:
            cut[:, w - int(f * w) :] = True
        crop[mask & cut] = 0


def _check_inputs(rgb, depth, semantic) -> tuple[int, int]:
    """Validate one frame; returns (H, W). One-line ``ValueError`` naming the problem."""
    if not isinstance(rgb, np.ndarray) or rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"rgb must be an (H, W, 3) array, got {_desc(rgb)}")
    if rgb.dtype != np.uint8:
        raise ValueError(f"rgb must be uint8, got {rgb.dtype}")
    H, W = rgb.shape[:2]
    if not isinstance(depth, np.ndarray) or depth.shape != (H, W):
        raise ValueError(f"depth must be an ({H}, {W}) array like rgb, got {_desc(depth)}")
    if depth.dtype.kind != "f":
        raise ValueError(f"depth must be a float array (metres), got {depth.dtype}")
    if semantic is None:
        raise ValueError("the ground-truth segmenter needs the semantic frame (got None)")
    if not isinstance(semantic, np.ndarray) or semantic.shape != (H, W, 2):
        raise ValueError(f"semantic must be an ({H}, {W}, 2) array, got {_desc(semantic)}")
    if semantic.dtype.kind not in "iu":
        raise ValueError(f"semantic must be an integer array, got {semantic.dtype}")
    if H == 0 or W == 0:
        raise ValueError(f"empty frame ({H}x{W})")
    if semantic.dtype.kind == "i" and int(semantic.min()) < 0:
        raise ValueError("semantic ids must be >= 0")
    if semantic.dtype.itemsize > 4 - (semantic.dtype.kind == "u") and int(
            semantic[..., 1].max()) >= 2**31:
        raise ValueError("semantic instance ids must be < 2**31")
    return H, W


def _desc(a: object) -> str:
    return f"{a.dtype} {a.shape}" if isinstance(a, np.ndarray) else type(a).__name__


for _key in SEGMENTER_PRESETS:
    register_segmenter(_key)(functools.partial(NoisySegmenter, _key))
for _key, _reported in _PRESET_NAMES.items():  # the names the segmenters report, after
    register_segmenter(_reported)(functools.partial(NoisySegmenter, _key))
