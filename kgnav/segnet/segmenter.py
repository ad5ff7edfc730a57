"""``learned``: the agent's :class:`~kgnav.agent.segmenter.Segmenter` backed by the RGB-D network.

It reads RGB and depth only — ``semantic`` is ignored and may be None — so the agent runs in any
simulator or on a robot that has no ground-truth semantic channel. Per frame:

1. the network (:class:`~kgnav.segnet.net.SegNet`) gives class logits at its input size
   (80×60 for a 160×120 frame);
2. the class map is the per-pixel argmax; a pixel's confidence its max softmax probability;
3. instances are the connected components (4-neighbour) of each class of that map; components
   smaller than ``min_pixels`` at frame resolution (20, what the state creator keeps) become
   background; a segment's score is the mean confidence of its pixels;
4. class and instance maps are resized (nearest) to the frame.

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

from kgnav.agent.segmenter import Segmentation, register_segmenter
from kgnav.encoder.extractor import resolve_device
from kgnav.segnet.net import SegNet, preprocess
from kgnav.segnet.weights import SegmenterWeights, load_weights

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
    """

    name = NAME

    def __init__(self, weights: str | os.PathLike[str] | SegmenterWeights | None = None,
                 seed: int = 0, device: str = "cpu", min_pixels: int = 20):
        w = weights if isinstance(weights, SegmenterWeights) else load_weights(weights)
        self.arch = w.arch
        self.class_names = w.classes
        self.meta = w.meta
        self.seed = int(seed)
        self.min_pixels = int(min_pixels)
        self.device = resolve_device(device)
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
        x, d = preprocess(rgb, depth, self.arch)
        with torch.inference_mode():
            logits = self.net(x.to(self.device, memory_format=torch.channels_last),
                              d.to(self.device, memory_format=torch.channels_last))[0]
            conf, cls = torch.softmax(logits, 0).max(0)
        return cls.to(torch.uint8).cpu().numpy(), conf.float().cpu().numpy()

    def __call__(self, rgb: np.ndarray, depth: np.ndarray,
                 semantic: np.ndarray | None = None) -> Segmentation:
        """Segment one frame from RGB (H, W, 3) uint8 and depth (H, W) float; ``semantic`` is
        ignored."""
        H, W = _check_rgbd(rgb, depth)
        cls, conf = self.probabilities(rgb, depth)
        h, w = cls.shape
        min_px = self.min_pixels * (h * w) / (H * W)  # the same size at the network's scale
        inst = np.zeros((h, w), np.int32)
        seg_cls = [0]
        n = 0
        for c in np.flatnonzero(np.bincount(cls.ravel(), minlength=2)[1:]) + 1:
            k, lab, stats, _ = cv2.connectedComponentsWithStats(
                (cls == c).view(np.uint8), connectivity=4, ltype=cv2.CV_32S)
            keep = np.flatnonzero(stats[1:, cv2.CC_STAT_AREA] >= min_px) + 1
            if not len(keep):
                continue
            lut = np.zeros(k, np.int32)
            lut[keep] = np.arange(n + 1, n + 1 + len(keep))
            np.add(inst, lut[lab], out=inst)  # components of distinct classes never overlap
            seg_cls += [int(c)] * len(keep)
            n += len(keep)
        counts = np.bincount(inst.ravel(), minlength=n + 1)
        scores = np.bincount(inst.ravel(), weights=conf.ravel(), minlength=n + 1) / np.maximum(
            counts, 1)
        classes = np.asarray(seg_cls, np.int32)[inst]
        if (w, h) != (W, H):
            classes = cv2.resize(classes, (W, H), interpolation=cv2.INTER_NEAREST)
            inst = cv2.resize(inst, (W, H), interpolation=cv2.INTER_NEAREST)
        return Segmentation.from_maps(classes, inst, np.round(scores, 4), self.class_names)


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
