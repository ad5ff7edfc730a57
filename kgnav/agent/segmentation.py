"""What the agent's knowledge extraction gets from a segmenter, and segmenters by name.

A segmenter turns an RGB-D frame into per-pixel class and instance maps (:class:`Segmentation`,
its :class:`Segment` list). :func:`make_segmenter` builds one by name: the ground-truth noise
presets of :mod:`kgnav.agent.noise_segmenters` (``clean``, ``default``, ``heavy``) or the learned
RGB-D network of :mod:`kgnav.nets.segnet` (``learned``), each module imported only when a name it
registers is asked for (the ground-truth segmenters do not pull in torch).

>>> seg = make_segmenter("clean")
>>> seg.name
'gt-clean'
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import cv2
import numpy as np

from kgnav.common.classes import OBJECT_CLASSES
from kgnav.registry import Registry

__all__ = [
    "SEGMENTERS",
    "Segment",
    "Segmentation",
    "Segmenter",
    "make_segmenter",
    "register_segmenter",
]


# ---------------------------------------------------------------------------------- results
@dataclass(frozen=True)
class Segment:
    """One segment of a frame: its id in :attr:`Segmentation.instances`, class and extent.

    ``bbox`` is ``(u0, v0, u1, v1)`` with ``u`` the column, ``v`` the row, maxima exclusive.
    """

    id: int
    cls: str
    bbox: tuple[int, int, int, int]
    pixels: int
    score: float


@dataclass
class Segmentation:
    """A segmenter's output for one frame.

    ``classes`` (int32, H×W) holds 1-based class ids (0 = background); ``instances`` (int32,
    H×W) segment ids (0 = none), every pixel of a segment having the same class. Segment ids are
    per frame: they do not follow an object from one frame to the next. ``segments`` lists one
    :class:`Segment` per id present, ordered by id.
    """

    classes: np.ndarray
    instances: np.ndarray
    segments: list[Segment]
    #: segments below the segmenter's detection threshold (its own maps), when it was asked
    #: for them: nothing to act on, but views a memory fuses (see ``AgentConfig.weak_views``)
    weak: Segmentation | None = field(default=None, repr=False, compare=False)

    @classmethod
    def from_maps(
        cls,
        classes: np.ndarray,
        instances: np.ndarray,
        scores: Mapping[int, float] | Sequence[float] | np.ndarray | None = None,
        class_names: Sequence[str] = OBJECT_CLASSES,
    ) -> Segmentation:
        """Build the segment list of two maps (bbox and pixel count from one run-length pass).

        ``scores`` gives each segment's confidence by id (a mapping, or a sequence indexed by
        id); missing ones are 1.0. Raises ``ValueError`` when the maps differ in shape, are not
        2-D integer arrays, hold negative or unknown ids, or a segment spans several classes.
        """
        classes = np.asarray(classes)
        instances = np.asarray(instances)
        for nm, a in (("classes", classes), ("instances", instances)):
            if a.ndim != 2 or a.dtype.kind not in "iu":
                raise ValueError(f"{nm} must be a 2-D integer array, got {a.dtype} {a.shape}")
        if classes.shape != instances.shape:
            raise ValueError(
                f"classes {classes.shape} and instances {instances.shape} differ in shape")
        if instances.size and (int(instances.min()) < 0 or int(classes.min()) < 0):
            raise ValueError("classes and instances must be >= 0")
        if classes.size and int(classes.max()) > len(class_names):
            raise ValueError(
                f"class id {int(classes.max())} out of range (vocabulary of {len(class_names)})")
        if instances.size and int(instances.max()) >= 2**31:
            raise ValueError("instance ids must be < 2**31")
        classes = np.ascontiguousarray(classes, np.int32)
        instances = np.ascontiguousarray(instances, np.int32)
        if not instances.size:
            return cls(classes, instances, [])
        st = run_stats(instances)
        seg_cls = classes.ravel()[st.first]
        fg = instances > 0
        map8 = instances.astype(np.uint8) if st.top < 256 else None
        if np.any(relabel_ids(instances, st.ids, seg_cls, st.top, map8)[fg] != classes[fg]):
            raise ValueError("a segment spans pixels of several classes")
        if np.any(seg_cls == 0):
            raise ValueError("a segment lies on background pixels (class 0)")
        if scores is None:
            sc = [1.0] * len(st.ids)
        elif isinstance(scores, Mapping):
            sc = [float(scores.get(i, 1.0)) for i in st.ids.tolist()]
        else:
            arr = np.asarray(scores, np.float64)
            sc = [float(arr[i]) if i < len(arr) else 1.0 for i in st.ids.tolist()]
        return cls(classes, instances, segments_from_runs(st, seg_cls.tolist(), sc, class_names))

    def mask(self, seg_id: int) -> np.ndarray:
        """Boolean (H, W) mask of one segment."""
        return self.instances == seg_id

    def of_class(self, name: str) -> list[Segment]:
        """The segments labelled ``name``."""
        return [s for s in self.segments if s.cls == name]


@runtime_checkable
class Segmenter(Protocol):
    """What the agent needs from a segmenter.

    ``reset(seed, scene)`` starts an episode: it seeds the per-frame noise, and ``scene`` names
    the house so that per-object errors persist across its episodes. Calling it on a frame
    returns a :class:`Segmentation`; ``semantic`` (the simulator's ground truth) is needed only
    by segmenters built on it. The same seeds, scene and frames give the same output. A
    segmenter may name the vocabulary its class ids index (``classes`` or ``class_names``);
    the agent then maps it to the environment's by name (default: kgnav's classes).
    ``needs_semantic = False`` says it reads RGB-D only, so the benchmark need not ask the
    environment for the semantic frame (rendering it is not free everywhere); a segmenter that
    does not say is given it.
    """

    name: str

    def reset(self, seed: int, scene: str = "") -> None: ...

    def __call__(
        self, rgb: np.ndarray, depth: np.ndarray, semantic: np.ndarray | None = None
    ) -> Segmentation: ...


# ---------------------------------------------------------------------------------- run stats
@dataclass
class RunStats:
    """Per-id statistics of an id map from its horizontal runs (ids ascending, 0 excluded)."""

    ids: np.ndarray  # (k,) ids present
    counts: np.ndarray  # pixels
    u0: np.ndarray
    v0: np.ndarray
    u1: np.ndarray
    v1: np.ndarray
    first: np.ndarray  # flat index of the first pixel (row-major)
    top: int  # the largest id in the map (0 if none)
    # the foreground runs, grouped by id, raster order within each group
    r_start: np.ndarray
    r_len: np.ndarray
    g_start: np.ndarray  # index of each id's first run


def run_stats(inst: np.ndarray) -> RunStats:
    """Pixel counts, bounding boxes and first pixels of every id of a contiguous int32 map.

    One comparison pass finds the row-wise runs; everything else works on the (few hundred)
    runs, which is much faster than ``np.bincount``/``np.unique`` over all pixels.
    """
    H, W = inst.shape
    flat = inst.ravel()
    n = flat.size
    brk = np.empty(n + 1, bool)
    brk[0] = brk[n] = True
    np.not_equal(flat[1:], flat[:-1], out=brk[1:n])
    brk[W:n:W] = True  # a run never crosses a row end
    edges = np.flatnonzero(brk)  # run starts, then n
    vals = flat[edges[:-1]]
    order = np.argsort(vals, kind="stable")  # stable: raster order kept within an id
    vals = vals[order]
    top = int(vals[-1])
    order = order[int(np.searchsorted(vals, 1)):]  # background runs sort first: drop them
    vals = vals[len(vals) - len(order):]
    starts = edges[order]
    lens = edges[order + 1] - starts
    new = np.empty(len(vals), bool)
    if len(vals):
        new[0] = True
    np.not_equal(vals[1:], vals[:-1], out=new[1:])
    g_start = np.flatnonzero(new)
    rows = starts // W
    c0 = starts - rows * W
    if len(g_start):
        g_last = np.empty_like(g_start)
        g_last[:-1] = g_start[1:] - 1
        g_last[-1] = len(vals) - 1
        counts = np.add.reduceat(lens, g_start)
        u0 = np.minimum.reduceat(c0, g_start)
        u1 = np.maximum.reduceat(c0 + lens, g_start)
        v1 = rows[g_last] + 1
    else:
        counts = u0 = u1 = v1 = g_start
    return RunStats(vals[g_start], counts, u0, rows[g_start], u1, v1, starts[g_start], top,
                     starts, lens, g_start)


def median_depth(st: RunStats, depth_flat: np.ndarray) -> np.ndarray:
    """Per-id median depth: the length-weighted median of the runs' middle-pixel depths.

    A run lies on one planar face, where depth is monotonic along it, so its middle pixel is
    its exact median; weighting runs by length gives the instance's median to within a run.
    """
    if not len(st.ids):
        return np.zeros(0)
    d = depth_flat[st.r_start + (st.r_len - 1) // 2].astype(np.float64)
    grp = np.zeros(len(d))
    grp[st.g_start[1:]] = 1e6  # group index * 1e6 + depth sorts by group, then depth
    o = np.argsort(np.cumsum(grp) + d)
    cw = np.cumsum(st.r_len[o])
    before = np.cumsum(st.counts) - st.counts  # pixels of all earlier ids
    pos = np.searchsorted(cw, before + (st.counts + 1) // 2)
    return d[o[pos]]


def segments_from_runs(st: RunStats, cls_ids: list[int], scores: list[float],
              class_names: Sequence[str] = OBJECT_CLASSES) -> list[Segment]:
    return [
        Segment(i, class_names[c - 1], (a, b, e, f), n, s)
        for i, c, a, b, e, f, n, s in zip(
            st.ids.tolist(), cls_ids, st.u0.tolist(), st.v0.tolist(), st.u1.tolist(),
            st.v1.tolist(), st.counts.tolist(), scores, strict=True)
    ]


def relabel_ids(ids_map: np.ndarray, ids: Sequence[int], new: Sequence[int], top: int,
             map8: np.ndarray | None = None) -> np.ndarray:
    """Map ``ids`` (ascending) of an id map whose largest id is ``top`` to ``new``, every other
    id to 0; returns an int32 copy. ``map8`` is ``ids_map`` as uint8, given when ``top`` < 256.
    """
    if map8 is not None and (not len(new) or max(new) < 256):
        lut8 = np.zeros(256, np.uint8)  # cv2.LUT is ~3x faster than np.take on uint8
        lut8[ids] = new
        return cv2.LUT(map8, lut8).astype(np.int32)
    if top < (1 << 16) or top < 4 * ids_map.size:  # small ids: one table lookup per pixel
        lut = np.zeros(top + 1, np.int32)
        lut[ids] = new
        return np.take(lut, ids_map)
    ids = np.asarray(ids, np.int64)
    if not len(ids):
        return np.zeros(ids_map.shape, np.int32)
    pos = np.minimum(np.searchsorted(ids, ids_map), len(ids) - 1)
    return np.where(ids[pos] == ids_map, np.asarray(new, np.int32)[pos], 0).astype(np.int32)


#: Segmenters by name, ``factory(seed=..., **params)``: the noise presets (and the names they
#: report), then ``learned`` / ``kgnav-segnet`` (the RGB-D network).
REGISTRY: Registry[Callable[..., Segmenter]] = Registry(
    "segmenter", plugins=("kgnav.agent.noise_segmenters", "kgnav.nets.segnet.segmenter"))
SEGMENTERS = REGISTRY.factories
register_segmenter = REGISTRY.register


def make_segmenter(name: str, seed: int = 0, **params) -> Segmenter:
    """A segmenter by name: ``learned`` (the RGB-D network, :mod:`kgnav.nets.segnet`), a preset of
    :data:`~kgnav.agent.noise_segmenters.SEGMENTER_PRESETS` (``clean``, ``default``, ``heavy``),
    the name a segmenter reports (``kgnav-segnet``, ``gt-clean``, ``gt-noisy``, ``gt-heavy``) or
    any registered name.
    """
    return REGISTRY.get(name)(seed=seed, **params)
