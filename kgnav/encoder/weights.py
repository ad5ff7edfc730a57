"""The encoder's weight file: a numpy ``.npz`` of float32 arrays plus a JSON metadata record.

No pickle anywhere (``allow_pickle=False``), so a weight file from elsewhere cannot run code.
Layout: one array per parameter of the inference network (BatchNorm folded, names as in
:class:`~kgnav.encoder.net.ConvEncoder`'s state dict) and ``__meta__``, the UTF-8 bytes of a JSON
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

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from kgnav.atomic import atomic_open
from kgnav.encoder.net import Arch, ConvEncoder
from kgnav.errors import KgnavError

FORMAT = "kgnav-encoder-weights"
VERSION = 1
META_KEY = "__meta__"
DEFAULT_WEIGHTS = Path(__file__).resolve().parents[1] / "weights" / "encoder.npz"
PAPER_THRESHOLD = 0.3  # the paper's cosine-distance threshold, used until one is calibrated


class EncoderWeightsError(KgnavError):
    """An encoder weight file cannot be used: missing, corrupt, foreign or of another version."""

    def __init__(self, path: str | os.PathLike[str], reason: str):
        self.path = os.fspath(path)
        self.reason = reason
        super().__init__(f"{self.path}: {reason}")


@dataclass
class EncoderWeights:
    """The content of a weight file: architecture, parameter arrays and metadata."""

    arch: Arch
    params: dict[str, np.ndarray]
    meta: dict = field(default_factory=dict)

    @property
    def threshold(self) -> float:
        return float(self.meta.get("threshold", PAPER_THRESHOLD))

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write atomically (a crash never leaves a half-written file at ``path``)."""
        meta = dict(self.meta, format=FORMAT, version=VERSION, arch=self.arch.to_dict())
        blob = np.frombuffer(json.dumps(meta, sort_keys=True).encode(), dtype=np.uint8)
        arrays = {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in self.params.items()}
        with atomic_open(path, "wb") as fh:
            np.savez(fh, **{META_KEY: blob}, **arrays)
        os.chmod(path, 0o644)  # the temporary file was private (0600); weights are shareable
        return Path(path)


def expected_shapes(arch: Arch) -> dict[str, tuple[int, ...]]:
    """Parameter name → shape of the inference network of ``arch``."""
    net = ConvEncoder(arch, batchnorm=False)
    return {k: tuple(v.shape) for k, v in net.state_dict().items()}


def load_weights(path: str | os.PathLike[str] | None = None) -> EncoderWeights:
    """Read and validate a weight file (default: the weights shipped in the package)."""
    path = Path(DEFAULT_WEIGHTS if path is None else path)
    if not path.is_file():
        raise EncoderWeightsError(path, "no such file" if not path.exists() else "not a file")
    try:
        npz = np.load(path, allow_pickle=False)
    except Exception as exc:  # BadZipFile, ValueError, OSError, EOFError, ...: all "unreadable"
        raise EncoderWeightsError(path, f"not a kgnav encoder weight file ({_why(exc)})") from None
    if not hasattr(npz, "files"):  # a bare .npy array
        raise EncoderWeightsError(path, "not a kgnav encoder weight file (a single array)")
    with npz:
        if META_KEY not in npz.files:
            raise EncoderWeightsError(path, "not a kgnav encoder weight file (no metadata)")
        try:
            meta = json.loads(bytes(npz[META_KEY]).decode())
        except Exception as exc:
            raise EncoderWeightsError(path, f"corrupt metadata ({_why(exc)})") from None
        if not isinstance(meta, dict) or meta.get("format") != FORMAT:
            got = meta.get("format") if isinstance(meta, dict) else type(meta).__name__
            raise EncoderWeightsError(path, f"not a kgnav encoder weight file (format {got!r})")
        if meta.get("version") != VERSION:
            raise EncoderWeightsError(
                path, f"weight format version {meta.get('version')!r}, this release reads {VERSION}"
            )
        try:
            arch = Arch.from_dict(meta["arch"])
            if arch.dim < 1 or min(arch.input_size) < 1 or not arch.channels:
                raise ValueError("non-positive sizes")
        except Exception as exc:
            raise EncoderWeightsError(path, f"bad architecture record ({_why(exc)})") from None
        shapes = expected_shapes(arch)
        missing = sorted(set(shapes) - set(npz.files))
        extra = sorted(set(npz.files) - set(shapes) - {META_KEY})
        if missing or extra:
            raise EncoderWeightsError(path, f"parameters do not match the architecture "
                                            f"(missing {missing}, unexpected {extra})")
        params = {}
        for name, shape in shapes.items():
            try:
                a = np.asarray(npz[name])
            except Exception as exc:
                raise EncoderWeightsError(path, f"corrupt array {name!r} ({_why(exc)})") from None
            if a.shape != shape or a.dtype.kind != "f":
                raise EncoderWeightsError(
                    path, f"array {name!r} is {a.dtype} {a.shape}, expected float {shape}")
            if not np.isfinite(a).all():
                raise EncoderWeightsError(path, f"array {name!r} holds non-finite values")
            params[name] = a.astype(np.float32)
    thr = meta.get("threshold", PAPER_THRESHOLD)
    if not isinstance(thr, int | float) or not 0 < thr <= 2:
        raise EncoderWeightsError(path, f"threshold {thr!r} is not a cosine distance in (0, 2]")
    return EncoderWeights(arch, params, meta)


def set_threshold(path: str | os.PathLike[str], threshold: float, source: str) -> None:
    """Store a calibrated match threshold in the metadata of the weight file at ``path``."""
    w = load_weights(path)
    w.meta["threshold"] = round(float(threshold), 6)
    w.meta["threshold_source"] = source
    w.save(path)


def _why(exc: BaseException) -> str:
    msg = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {msg[0]}" if msg else type(exc).__name__
