"""The convolutional encoder: architecture, input preprocessing, BatchNorm folding.

A frame is box-downscaled to ``input_size`` (80×60 by default: an exact 2×2 average of a 160×120
frame), then goes through stride-2 convolutions (5×5 first, then 3×3) with ReLU, is flattened —
the coarse spatial layout is kept on purpose: it tells views of the same room from different
headings apart — and a linear layer gives the ``dim``-vector. Training uses BatchNorm after each
convolution; the shipped network has it folded into the convolutions' weights and biases, so
inference is plain conv + ReLU (faster, and no running statistics to store).

>>> arch = Arch(dim=32)
>>> net = ConvEncoder(arch, batchnorm=False)
>>> import torch
>>> tuple(net(torch.zeros(2, 3, 60, 80)).shape)
(2, 32)
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import cv2
import numpy as np
import torch
from torch import nn

# fixed input normalisation: pixel / 255 → roughly zero-mean, unit-variance
_MEAN, _SCALE = 0.5, 4.0


@dataclass(frozen=True)
class Arch:
    """Architecture of a :class:`ConvEncoder`; stored in the weight file's metadata."""

    dim: int = 128
    input_size: tuple[int, int] = (80, 60)  # (width, height) after downscaling
    channels: tuple[int, ...] = (16, 32, 64, 128)
    first_kernel: int = 5

    def grid(self) -> tuple[int, int]:
        """(width, height) of the last feature map (each stride-2 conv halves, rounding up)."""
        w, h = self.input_size
        for _ in self.channels:
            w, h = (w + 1) // 2, (h + 1) // 2
        return w, h

    @property
    def flat(self) -> int:
        w, h = self.grid()
        return self.channels[-1] * w * h

    def to_dict(self) -> dict:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, d: dict) -> Arch:
        return cls(dim=int(d["dim"]), input_size=tuple(int(v) for v in d["input_size"]),
                   channels=tuple(int(v) for v in d["channels"]),
                   first_kernel=int(d["first_kernel"]))


class ConvEncoder(nn.Module):
    """Stride-2 conv stack + linear head. ``batchnorm=True`` is the training form.

    Parameter names (``convs.{i}.weight``, ``convs.{i}.bias``, ``head.weight``, ``head.bias``)
    are those of the weight file.
    """

    def __init__(self, arch: Arch, batchnorm: bool = True):
        super().__init__()
        self.arch = arch
        self.batchnorm = batchnorm
        convs, norms = [], []
        c = 3
        for i, o in enumerate(arch.channels):
            k = arch.first_kernel if i == 0 else 3
            convs.append(nn.Conv2d(c, o, k, stride=2, padding=k // 2, bias=not batchnorm))
            if batchnorm:
                norms.append(nn.BatchNorm2d(o))
            c = o
        self.convs = nn.ModuleList(convs)
        self.norms = nn.ModuleList(norms)
        self.head = nn.Linear(arch.flat, arch.dim)

    def trunk(self, x: torch.Tensor) -> torch.Tensor:
        """The last feature map (N, C, h, w)."""
        for i, conv in enumerate(self.convs):
            x = conv(x)
            if self.batchnorm:
                x = self.norms[i](x)
            x = torch.relu(x)
        return x

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Unnormalised embeddings (N, dim) of preprocessed images (N, 3, H, W)."""
        return self.head(self.trunk(x).flatten(1))


class Decoder(nn.Module):
    """Mirror of the encoder for the autoencoder objective (the Taskonomy-style baseline)."""

    def __init__(self, arch: Arch):
        super().__init__()
        self.arch = arch
        w, h = arch.grid()
        self.fc = nn.Linear(arch.dim, arch.flat)
        ups: list[nn.Module] = []
        chans = list(arch.channels[::-1]) + [16]
        for c_in, c_out in zip(chans[:-1], chans[1:], strict=True):
            ups += [nn.Upsample(scale_factor=2, mode="nearest"),
                    nn.Conv2d(c_in, c_out, 3, padding=1), nn.ReLU()]
        ups.append(nn.Conv2d(16, 3, 3, padding=1))
        self.layers = nn.Sequential(*ups)
        self._shape = (arch.channels[-1], h, w)

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        """Reconstructed preprocessed images (N, 3, H, W) from embeddings (N, dim)."""
        x = torch.relu(self.fc(z)).view(-1, *self._shape)
        w, h = self.arch.input_size
        return self.layers(x)[..., :h, :w]


def fold_batchnorm(net: ConvEncoder) -> dict[str, torch.Tensor]:
    """State dict of the equivalent ``batchnorm=False`` network (BatchNorm in eval mode)."""
    out: dict[str, torch.Tensor] = {}
    with torch.no_grad():
        for i, conv in enumerate(net.convs):
            w = conv.weight.detach().clone()
            b = torch.zeros_like(w[:, 0, 0, 0]) if conv.bias is None else conv.bias.detach().clone()
            if net.batchnorm:
                bn = net.norms[i]
                g = bn.weight / torch.sqrt(bn.running_var + bn.eps)
                w = w * g[:, None, None, None]
                b = (b - bn.running_mean) * g + bn.bias
            out[f"convs.{i}.weight"], out[f"convs.{i}.bias"] = w, b
        out["head.weight"] = net.head.weight.detach().clone()
        out["head.bias"] = net.head.bias.detach().clone()
    return out


def downscale(rgb: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Area-average a uint8 frame to ``size`` = (width, height) (no-op when already there)."""
    if (rgb.shape[1], rgb.shape[0]) == tuple(size):
        return rgb
    return cv2.resize(rgb, size, interpolation=cv2.INTER_AREA)


def to_tensor(small: np.ndarray) -> torch.Tensor:
    """uint8 (N, H, W, 3) or (H, W, 3) → normalised float32 (N, 3, H, W)."""
    x = torch.from_numpy(np.ascontiguousarray(small))
    if x.ndim == 3:
        x = x[None]
    return x.permute(0, 3, 1, 2).float().mul_(_SCALE / 255.0).sub_(_MEAN * _SCALE)


def preprocess(rgbs: np.ndarray, arch: Arch) -> torch.Tensor:
    """RGB uint8 frames (N, H, W, 3) → the network's input tensor."""
    size = arch.input_size
    small = np.stack([downscale(f, size) for f in rgbs]) if len(rgbs) else np.zeros(
        (0, size[1], size[0], 3), np.uint8)
    return to_tensor(small)
