"""State features ``F_s``: the :class:`FeatureExtractor` protocol, a registry, and the default
OpenCV descriptor.

An extractor maps one RGB frame (uint8, H×W×3) to a unit-norm float32 vector of ``dim``
entries; states of two models are matched by the cosine distance of these vectors (the paper's
relocation, threshold 0.3 by default). Extractors are looked up by name, like habitat-lab's
sensor registry, so a stored model's ``extractor`` attribute says how to reproduce its features:

>>> import numpy as np
>>> ext = make_extractor("opencv-gist")
>>> f = ext(np.zeros((120, 160, 3), np.uint8))
>>> f.shape, f.dtype, round(float(np.linalg.norm(f)), 5)
((512,), dtype('float32'), 1.0)
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol, runtime_checkable

import cv2
import numpy as np

from kgnav.registry import Registry


@runtime_checkable
class FeatureExtractor(Protocol):
    """What the agent needs from a state-feature extractor.

    ``name`` identifies it (recorded in every model it builds); ``dim`` is the output length;
    calling it on an RGB frame returns a float32 ``(dim,)`` vector of unit norm. It must be
    deterministic: the same frame always gives the same vector.
    """

    name: str
    dim: int

    def __call__(self, rgb: np.ndarray) -> np.ndarray: ...


#: Feature extractors by name; the learned encoder (:mod:`kgnav.nets.encoder.extractor`)
#: registers on first use, so that ``import kgnav`` does not pull in torch.
REGISTRY: Registry[Callable[..., FeatureExtractor]] = Registry(
    "feature extractor", plugins=("kgnav.nets.encoder.extractor",))
EXTRACTORS = REGISTRY.factories
register_extractor = REGISTRY.register


def make_extractor(name: str, **params) -> FeatureExtractor:
    """Build the registered extractor ``name`` (e.g. ``"opencv-gist"``)."""
    return REGISTRY.get(name)(**params)


#: The paper's relocation threshold, for extractors without a calibrated one.
DEFAULT_THRESHOLD = 0.3


def loop_threshold(extractor) -> float:
    """The relocation threshold the agent loop uses with ``extractor``: its ``loop_threshold``
    if it names one (looser: the loop also confirms and verifies matches), else its calibrated
    ``threshold``, else :data:`DEFAULT_THRESHOLD`."""
    return float(getattr(extractor, "loop_threshold",
                         getattr(extractor, "threshold", DEFAULT_THRESHOLD)))


def _unit(v: np.ndarray) -> np.ndarray:
    n = float(np.linalg.norm(v))
    if n < 1e-12:  # a blank frame: any fixed unit vector keeps the contract
        v = np.zeros_like(v)
        v[0] = 1.0
        return v
    return v / n


def _check_rgb(rgb: np.ndarray) -> np.ndarray:
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise ValueError(f"expected an RGB uint8 frame (H, W, 3), got {rgb.dtype} {rgb.shape}")
    return rgb


@register_extractor("opencv-gist")
class GistDescriptor:
    """A compact global image descriptor from OpenCV: a GIST-like layout of the frame (512-d).

    Three parts, each z-scored: a coarse colour thumbnail (Lab, 8×6 cells), oriented gradient
    energy on the same 8×6 grid (7 unsigned orientations: the edge layout), and a hue/saturation
    histogram (colour content, position-free). The vector is centred and scaled to unit norm,
    so the cosine distance of two descriptors is one minus their correlation and spreads over
    [0, 2] instead of bunching near 0 as raw non-negative histograms do.
    """

    name = "opencv-gist"
    dim = 512
    # relocation cosine-distance threshold calibrated by `kgnav relocation-bench` (val, seed 0,
    # precision >= 0.99 there; 0.947 on a held-out draw): see docs/encoder.md
    threshold = 0.1006
    GRID = (8, 6)
    ORIENTATIONS = 7
    HIST = (8, 4)

    def __call__(self, rgb: np.ndarray) -> np.ndarray:
        rgb = _check_rgb(rgb)
        gw, gh = self.GRID
        small = cv2.resize(rgb, (gw * 8, gh * 8), interpolation=cv2.INTER_AREA)
        lab = cv2.cvtColor(cv2.resize(small, self.GRID, interpolation=cv2.INTER_AREA),
                           cv2.COLOR_RGB2LAB).astype(np.float32).ravel()
        grey = cv2.cvtColor(small, cv2.COLOR_RGB2GRAY).astype(np.float32)
        mag, ang = cv2.cartToPolar(cv2.Sobel(grey, cv2.CV_32F, 1, 0),
                                   cv2.Sobel(grey, cv2.CV_32F, 0, 1))
        k = self.ORIENTATIONS
        b = (np.mod(ang, np.pi) * (k / np.pi)).astype(np.int32) % k
        # energy per (cell row, cell col, orientation) in one bincount
        rows = np.arange(gh * 8)[:, None] // 8
        cols = np.arange(gw * 8)[None, :] // 8
        idx = (rows * gw + cols) * k + b
        grad = np.bincount(idx.ravel(), mag.ravel(), gw * gh * k).astype(np.float32)
        hsv = cv2.cvtColor(small, cv2.COLOR_RGB2HSV)
        hist = cv2.calcHist([hsv], [0, 1], None, list(self.HIST), [0, 180, 0, 256]).ravel()
        v = np.concatenate([_zscore(lab), _zscore(np.sqrt(grad)), _zscore(np.sqrt(hist))])
        v -= v.mean()
        return _unit(v)


def _zscore(v: np.ndarray) -> np.ndarray:
    v = v.astype(np.float32)
    sd = float(v.std())
    return (v - v.mean()) / sd if sd > 1e-9 else v - v.mean()
