"""The encoder's weight file: a numpy ``.npz`` of float32 arrays plus a JSON metadata record.

The format is :mod:`kgnav.nets.weights`' (no pickle, so a weight file from elsewhere cannot run
code). Layout: one array per parameter of the inference network (BatchNorm folded, names as in
:class:`~kgnav.nets.encoder.net.ConvEncoder`'s state dict) and ``__meta__``, the UTF-8 bytes of a
JSON
object::

    {"format": "kgnav-encoder-weights", "version": 1,
     "arch": {"dim": 128, "input_size": [80, 60], "channels": [...], "first_kernel": 5},
     "threshold": 0.21, "threshold_source": "calibrated on val ...",
     "train": {"seed": 0, "steps": 1800, "objective": "contrastive", ...}}

Every way a file can be wrong (missing, truncated, not an npz, another format or version,
missing or misshaped arrays, non-finite values) raises :class:`EncoderWeightsError` naming the
file and the reason.
"""

from __future__ import annotations

import os
from functools import cache
from pathlib import Path
from typing import ClassVar

from kgnav.nets.encoder.net import Arch, ConvEncoder
from kgnav.nets.weights import META_KEY as META_KEY  # re-exported: the layout's metadata key
from kgnav.nets.weights import SHIPPED, NetWeights, WeightsError, read_npz

FORMAT = "kgnav-encoder-weights"
VERSION = 1
DEFAULT_WEIGHTS = SHIPPED / "encoder.npz"
PAPER_THRESHOLD = 0.3  # the paper's cosine-distance threshold, used until one is calibrated


class EncoderWeightsError(WeightsError):
    """An encoder weight file cannot be used: missing, corrupt, foreign or of another version."""


class EncoderWeights(NetWeights):
    """The content of a weight file: architecture, parameter arrays and metadata."""

    arch: Arch
    FORMAT: ClassVar[str] = FORMAT
    VERSION: ClassVar[int] = VERSION

    @property
    def threshold(self) -> float:
        return float(self.meta.get("threshold", PAPER_THRESHOLD))

    def fingerprint(self) -> str:
        """12 hex digits of SHA-256 over the architecture and the parameters (not the
        metadata: recalibrating a threshold keeps the features, and so the fingerprint)."""
        import hashlib
        import json

        import numpy as np

        h = hashlib.sha256(json.dumps(self.arch.to_dict(), sort_keys=True).encode())
        for k in sorted(self.params):
            h.update(k.encode())
            h.update(np.ascontiguousarray(self.params[k], np.float32).tobytes())
        return h.hexdigest()[:12]


def expected_shapes(arch: Arch | dict) -> dict[str, tuple[int, ...]]:
    """Parameter name → shape of the inference network of ``arch`` (an :class:`Arch` or its
    metadata record)."""
    if not isinstance(arch, Arch):
        arch = Arch.from_dict(arch)
        if arch.dim < 1 or min(arch.input_size) < 1 or not arch.channels:
            raise ValueError("non-positive sizes")
    net = ConvEncoder(arch, batchnorm=False)
    return {k: tuple(v.shape) for k, v in net.state_dict().items()}


def load_weights(path: str | os.PathLike[str] | None = None) -> EncoderWeights:
    """Read and validate a weight file (default: the weights shipped in the package)."""
    path = Path(DEFAULT_WEIGHTS if path is None else path)
    meta, params = read_npz(path, fmt=FORMAT, version=VERSION, what="kgnav encoder weight file",
                            error=EncoderWeightsError, shapes=expected_shapes)
    thr = meta.get("threshold", PAPER_THRESHOLD)
    if not isinstance(thr, int | float) or not 0 < thr <= 2:
        raise EncoderWeightsError(path, f"threshold {thr!r} is not a cosine distance in (0, 2]")
    return EncoderWeights(Arch.from_dict(meta["arch"]), params, meta)


@cache
def shipped_fingerprint() -> str:
    """The fingerprint of the shipped weights."""
    return load_weights().fingerprint()


def set_threshold(path: str | os.PathLike[str], threshold: float, source: str,
                  key: str = "threshold") -> None:
    """Store a calibrated threshold in the metadata of the weight file at ``path``: the match
    threshold (``key="threshold"``) or the one the agent relocates with
    (``key="loop_threshold"``, see :class:`~kgnav.nets.encoder.extractor.LearnedEncoder`),
    with its source under ``<key>_source``."""
    if key not in ("threshold", "loop_threshold"):
        raise ValueError(f"key must be threshold or loop_threshold, got {key!r}")
    w = load_weights(path)
    w.meta[key] = round(float(threshold), 6)
    w.meta[f"{key}_source"] = source
    w.save(path)
