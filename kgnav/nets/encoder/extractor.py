"""``kgnav-encoder``: state features from the trained convolutional encoder.

Importing this module registers the extractor; :func:`kgnav.agent.features.make_extractor`
imports it on first use of the name, so ``make_extractor("kgnav-encoder")`` just works:

>>> import numpy as np
>>> from kgnav.agent.features import make_extractor
>>> enc = make_extractor("kgnav-encoder", device="cpu")
>>> f = enc(np.zeros((120, 160, 3), np.uint8))
>>> f.shape == (enc.dim,), f.dtype, round(float(np.linalg.norm(f)), 5)
(True, dtype('float32'), 1.0)
>>> 0 < enc.threshold < 1
True
"""

from __future__ import annotations

import os

import numpy as np
import torch

from kgnav.agent.features import register_extractor
from kgnav.nets.encoder.net import ConvEncoder, downscale, preprocess, to_tensor
from kgnav.nets.encoder.weights import EncoderWeights, load_weights, shipped_fingerprint

NAME = "kgnav-encoder"
# The agent's relocation threshold for the shipped weights: precision 0.973, recall 0.45 per view
# pair on the calibration draw (seed 0), against 0.99 / 0.08 at ``threshold``. In the loop a
# match must also be confirmed by a second one and survive the landmark check, which removes
# most of the look-alike matches this admits (docs/encoder.md, "Thresholds in the loop").
LOOP_THRESHOLD = 0.1


def resolve_device(device: str = "auto") -> torch.device:
    """``"auto"`` → ``cuda`` when available, else ``cpu``; ``"cpu"``/``"cuda"`` as given."""
    if device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if device not in ("cpu", "cuda"):
        raise ValueError(f"device must be auto, cpu or cuda, got {device!r}")
    if device == "cuda" and not torch.cuda.is_available():
        raise ValueError("device 'cuda' requested but torch sees no CUDA GPU")
    return torch.device(device)


@register_extractor(NAME)
class LearnedEncoder:
    """Unit-norm features of an RGB frame from the trained encoder.

    Parameters
    ----------
    weights:
        Path of a weight file (default: the weights shipped in ``kgnav/weights/``) or an
        already loaded :class:`EncoderWeights`.
    device:
        ``"auto"`` (GPU when present), ``"cpu"`` or ``"cuda"``.

    Attributes: ``name`` (``kgnav-encoder`` for the shipped weights, else
    ``kgnav-encoder:<fingerprint>``, see :meth:`EncoderWeights.fingerprint`), ``dim``,
    ``threshold`` (the calibrated cosine-distance below which two states match, from the weight
    file), ``loop_threshold`` (the one the agent relocates with: the weight file's
    ``loop_threshold`` metadata, else :data:`LOOP_THRESHOLD` for the shipped weights and
    ``threshold`` for others), ``meta`` (the weight file's metadata).
    """

    name = NAME

    def __init__(self, weights: str | os.PathLike[str] | EncoderWeights | None = None,
                 device: str = "auto"):
        w = weights if isinstance(weights, EncoderWeights) else load_weights(weights)
        self.arch = w.arch
        self.dim = w.arch.dim
        self.threshold = w.threshold
        shipped = weights is None or w.fingerprint() == shipped_fingerprint()
        # other weights give other features: models built with them must never mix with the
        # shipped encoder's (merging and relocation refuse another extractor name)
        self.name = NAME if shipped else f"{NAME}:{w.fingerprint()}"
        # LOOP_THRESHOLD was chosen for the shipped weights; others relocate at their own
        # calibrated threshold unless their file names a loop threshold
        self.loop_threshold = float(w.meta.get("loop_threshold",
                                               LOOP_THRESHOLD if shipped else self.threshold))
        self.meta = w.meta
        self.device = resolve_device(device)
        net = ConvEncoder(w.arch, batchnorm=False)
        net.load_state_dict({k: torch.from_numpy(v) for k, v in w.params.items()})
        self.net = net.eval().to(self.device)
        for p in self.net.parameters():
            p.requires_grad_(False)

    def __repr__(self) -> str:
        return f"LearnedEncoder(dim={self.dim}, threshold={self.threshold:.3f}, {self.device})"

    def __call__(self, rgb: np.ndarray) -> np.ndarray:
        """Features (dim,) float32, unit norm, of one RGB uint8 frame (H, W, 3)."""
        rgb = np.asarray(rgb)
        if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
            raise ValueError(f"expected an RGB uint8 frame (H, W, 3), got {rgb.dtype} {rgb.shape}")
        return self._embed(to_tensor(downscale(rgb, self.arch.input_size)))[0]

    def batch(self, rgbs: np.ndarray, chunk: int = 256) -> np.ndarray:
        """Features (N, dim) of frames (N, H, W, 3); row i is ``self(rgbs[i])`` (to rounding)."""
        rgbs = np.asarray(rgbs)
        if rgbs.ndim != 4 or rgbs.shape[3] != 3 or rgbs.dtype != np.uint8:
            raise ValueError(f"expected RGB uint8 frames (N, H, W, 3), got {rgbs.dtype} "
                             f"{rgbs.shape}")
        out = np.empty((len(rgbs), self.dim), np.float32)
        for i in range(0, len(rgbs), chunk):
            out[i:i + chunk] = self._embed(preprocess(rgbs[i:i + chunk], self.arch))
        return out

    def _embed(self, x: torch.Tensor) -> np.ndarray:
        with torch.inference_mode():
            y = self.net(x.to(self.device)).float().cpu().numpy()
        n = np.linalg.norm(y, axis=1, keepdims=True)
        blank = n[:, 0] < 1e-12  # cannot happen with trained weights; keeps the unit-norm contract
        y /= np.maximum(n, 1e-12)
        if blank.any():
            y[blank] = 0.0
            y[blank, 0] = 1.0
        return y
