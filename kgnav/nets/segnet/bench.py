"""The segmenter benchmark: any :class:`~kgnav.agent.noise_segmenters.Segmenter` against ground
truth.

Definitions (those of ``docs/segmenter.md``, at the state creator's 20-pixel minimum):

* **pixel IoU** per class over all frames (intersection / union of the class maps); mean IoU
  over the classes present in the ground truth, and over the six goal classes;
* a ground-truth instance (≥ ``min_pixels``) is **detected** when some segment has its class
  and at least half of that segment's pixels lie on it; **recall** by the instance's median
  depth (bands 0–2, 2–3.5, 3.5–5 m) and by mask size;
* a segment (≥ ``min_pixels``) is **correct** when most of its pixels lie on instances of its
  own class; **precision** by the segment's median depth and size; the others are **false
  positives** (per frame; of them, on background and of a goal class);
* **confusion pairs**: segments whose pixels lie mostly on an object of another class (true →
  predicted, counted), and the pixel confusion matrix (``confusion.png``);
* **persistence**: for objects seen in at least 3 frames with ≥ 100 pixels, the share
  mislabelled in most of their views and in all of them (a view is *mislabelled* when at least
  30 % of the object's pixels carry an object class and the most common one is wrong): errors
  no number of views corrects;
* **time**: wall time of one segmenter call per frame (median, 90th percentile).

Class ids index a vocabulary (``classes``, default kgnav's; another environment's when its
frames are scored), and a segmenter labelling another vocabulary is mapped to it by name, its
other classes dropped (as the agent maps it). The goal classes are kgnav's six ObjectNav
classes, or every class of another environment (whose episodes may ask for any).

>>> distance_band(1.0), distance_band(3.0), distance_band(4.9), size_band(50)
('0-2 m', '2-3.5 m', '3.5-5 m', '20-100 px')
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from kgnav.common.classes import OBJECT_CLASSES, OBJECTNAV_CLASSES

DIST_BANDS = ((0.0, 2.0, "0-2 m"), (2.0, 3.5, "2-3.5 m"), (3.5, 1e9, "3.5-5 m"))
SIZE_BANDS = ((0, 100, "20-100 px"), (100, 500, "100-500 px"), (500, 10**9, ">=500 px"))


def distance_band(d: float) -> str:
    return next(name for lo, hi, name in DIST_BANDS if lo <= d < hi)


def size_band(n: int) -> str:
    return next(name for lo, hi, name in SIZE_BANDS if lo <= n < hi)


@dataclass
class Frames:
    """Benchmark frames: rgb (N, H, W, 3), depth (N, H, W), semantic (N, H, W, 2), and per
    frame the house name and pose."""

    rgb: np.ndarray
    depth: np.ndarray
    semantic: np.ndarray
    scenes: list[str]
    poses: np.ndarray

    def __len__(self) -> int:
        return len(self.rgb)


def render_frames(split: str | Sequence, n: int, seed: int = 1, object_share: float = 0.5,
                  progress: Callable[[int], None] | None = None) -> Frames:
    """``n`` frames of the houses of ``split`` (a split's name, or the scenes themselves:
    houses of your own, e.g. :class:`~kgnav.sim.scene_dir.SceneDir`'s), in turn:
    ``object_share`` of them aimed at an object (class-balanced), the rest from random poses;
    seeded."""
    from kgnav.nets.segnet.data import LabelledViews
    from kgnav.sim.episodes import load_split

    views = LabelledViews(load_split(split) if isinstance(split, str) else list(split))
    rng = np.random.default_rng([seed, 0x5E6B])
    out = [], [], [], [], []
    for k in range(n):
        h = k % len(views)
        pose = views.draw_pose(h, rng, object_share)
        for lst, v in zip(out, (*views.render_labelled(h, pose), views.scenes[h].name, pose),
                          strict=True):
            lst.append(v)
        if progress is not None:
            progress(k + 1)
    rgb, depth, sem, scenes, poses = out
    return Frames(np.stack(rgb), np.stack(depth), np.stack(sem), scenes, np.array(poses))


def walked_frames(views, n: int, seed: int = 1, object_share: float = 0.5) -> Frames:
    """``n`` frames of another environment's walked views
    (:class:`~kgnav.nets.segnet.env_data.EnvLabelledViews`), the scenes in turn after a
    shuffle: ``object_share`` of them showing an object (class-balanced), the rest any; seeded.
    """
    rgb, depth, sem, houses, poses = views.frames(np.random.default_rng([seed, 0x5E6B]), n,
                                                  object_share=object_share)
    return Frames(rgb, depth, sem, [views.views[h].name for h in houses], poses)


class Scorer:
    """Accumulates the benchmark's counts over frames for one segmenter; class ids index
    ``classes``, and ``goal_classes`` (default: all of them unless ``classes`` are kgnav's,
    whose goals are the six ObjectNav classes) are the goal classes' figures."""

    def __init__(self, min_pixels: int = 20, classes: Sequence[str] = OBJECT_CLASSES,
                 goal_classes: Sequence[str] | None = None):
        self.min_pixels = min_pixels
        self.classes = tuple(classes)
        goals = goal_classes if goal_classes is not None else default_goals(self.classes)
        self.goal = {self.classes.index(c) + 1 for c in goals if c in self.classes}
        self.n_cls = n = len(self.classes) + 1
        self.conf = np.zeros((n, n), np.int64)  # pixels: [true, predicted]
        self.gt = Counter()  # (band kind, band) -> instances
        self.hit = Counter()
        self.seg = Counter()  # (band kind, band) -> segments
        self.ok = Counter()
        self.fp = Counter()  # "all", "background", "goal"
        self.pairs = Counter()  # (true, predicted) of mislabelled segments
        self.frames = 0
        self.seconds: list[float] = []
        self.views: dict[tuple[str, int], list[bool]] = {}  # (scene, instance) -> mislabelled?

    def add(self, out, depth: np.ndarray, semantic: np.ndarray, seconds: float,
            scene: str = "") -> None:
        """Score one frame's :class:`Segmentation` against its ground truth (``scene`` names
        the house, for the persistence of errors across views)."""
        self.frames += 1
        self.seconds.append(seconds)
        N = self.n_cls
        gcls = semantic[..., 0].ravel().astype(np.int64)
        ginst = semantic[..., 1].ravel().astype(np.int64)
        pcls = out.classes.ravel().astype(np.int64)
        self.conf += np.bincount(gcls * N + pcls, minlength=N * N).reshape(N, N)
        d = depth.ravel()
        inst_cls = {}
        gsize = np.bincount(ginst)
        for i in np.flatnonzero(gsize[1:] >= self.min_pixels) + 1:
            inst_cls[int(i)] = int(gcls[np.argmax(ginst == i)])
        hit = set()
        pinst = out.instances.ravel()
        for s in out.segments:
            if s.pixels < self.min_pixels:
                continue
            m = pinst == s.id
            c = self.classes.index(s.cls) + 1
            under = ginst[m]
            ids, cnt = np.unique(under, return_counts=True)
            own = sum(int(n) for i, n in zip(ids, cnt, strict=True)
                      if i and int(gcls[np.argmax(ginst == i)]) == c)
            correct = own * 2 > s.pixels
            md = float(np.median(d[m]))
            for key in (("dist", distance_band(md)), ("size", size_band(s.pixels))):
                self.seg[key] += 1
                self.ok[key] += correct
            for i, n in zip(ids.tolist(), cnt.tolist(), strict=True):
                if i in inst_cls and inst_cls[i] == c and n * 2 >= s.pixels:
                    hit.add(i)
            if not correct:
                self.fp["all"] += 1
                self.fp["goal"] += c in self.goal
                main = int(ids[np.argmax(cnt)])
                if main == 0:
                    self.fp["background"] += 1
                else:
                    self.pairs[(self.classes[inst_cls.get(main, int(
                        gcls[np.argmax(ginst == main)])) - 1], s.cls)] += 1
        for i, c in inst_cls.items():
            m = ginst == i
            if gsize[i] >= 100:
                lab = np.bincount(pcls[m], minlength=N)
                lab[0] = 0
                if lab.sum() >= 0.3 * gsize[i]:
                    self.views.setdefault((scene, i), []).append(int(np.argmax(lab)) != c)
                else:
                    self.views.setdefault((scene, i), []).append(False)
            md = float(np.median(d[m]))
            for key in (("dist", distance_band(md)), ("size", size_band(int(gsize[i])))):
                self.gt[key] += 1
                self.hit[key] += i in hit
            self.gt[("all", "all")] += 1
            self.hit[("all", "all")] += i in hit
            if c in self.goal:
                self.gt[("goal", "goal")] += 1
                self.hit[("goal", "goal")] += i in hit

    def report(self) -> dict:
        """The figures as a JSON-able dict."""
        inter = np.diag(self.conf).astype(float)
        union = self.conf.sum(0) + self.conf.sum(1) - np.diag(self.conf)
        present = self.conf.sum(1) > 0
        iou = {self.classes[c - 1]: round(inter[c] / union[c], 4)
               for c in range(1, self.n_cls) if present[c]}
        goal_iou = [iou[self.classes[c - 1]] for c in sorted(self.goal)
                    if self.classes[c - 1] in iou]

        def ratio(a: Counter, b: Counter, kind: str) -> dict:
            return {k[1]: {"value": round(a[k] / b[k], 4) if b[k] else None, "n": b[k]}
                    for k in sorted(b, key=_band_order) if k[0] == kind}

        segs = sum(v for k, v in self.seg.items() if k[0] == "dist")
        multi = [v for v in self.views.values() if len(v) >= 3]
        secs = np.array(self.seconds) * 1e3
        return {
            "frames": self.frames,
            "mean_iou": round(float(np.mean(list(iou.values()))), 4) if iou else None,
            "mean_iou_goal": round(float(np.mean(goal_iou)), 4) if goal_iou else None,
            "background_iou": round(inter[0] / union[0], 4) if union[0] else None,
            "iou": iou,
            "recall": self.hit[("all", "all")] / max(self.gt[("all", "all")], 1),
            "recall_goal": self.hit[("goal", "goal")] / max(self.gt[("goal", "goal")], 1),
            "instances": self.gt[("all", "all")],
            "precision": (segs - self.fp["all"]) / max(segs, 1),
            "recall_by_distance": ratio(self.hit, self.gt, "dist"),
            "recall_by_size": ratio(self.hit, self.gt, "size"),
            "precision_by_distance": ratio(self.ok, self.seg, "dist"),
            "precision_by_size": ratio(self.ok, self.seg, "size"),
            "segments_per_frame": segs / max(self.frames, 1),
            "fp_per_frame": self.fp["all"] / max(self.frames, 1),
            "fp_background_per_frame": self.fp["background"] / max(self.frames, 1),
            "fp_goal_per_frame": self.fp["goal"] / max(self.frames, 1),
            "persistence": {
                "objects": len(multi),
                "views": sum(len(v) for v in multi),
                "mislabelled_views": round(sum(sum(v) for v in multi)
                                           / max(sum(len(v) for v in multi), 1), 4),
                "mislabelled_in_most_views": round(
                    sum(sum(v) * 2 > len(v) for v in multi) / max(len(multi), 1), 4),
                "mislabelled_in_all_views": round(
                    sum(all(v) for v in multi) / max(len(multi), 1), 4)},
            "confusion_pairs": [[t, p, n] for (t, p), n in self.pairs.most_common(15)],
            "pixel_confusions": pixel_confusions(self.conf, classes=self.classes),
            "ms_per_frame": {"median": round(float(np.median(secs)), 3) if len(secs) else None,
                             "p90": round(float(np.percentile(secs, 90)), 3) if len(secs)
                             else None},
        }


def _band_order(key: tuple[str, str]) -> int:
    names = [b[2] for b in DIST_BANDS] + [b[2] for b in SIZE_BANDS]
    return names.index(key[1]) if key[1] in names else -1


def default_goals(classes: Sequence[str]) -> tuple[str, ...]:
    """The goal classes of a vocabulary: kgnav's six ObjectNav classes for kgnav's, every class
    of another (an environment declares no goal subset; MiniWorld's episodes ask for any)."""
    return OBJECTNAV_CLASSES if tuple(classes) == OBJECT_CLASSES else tuple(classes)


def pixel_confusions(conf: np.ndarray, top: int = 10,
                     classes: Sequence[str] = OBJECT_CLASSES) -> list[list]:
    """The largest off-diagonal object→object pixel confusions: [true, predicted, share of the
    true class's pixels]."""
    share = conf / np.maximum(conf.sum(1, keepdims=True), 1)
    out = []
    n = len(classes) + 1
    for t in range(1, n):
        for p in range(1, n):
            if t != p and conf[t, p]:
                out.append([classes[t - 1], classes[p - 1], round(float(share[t, p]), 4)])
    return sorted(out, key=lambda r: -r[2])[:top]


def score(segmenter, frames: Frames, min_pixels: int = 20,
          progress: Callable[[int], None] | None = None,
          classes: Sequence[str] = OBJECT_CLASSES) -> Scorer:
    """Run ``segmenter`` on every frame (reset per frame: seed = frame index, scene = house);
    the frames' class ids index ``classes``, to which the segmenter's output is mapped."""
    from kgnav.agent.loop import _relabel, _vocabulary_map

    sc = Scorer(min_pixels, classes)
    table = _vocabulary_map(segmenter, sc.classes)  # one-line error: no class in common
    for k in range(len(frames)):
        segmenter.reset(k, frames.scenes[k])
        rgb, depth, sem = frames.rgb[k], frames.depth[k], frames.semantic[k]
        t = time.perf_counter()
        out = segmenter(rgb, depth, sem)
        if table is not None:
            out = _relabel(out, table, sc.classes)
        sc.add(out, depth, sem, time.perf_counter() - t, frames.scenes[k])
        if progress is not None:
            progress(k + 1)
    return sc


def plot_confusion(confs: dict[str, np.ndarray], path, title: str = "",
                   classes: Sequence[str] = OBJECT_CLASSES) -> None:
    """Row-normalised pixel confusion matrices side by side (one panel per segmenter)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from kgnav.common.atomic import atomic_open

    names = ["background", *classes]
    n = len(names)
    fig, axes = plt.subplots(1, len(confs), figsize=(7.5 * len(confs), 7), squeeze=False)
    for ax, (label, conf) in zip(axes[0], confs.items(), strict=True):
        share = conf / np.maximum(conf.sum(1, keepdims=True), 1)
        im = ax.imshow(share, cmap="viridis", vmin=0, vmax=1)
        ax.set_xticks(range(n), names, rotation=90, fontsize=7)
        ax.set_yticks(range(n), names, fontsize=7)
        ax.set_xlabel("predicted")
        ax.set_ylabel("true")
        ax.set_title(label)
        fig.colorbar(im, ax=ax, fraction=0.046, pad=0.04, label="share of the true class")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    with atomic_open(path, "wb") as fh:
        fig.savefig(fh, format="png", dpi=110)
    plt.close(fig)


def bench(segmenters: Sequence[tuple[str, object]], frames: Frames, min_pixels: int = 20,
          progress: Callable[[str, int], None] | None = None,
          classes: Sequence[str] = OBJECT_CLASSES) -> dict[str, Scorer]:
    """Score each ``(label, segmenter)`` on the same frames (class ids into ``classes``)."""
    out = {}
    for label, seg in segmenters:
        out[label] = score(seg, frames, min_pixels,
                           None if progress is None else (lambda k, lb=label: progress(lb, k)),
                           classes)
    return out


#: score thresholds tried by :func:`calibrate_min_score`
SCORE_GRID = tuple(round(0.05 * i, 2) for i in range(19))


def calibrate_min_score(segmenter, frames: Frames, grid: Sequence[float] = SCORE_GRID,
                        min_pixels: int = 20) -> tuple[float, list[dict]]:
    """The segment-score threshold of ``grid`` with the best F1 of instance recall and segment
    precision on ``frames`` (frames of train houses: tune on train), and the whole curve
    ``[{"threshold", "recall", "precision", "f1", "fp_per_frame"}]``."""
    from kgnav.nets.segnet.segmenter import segmentation_from_classes

    maps = [segmenter.probabilities(frames.rgb[k], frames.depth[k]) for k in range(len(frames))]
    curve = []
    for t in grid:
        sc = Scorer(min_pixels, segmenter.class_names)
        for k, (cls, conf) in enumerate(maps):
            depth = frames.depth[k]
            out = segmentation_from_classes(cls, conf, depth.shape[::-1], min_pixels,
                                            segmenter.class_names, t)
            sc.add(out, depth, frames.semantic[k], 0.0)
        r = sc.report()
        f1 = 2 * r["recall"] * r["precision"] / max(r["recall"] + r["precision"], 1e-9)
        curve.append({"threshold": t, "recall": round(r["recall"], 4),
                      "precision": round(r["precision"], 4), "f1": round(f1, 4),
                      "fp_per_frame": round(r["fp_per_frame"], 4)})
    best = max(curve, key=lambda c: (c["f1"], -c["threshold"]))
    return best["threshold"], curve
