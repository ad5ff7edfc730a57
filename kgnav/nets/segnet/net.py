"""The RGB-D segmentation network: a small encoder–decoder in RedNet's spirit, for the CPU.

RedNet (Jiang et al. 2018) runs two ResNet encoders, one on RGB and one on depth, adds the depth
features into the RGB branch after every stage, and decodes with skip connections. This network
keeps that shape at a size one CPU core runs in about a millisecond:

* the frame is area-downscaled to ``input_size`` (80×60 by default, an exact 2×2 average of a
  160×120 frame); RGB is normalised like the encoder's, depth mapped from [0.5, 5] m to [-1, 1];
* a full-resolution stem (3×3 conv over RGB-D) feeds the last decoder stage (edges);
* RGB encoder: stride-2 stages of ``channels`` (each a strided 3×3 conv, then one 3×3 conv
  from the second stage on); depth encoder: one strided 3×3 conv per stage, its output **added**
  to the RGB stage's output (RedNet's fusion);
* decoder: a 3×3 conv at the coarse scale (to the skip's width), upsample ×2 (nearest), add the
  encoder's skip, ReLU, down to the input size — convolving before upsampling costs a quarter of
  the other order; a 1×1 head gives the logits of background + the 24 classes of
  :data:`kgnav.common.classes.OBJECT_CLASSES`.

Training uses BatchNorm after every convolution; the shipped network has it folded into the
convolutions (:func:`fold_batchnorm`), so inference is conv + ReLU.

>>> import torch
>>> net = SegNet(SegArch(), batchnorm=False)
>>> tuple(net(torch.zeros(2, 3, 60, 80), torch.zeros(2, 1, 60, 80)).shape)
(2, 25, 60, 80)
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import cv2
import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from kgnav.common.classes import OBJECT_CLASSES
from kgnav.nets.encoder.net import downscale, to_tensor
from kgnav.sim.render import MAX_DEPTH, MIN_DEPTH

N_OUT = len(OBJECT_CLASSES) + 1  # background + the object classes


@dataclass(frozen=True)
class SegArch:
    """Architecture of a :class:`SegNet`; stored in the weight file's metadata."""

    input_size: tuple[int, int] = (80, 60)  # (width, height) the frame is downscaled to
    stem: int = 16  # channels of the full-resolution stem
    channels: tuple[int, ...] = (24, 32, 64)  # RGB/depth encoder stages (stride 2 each)
    depth_channels: tuple[int, ...] = (16, 32, 64)  # depth branch; last must match channels
    n_classes: int = N_OUT

    def __post_init__(self):
        if len(self.channels) != len(self.depth_channels) or not self.channels:
            raise ValueError("channels and depth_channels need the same, non-zero length")
        if min(self.input_size) < 2 ** len(self.channels):
            raise ValueError(f"input_size {self.input_size} too small for "
                             f"{len(self.channels)} stride-2 stages")
        if self.n_classes < 2:
            raise ValueError("n_classes must be >= 2")

    def to_dict(self) -> dict:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, d: dict) -> SegArch:
        return cls(input_size=tuple(int(v) for v in d["input_size"]), stem=int(d["stem"]),
                   channels=tuple(int(v) for v in d["channels"]),
                   depth_channels=tuple(int(v) for v in d["depth_channels"]),
                   n_classes=int(d["n_classes"]))


class ConvBN(nn.Module):
    """3×3 (or k×k) convolution, BatchNorm when training-form, ReLU unless ``act=False``."""

    def __init__(self, c_in: int, c_out: int, stride: int = 1, batchnorm: bool = True,
                 act: bool = True, k: int = 3):
        super().__init__()
        self.conv = nn.Conv2d(c_in, c_out, k, stride=stride, padding=k // 2, bias=not batchnorm)
        self.bn = nn.BatchNorm2d(c_out) if batchnorm else None
        self.act = act

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self.conv(x)
        if self.bn is not None:
            x = self.bn(x)
        return torch.relu(x) if self.act else x


class SegNet(nn.Module):
    """RGB-D encoder–decoder (see the module doc). ``forward(rgb, depth)`` takes preprocessed
    tensors (N, 3, h, w) and (N, 1, h, w) and returns logits (N, n_classes, h, w)."""

    def __init__(self, arch: SegArch, batchnorm: bool = True):
        super().__init__()
        self.arch = arch
        self.batchnorm = batchnorm
        bn = batchnorm
        self.stem = ConvBN(4, arch.stem, 1, bn)
        rgb, dep, dec = [], [], []
        c, cd = 3, 1
        for i, (o, od) in enumerate(zip(arch.channels, arch.depth_channels, strict=True)):
            stage = [ConvBN(c, o, 2, bn)] + ([ConvBN(o, o, 1, bn)] if i else [])
            rgb.append(nn.Sequential(*stage))
            dep.append(ConvBN(cd, od, 2, bn))
            c, cd = o, od
        self.rgb = nn.ModuleList(rgb)
        self.dep = nn.ModuleList(dep)
        # depth features join the RGB stage of the same width; a 1x1 adapts others
        self.fuse = nn.ModuleList(
            nn.Identity() if od == o else nn.Conv2d(od, o, 1, bias=False)
            for o, od in zip(arch.channels, arch.depth_channels, strict=True))
        skips = [arch.stem, *arch.channels[:-1]]
        c = arch.channels[-1]
        for s in reversed(skips):
            dec.append(ConvBN(c, s, 1, bn, act=False))
            c = s
        self.dec = nn.ModuleList(dec)
        self.head = nn.Conv2d(arch.stem, arch.n_classes, 1)

    def forward(self, rgb: torch.Tensor, depth: torch.Tensor) -> torch.Tensor:
        skips = [self.stem(torch.cat([rgb, depth], 1))]
        x, d = rgb, depth
        for rgb_stage, dep_stage, fuse in zip(self.rgb, self.dep, self.fuse, strict=True):
            d = dep_stage(d)
            x = rgb_stage(x) + fuse(d)
            skips.append(x)
        skips.pop()
        for conv in self.dec:
            s = skips.pop()
            x = F.interpolate(conv(x), size=s.shape[-2:], mode="nearest")
            x = torch.relu(x + s)
        return self.head(x)


def fold_batchnorm(net: SegNet) -> dict[str, torch.Tensor]:
    """State dict of the equivalent ``batchnorm=False`` network (BatchNorm in eval mode)."""
    out = {k: v.detach().clone() for k, v in net.state_dict().items()
           if ".bn." not in k and not k.endswith(".conv.weight")}
    with torch.no_grad():
        for name, m in net.named_modules():
            if not isinstance(m, ConvBN):
                continue
            w = m.conv.weight.detach().clone()
            b = torch.zeros(w.shape[0]) if m.conv.bias is None else m.conv.bias.detach().clone()
            if m.bn is not None:
                g = m.bn.weight / torch.sqrt(m.bn.running_var + m.bn.eps)
                w = w * g[:, None, None, None]
                b = (b - m.bn.running_mean) * g + m.bn.bias
            out[f"{name}.conv.weight"], out[f"{name}.conv.bias"] = w, b
    return out


_D_MID = (MAX_DEPTH + MIN_DEPTH) / 2
_D_HALF = (MAX_DEPTH - MIN_DEPTH) / 2


def depth_tensor(depth: np.ndarray) -> torch.Tensor:
    """float depth (N, h, w) or (h, w) in metres → (N, 1, h, w), [0.5, 5] m → [-1, 1]."""
    d = torch.from_numpy(np.ascontiguousarray(depth, np.float32))
    if d.ndim == 2:
        d = d[None]
    return d[:, None].sub(_D_MID).mul_(1.0 / _D_HALF)


def downscale_depth(depth: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Area-average a float depth frame to ``size`` = (width, height)."""
    if (depth.shape[1], depth.shape[0]) == tuple(size):
        return np.asarray(depth, np.float32)
    return cv2.resize(np.asarray(depth, np.float32), size, interpolation=cv2.INTER_AREA)


def preprocess(rgb: np.ndarray, depth: np.ndarray, arch: SegArch
               ) -> tuple[torch.Tensor, torch.Tensor]:
    """One frame (H, W, 3) uint8 + (H, W) float, or a batch of them, → the network's inputs."""
    size = arch.input_size
    if rgb.ndim == 3:
        return to_tensor(downscale(rgb, size)), depth_tensor(downscale_depth(depth, size))
    return (to_tensor(np.stack([downscale(f, size) for f in rgb])),
            depth_tensor(np.stack([downscale_depth(d, size) for d in depth])))
