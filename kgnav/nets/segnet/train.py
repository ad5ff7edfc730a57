"""Supervised training of the segmenter on frames rendered from the ``train`` houses.

Each step renders a fresh batch (:class:`~kgnav.nets.segnet.data.LabelledViews`: class-balanced
views aimed at objects plus random ones), downscales it to the network's input size, augments it
(:func:`~kgnav.nets.segnet.data.augment`) and takes one AdamW step on a class-weighted cross-entropy
(background weighted down, the six ObjectNav goal classes up).

Reproducible: the batch of step ``k`` comes from ``default_rng([seed, k])`` and the weights are
initialised from ``seed``, so a run is a pure function of its :class:`SegTrainConfig` (on CPU, for
a given thread count); a run resumed from a checkpoint equals an uninterrupted one
(:class:`~kgnav.nets.training.SeededTrainer`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from kgnav.common.classes import OBJECT_CLASSES, OBJECTNAV_CLASSES
from kgnav.nets.encoder.net import downscale, to_tensor
from kgnav.nets.segnet.data import LabelledViews, augment, labels_at
from kgnav.nets.segnet.net import (
    N_OUT,
    SegArch,
    SegNet,
    depth_tensor,
    downscale_depth,
    fold_batchnorm,
)
from kgnav.nets.segnet.weights import SegmenterWeights, SegmenterWeightsError
from kgnav.nets.training import SeededTrainer, TrainingConfig

CHECKPOINT_FORMAT = "kgnav-segmenter-checkpoint"


@dataclass(frozen=True)
class SegTrainConfig(TrainingConfig):
    """Everything that determines a training run (recorded in checkpoints and weight files)."""

    split: str = "train"  # the shipped weights: the Matterport3D-scale train houses
    steps: int = 12000
    lr: float = 3e-3
    warmup: int = 100
    batch: int = 24
    background_weight: float = 0.7  # loss weight of background pixels (objects: 1)
    goal_weight: float = 1.5  # loss weight of the six ObjectNav goal classes
    object_share: float = 0.75  # share of views aimed at an object
    stem: int = 16
    channels: tuple[int, ...] = (24, 32, 64)
    depth_channels: tuple[int, ...] = (16, 32, 64)

    def __post_init__(self):
        if self.steps < 0 or self.batch < 2 or self.n_houses < 1:
            raise ValueError("steps must be >= 0, batch >= 2 and n_houses >= 1")

    @property
    def arch(self) -> SegArch:
        return SegArch(input_size=tuple(self.input_size), stem=self.stem,
                       channels=tuple(self.channels), depth_channels=tuple(self.depth_channels))

    def class_weights(self) -> torch.Tensor:
        w = torch.ones(N_OUT)
        w[0] = self.background_weight
        for c in OBJECTNAV_CLASSES:
            w[OBJECT_CLASSES.index(c) + 1] = self.goal_weight
        return w


class SegTrainer(SeededTrainer):
    """Trains a :class:`SegNet` per a :class:`SegTrainConfig`; ``fit`` returns ``self``.

    ``sampler`` defaults to the houses of ``config.split``; pass one to train elsewhere.
    """

    checkpoint_format = CHECKPOINT_FORMAT
    error = SegmenterWeightsError

    def __init__(self, config: SegTrainConfig, device: str = "cpu",
                 sampler: LabelledViews | None = None, threads: int = 1):
        super().__init__(config, device, threads)
        self._sampler = sampler
        torch.manual_seed(config.seed)
        self.net = SegNet(config.arch, batchnorm=True).to(self.device)
        self.opt = torch.optim.AdamW(self.net.parameters(), lr=config.lr,
                                     weight_decay=config.weight_decay)
        self._weights = config.class_weights().to(self.device)

    def modules(self):
        return {"net": self.net}

    @property
    def sampler(self) -> LabelledViews:
        if self._sampler is None:
            from kgnav.sim.episodes import load_scene_of

            c = self.config
            self._sampler = LabelledViews([load_scene_of(c.split, k) for k in range(c.n_houses)])
        return self._sampler

    def batch(self, step: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(rgb (N, 3, h, w), depth (N, 1, h, w), labels (N, h, w)) of a step, augmented."""
        c = self.config
        rng = np.random.default_rng([c.seed, step])
        rgb, depth, sem, _, _ = self.sampler.frames(rng, c.batch, object_share=c.object_share)
        size = c.arch.input_size
        xs, ds, ys = [], [], []
        for f, d, s in zip(rgb, depth, sem, strict=True):
            a, b, lab = augment(downscale(f, size), downscale_depth(d, size), labels_at(s, size),
                                rng)
            xs.append(a)
            ds.append(b)
            ys.append(lab)
        return to_tensor(np.stack(xs)), depth_tensor(np.stack(ds)), torch.from_numpy(
            np.stack(ys))

    def _train_step(self) -> float:
        x, d, y = (t.to(self.device) for t in self.batch(self.step))
        self.set_lr()
        self.net.train()
        loss = F.cross_entropy(self.net(x, d), y, weight=self._weights)
        return self.optimise(loss)

    def export(self) -> SegmenterWeights:
        """The inference weights (BatchNorm folded) with their metadata."""
        self.net.eval()
        params = {k: v.cpu().numpy() for k, v in fold_batchnorm(self.net).items()}
        meta = {"classes": list(OBJECT_CLASSES), "train": self.train_meta(curve_every=100)}
        return SegmenterWeights(self.config.arch, params, meta)
