"""The segmenter's weight file (``kgnav/weights/segmenter.npz``): arrays + JSON metadata.

The format is :mod:`kgnav.nets.weights`' (no pickle): one float32 array per parameter of the
inference network (BatchNorm folded, names as in :class:`~kgnav.nets.segnet.net.SegNet`'s state
dict)
and ``__meta__``::

    {"format": "kgnav-segmenter-weights", "version": 1,
     "arch": {"input_size": [80, 60], "stem": 16, "channels": [...], ...},
     "classes": ["chair", ...], "score_threshold": 0.6, "score_threshold_source": "...",
     "train": {"seed": 0, "steps": ..., "threads": 1, "loss_curve": [...], ...}}

Every way a file can be wrong raises :class:`SegmenterWeightsError` naming the file and the
reason, in one line.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import ClassVar

from kgnav.common.classes import OBJECT_CLASSES
from kgnav.nets.segnet.net import SegArch, SegNet
from kgnav.nets.weights import SHIPPED, NetWeights, WeightsError, read_npz

FORMAT = "kgnav-segmenter-weights"
VERSION = 1
DEFAULT_WEIGHTS = SHIPPED / "segmenter.npz"


class SegmenterWeightsError(WeightsError):
    """A segmenter weight file cannot be used: missing, corrupt, foreign or of another version."""


class SegmenterWeights(NetWeights):
    """The content of a weight file: architecture, parameter arrays, metadata (with the class
    names and the calibrated segment-score threshold)."""

    arch: SegArch
    FORMAT: ClassVar[str] = FORMAT
    VERSION: ClassVar[int] = VERSION

    @property
    def classes(self) -> tuple[str, ...]:
        return tuple(self.meta.get("classes", OBJECT_CLASSES))

    @property
    def score_threshold(self) -> float:
        """Segments scoring below this are dropped (0 until calibrated)."""
        return float(self.meta.get("score_threshold", 0.0))


def expected_shapes(arch: SegArch | dict) -> dict[str, tuple[int, ...]]:
    """Parameter name → shape of the inference network of ``arch``."""
    arch = arch if isinstance(arch, SegArch) else SegArch.from_dict(arch)
    return {k: tuple(v.shape) for k, v in SegNet(arch, batchnorm=False).state_dict().items()}


def load_weights(path: str | os.PathLike[str] | None = None) -> SegmenterWeights:
    """Read and validate a weight file (default: the weights shipped in the package)."""
    path = Path(DEFAULT_WEIGHTS if path is None else path)
    meta, params = read_npz(path, fmt=FORMAT, version=VERSION,
                            what="kgnav segmenter weight file", error=SegmenterWeightsError,
                            shapes=expected_shapes)
    arch = SegArch.from_dict(meta["arch"])
    classes = meta.get("classes")
    if (not isinstance(classes, list) or len(classes) != arch.n_classes - 1
            or not all(isinstance(c, str) for c in classes)):
        raise SegmenterWeightsError(
            path, f"class list does not fit the network ({arch.n_classes - 1} classes)")
    thr = meta.get("score_threshold", 0.0)
    if not isinstance(thr, int | float) or not 0 <= thr < 1:
        raise SegmenterWeightsError(path, f"score_threshold {thr!r} is not in [0, 1)")
    return SegmenterWeights(arch, params, meta)
