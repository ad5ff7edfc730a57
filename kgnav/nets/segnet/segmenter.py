"""``learned``: the agent's :class:`~kgnav.agent.noise_segmenters.Segmenter` backed by the RGB-D
network.

It reads RGB and depth only — ``semantic`` is ignored and may be None — so the agent runs in any
simulator or on a robot that has no ground-truth semantic channel. Per frame:

1. the network (:class:`~kgnav.nets.segnet.net.SegNet`) gives class logits at its input size
   (80×60 for a 160×120 frame);
2. the class map is the per-pixel argmax; a pixel's confidence its max softmax probability;
3. instances are the connected components (4-neighbour) of each class of that map; components
   smaller than ``min_pixels`` at frame resolution (20, what the state creator keeps) become
   background; a segment's score is the mean confidence of its pixels, and segments scoring
   under ``min_score`` (calibrated on train-house frames, stored with the weights) are dropped;
4. class and instance maps are resized (nearest) to the frame.

Steps 3–4 are :func:`segmentation_from_classes`, public so that any model giving class maps
plugs in the same way (:class:`ClassMapSegmenter`).

Deterministic: the same frame gives the same output (``reset`` has nothing to seed).

>>> import numpy as np
>>> seg = LearnedSegmenter()
>>> out = seg(np.zeros((120, 160, 3), np.uint8), np.full((120, 160), 2.0, np.float32))
>>> out.classes.shape, out.instances.dtype
((120, 160), dtype('int32'))
"""

from __future__ import annotations

import os

import cv2
import numpy as np
import torch

from kgnav.agent.segmentation import Segmentation, register_segmenter
from kgnav.common.classes import OBJECT_CLASSES
from kgnav.nets.encoder.extractor import resolve_device
from kgnav.nets.segnet.net import SegNet, preprocess
from kgnav.nets.segnet.weights import SegmenterWeights, load_weights

NAME = "kgnav-segnet"


class LearnedSegmenter:
    """The trained RGB-D segmentation network as a :class:`Segmenter`.

    Parameters
    ----------
    weights:
        Path of a weight file (default: ``kgnav/weights/segmenter.npz``, shipped) or loaded
        :class:`SegmenterWeights`.
    seed:
        Accepted for the ``make_segmenter(name, seed)`` signature; the network is deterministic.
    device:
        ``"cpu"`` (default: one frame at a time is fastest there), ``"cuda"`` or ``"auto"``.
    min_pixels:
        Components smaller than this (frame pixels) are dropped.
    min_score:
        Segments whose mean confidence is below this are dropped (default: the weight file's
        ``score_threshold``, calibrated on train-house frames by ``kgnav train-segmenter``;
        0 keeps every segment).
    weak_score:
        Segments scoring at least this but under ``min_score`` come back apart, as
        :attr:`Segmentation.weak`: too uncertain to act on, evidence for a memory that fuses
        many views (None: not asked for).
    threads:
        CPU threads for one frame (default 1; None: torch's setting). One small frame gains
        nothing from more, and on a busy machine two threads made a frame 15–50× slower
        (4 ms → 60–200 ms), the threads waiting on each other.
    """

    name = NAME
    needs_semantic = False  # RGB-D only: the environment need not render labels

    def __init__(self, weights: str | os.PathLike[str] | SegmenterWeights | None = None,
                 seed: int = 0, device: str = "cpu", min_pixels: int = 20,
                 min_score: float | None = None, threads: int | None = 1,
                 weak_score: float | None = None):
        w = weights if isinstance(weights, SegmenterWeights) else load_weights(weights)
        self.arch = w.arch
        self.class_names = w.classes
        self.meta = w.meta
        self.seed = int(seed)
        self.min_pixels = int(min_pixels)
        self.min_score = float(w.score_threshold if min_score is None else min_score)
        self.weak_score = None if weak_score is None else float(weak_score)
        self.device = resolve_device(device)
        self.threads = threads
        net = SegNet(w.arch, batchnorm=False)
        net.load_state_dict({k: torch.from_numpy(v) for k, v in w.params.items()})
        for p in net.parameters():
            p.requires_grad_(False)
        # channels_last: about 30 % faster for these small convolutions on one CPU core
        self.net = net.eval().to(self.device, memory_format=torch.channels_last)

    def __repr__(self) -> str:
        return f"LearnedSegmenter({self.arch.input_size[0]}x{self.arch.input_size[1]}, " \
               f"{self.device})"

    def reset(self, seed: int, scene: str = "") -> None:
        """Nothing to seed: the output depends on the frame alone."""

    def probabilities(self, rgb: np.ndarray, depth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(class map uint8 (h, w), confidence float32 (h, w)) at the network's input size."""
        x, d = preprocess(rgb, depth, self.arch)  # already channels_last (NHWC memory)
        prev = torch.get_num_threads()
        if self.threads and self.threads != prev:
            torch.set_num_threads(self.threads)
        try:
            with torch.inference_mode():
                logits = self.net(x.to(self.device), d.to(self.device))[0]
        finally:
            if self.threads and self.threads != prev:
                torch.set_num_threads(prev)
        # (h, w, C) view of the channels-last output: the per-pixel reductions run over
        # contiguous memory, faster in numpy than torch.softmax for one small frame
        lg = logits.permute(1, 2, 0).float().cpu().numpy()
        cls = lg.argmax(-1)
        conf = 1.0 / np.exp(lg - np.take_along_axis(lg, cls[..., None], -1)).sum(-1)
        return cls.astype(np.uint8), conf.astype(np.float32)

    def __call__(self, rgb: np.ndarray, depth: np.ndarray,
                 semantic: np.ndarray | None = None) -> Segmentation:
        """Segment one frame from RGB (H, W, 3) uint8 and depth (H, W) float; ``semantic`` is
        ignored."""
        H, W = _check_rgbd(rgb, depth)
        cls, conf = self.probabilities(rgb, depth)
        return segmentation_from_classes(cls, conf, (W, H), self.min_pixels, self.class_names,
                                         self.min_score, self.weak_score)


class ClassMapSegmenter:
    """Any model mapping an RGB-D frame to a class map, as a :class:`Segmenter`.

    ``model(rgb, depth)`` returns a class map (h, w) of 1-based ids into ``class_names``
    (0 = background), or a pair (class map, per-pixel confidence in [0, 1]); any (h, w): the
    maps are resized to the frame. Instances, scores and the size minimum are those of
    :func:`segmentation_from_classes`.

    >>> import numpy as np
    >>> def model(rgb, depth):                  # e.g. wrap your own network here
    ...     out = np.zeros(depth.shape, np.int32)
    ...     out[depth < 1.0] = 1                # "anything near is a chair"
    ...     return out
    >>> seg = ClassMapSegmenter(model, name="near-chairs")
    >>> depth = np.full((120, 160), 3.0, np.float32)
    >>> depth[40:80, 60:100] = 0.8
    >>> seg(np.zeros((120, 160, 3), np.uint8), depth).segments
    [Segment(id=1, cls='chair', bbox=(60, 40, 100, 80), pixels=1600, score=1.0)]
    """

    needs_semantic = False

    def __init__(self, model, name: str = "custom", class_names=OBJECT_CLASSES,
                 min_pixels: int = 20):
        self.model, self.name = model, name
        self.class_names = tuple(class_names)
        self.min_pixels = int(min_pixels)

    def reset(self, seed: int, scene: str = "") -> None:
        """Nothing to seed."""

    def __call__(self, rgb: np.ndarray, depth: np.ndarray,
                 semantic: np.ndarray | None = None) -> Segmentation:
        H, W = _check_rgbd(rgb, depth)
        out = self.model(rgb, depth)
        cls, conf = out if isinstance(out, tuple) else (out, None)
        return segmentation_from_classes(cls, conf, (W, H), self.min_pixels, self.class_names)


def segmentation_from_classes(classes: np.ndarray, confidence: np.ndarray | None = None,
                              frame_size: tuple[int, int] | None = None, min_pixels: int = 20,
                              class_names=OBJECT_CLASSES, min_score: float = 0.0,
                              weak_score: float | None = None) -> Segmentation:
    """A :class:`Segmentation` of a per-pixel class map (h, w): instances are the 4-connected
    components of each class; components under ``min_pixels`` at frame resolution become
    background; a segment's score is the mean ``confidence`` of its pixels (1.0 without one),
    and segments scoring under ``min_score`` become background too. ``frame_size`` = (W, H):
    the maps are resized (nearest) to it. ``weak_score``: the segments scoring at least this
    but under ``min_score`` come back apart, as :attr:`Segmentation.weak`."""
    cls = np.asarray(classes)
    if cls.ndim != 2 or cls.dtype.kind not in "iu" or not cls.size:
        raise ValueError(f"a class map must be a non-empty 2-D integer array, got {cls.dtype} "
                         f"{cls.shape}")
    if int(cls.min()) < 0 or int(cls.max()) > len(class_names):
        raise ValueError(f"class ids must lie in 0..{len(class_names)}, got {int(cls.min())}.."
                         f"{int(cls.max())}")
    h, w = cls.shape
    W, H = frame_size or (w, h)
    min_px = min_pixels * (h * w) / (H * W)  # the same size at the class map's scale
    inst = np.zeros((h, w), np.int32)
    seg_cls = [0]
    n = 0
    cls8 = cls.astype(np.uint8) if len(class_names) < 256 else cls
    for c in np.flatnonzero(np.bincount(cls.ravel(), minlength=2)[1:]) + 1:
        k, lab, stats, _ = cv2.connectedComponentsWithStats(
            (cls8 == c).view(np.uint8), connectivity=4, ltype=cv2.CV_32S)
        keep = np.flatnonzero(stats[1:, cv2.CC_STAT_AREA] >= min_px) + 1
        if not len(keep):
            continue
        lut = np.zeros(k, np.int32)
        lut[keep] = np.arange(n + 1, n + 1 + len(keep))
        np.add(inst, lut[lab], out=inst)  # components of distinct classes never overlap
        seg_cls += [int(c)] * len(keep)
        n += len(keep)
    scores = None
    weak = None
    if confidence is not None:
        conf = np.asarray(confidence, np.float64)
        if conf.shape != cls.shape:
            raise ValueError(f"confidence {conf.shape} and classes {cls.shape} differ in shape")
        counts = np.bincount(inst.ravel(), minlength=n + 1)
        scores = np.round(np.bincount(inst.ravel(), weights=conf.ravel(), minlength=n + 1)
                          / np.maximum(counts, 1), 4)
        low = scores[1:] < min_score
        if weak_score is not None:
            weak = _kept(inst, seg_cls, scores, low & (scores[1:] >= weak_score), (W, H),
                         class_names)
        if low.any():  # renumber the kept segments 1..m
            inst, seg_cls, scores = _renumbered(inst, seg_cls, scores, ~low)
    out = _maps(inst, seg_cls, scores, (W, H), class_names)
    if weak_score is not None:
        out.weak = weak if weak is not None else Segmentation.from_maps(
            np.zeros((H, W), np.int32), np.zeros((H, W), np.int32), None, class_names)
    return out


def _renumbered(inst, seg_cls, scores, keep):
    """The segments where ``keep`` (one flag per segment), numbered 1..m."""
    n = len(keep)
    lut = np.zeros(n + 1, np.int32)
    lut[1:][keep] = np.arange(1, int(keep.sum()) + 1)
    return (lut[inst], [0, *np.asarray(seg_cls[1:])[keep].tolist()],
            np.concatenate([[0.0], scores[1:][keep]]))


def _maps(inst, seg_cls, scores, frame_size, class_names) -> Segmentation:
    W, H = frame_size
    out_cls = np.asarray(seg_cls, np.int32)[inst]
    if inst.shape != (H, W):
        out_cls = cv2.resize(out_cls, (W, H), interpolation=cv2.INTER_NEAREST)
        inst = cv2.resize(inst, (W, H), interpolation=cv2.INTER_NEAREST)
    return Segmentation.from_maps(out_cls, inst, scores, class_names)


def _kept(inst, seg_cls, scores, keep, frame_size, class_names) -> Segmentation:
    """A segmentation of the segments where ``keep`` alone."""
    return _maps(*_renumbered(inst, seg_cls, scores, keep), frame_size, class_names)


def _check_rgbd(rgb, depth) -> tuple[int, int]:
    """Validate an RGB-D frame; returns (H, W). One-line ``ValueError`` naming the problem."""
    if not (isinstance(rgb, np.ndarray) and rgb.ndim == 3 and rgb.shape[2] == 3
            and rgb.dtype == np.uint8 and rgb.size):
        got = f"{rgb.dtype} {rgb.shape}" if isinstance(rgb, np.ndarray) else type(rgb).__name__
        raise ValueError(f"rgb must be a non-empty (H, W, 3) uint8 array, got {got}")
    H, W = rgb.shape[:2]
    if not (isinstance(depth, np.ndarray) and depth.shape == (H, W) and depth.dtype.kind == "f"):
        got = f"{depth.dtype} {depth.shape}" if isinstance(depth, np.ndarray) else \
            type(depth).__name__
        raise ValueError(f"depth must be a float ({H}, {W}) array in metres like rgb, got {got}")
    return H, W


@register_segmenter("learned", NAME)
def _learned(seed: int = 0, **params) -> LearnedSegmenter:
    return LearnedSegmenter(seed=seed, **params)
