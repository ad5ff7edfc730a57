"""Supervised training of the segmenter on frames rendered from the ``train`` houses, or walked
through any registered environment (``env``; :mod:`kgnav.nets.segnet.env_data`).

Each step renders a fresh batch (:class:`~kgnav.nets.segnet.data.LabelledViews`: class-balanced
views aimed at objects plus random ones), downscales it to the network's input size, augments it
(:func:`~kgnav.nets.segnet.data.augment`) and takes one AdamW step on a class-weighted cross-entropy
(background weighted down, the six ObjectNav goal classes up).

Reproducible: the batch of step ``k`` comes from ``default_rng([seed, k])`` and the weights are
initialised from ``seed``, so a run is a pure function of its :class:`SegTrainConfig` (on CPU, for
a given thread count); a run resumed from a checkpoint equals an uninterrupted one
(:class:`~kgnav.nets.training.SeededTrainer`). Another environment's frames are walked again
from the same seed when a run resumes, so they are the same frames.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from kgnav.common.classes import OBJECT_CLASSES, OBJECTNAV_CLASSES
from kgnav.errors import KgnavError
from kgnav.nets.encoder.net import downscale, to_tensor
from kgnav.nets.segnet.data import LabelledViews, augment, labels_at
from kgnav.nets.segnet.env_data import EnvLabelledViews
from kgnav.nets.segnet.net import (
    SegArch,
    SegNet,
    depth_tensor,
    downscale_depth,
    fold_batchnorm,
)
from kgnav.nets.segnet.weights import SegmenterWeights, SegmenterWeightsError
from kgnav.nets.training import SeededTrainer, TrainingConfig

CHECKPOINT_FORMAT = "kgnav-segmenter-checkpoint"
KGNAV = "kgnav"  # kgnav's own simulator: labelled views rendered from any pose


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
    env: str = KGNAV  # whose frames (kgnav.envs); recorded as the weights' domain
    classes: tuple[str, ...] = OBJECT_CLASSES  # the vocabulary it labels: the environment's
    walk_steps: int = 0  # views walked per scene of another environment (kgnav: none)
    scenes_dir: str | None = None  # kgnav houses of your own instead of the split's (a
    # `kgnav scenes generate` directory, its first n_houses)

    def __post_init__(self):
        if self.steps < 0 or self.batch < 2 or self.n_houses < 1:
            raise ValueError("steps must be >= 0, batch >= 2 and n_houses >= 1")
        if not self.classes or len(set(self.classes)) != len(self.classes):
            raise ValueError("classes must be distinct names, at least one")
        if self.scenes_dir is not None and self.env != KGNAV:
            raise ValueError("houses of your own (scenes_dir) are kgnav's, not another "
                             "environment's")
        if self.env != KGNAV and self.walk_steps < 1:
            raise ValueError("another environment's frames are walked: walk_steps must be >= 1")

    @property
    def arch(self) -> SegArch:
        return SegArch(input_size=tuple(self.input_size), stem=self.stem,
                       channels=tuple(self.channels), depth_channels=tuple(self.depth_channels),
                       n_classes=len(self.classes) + 1)

    def class_weights(self) -> torch.Tensor:
        """Background weighed down; kgnav's six goal classes up. Another environment declares
        no goal classes, so its object classes weigh 1."""
        w = torch.ones(len(self.classes) + 1)
        w[0] = self.background_weight
        if self.env == KGNAV:
            for c in OBJECTNAV_CLASSES:
                if c in self.classes:
                    w[self.classes.index(c) + 1] = self.goal_weight
        return w


class SegTrainer(SeededTrainer):
    """Trains a :class:`SegNet` per a :class:`SegTrainConfig`; ``fit`` returns ``self``.

    ``sampler`` defaults to the houses of ``config.split`` (of ``config.env``: walked there,
    labels from its semantic frames); pass one to train elsewhere.
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
            c = self.config
            if c.env == KGNAV:
                self._sampler = LabelledViews(training_houses(c))
            else:
                self._sampler = env_views(c.env, c.split, c.n_houses, c.walk_steps, c.seed)
                if self._sampler.classes != tuple(c.classes):
                    raise KgnavError(f"environment {c.env!r} labels {self._sampler.classes}, "
                                     f"not the run's classes {tuple(c.classes)}")
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
        c = self.config
        meta = {"classes": list(c.classes), "train": self.train_meta(curve_every=100),
                "domain": {"env": c.env, "scenes": c.n_houses,
                           **({"scenes_dir": c.scenes_dir} if c.scenes_dir
                              else {"train_split": c.split}),
                           "walk_steps": c.walk_steps or None}}
        return SegmenterWeights(c.arch, params, meta)


def training_houses(c: SegTrainConfig) -> list:
    """The kgnav houses a run trains on: the first ``n_houses`` of its split, or of its
    ``scenes_dir`` (:class:`~kgnav.errors.SceneFileError` when that has fewer)."""
    if c.scenes_dir is None:
        from kgnav.sim.episodes import load_scene_of

        return [load_scene_of(c.split, k) for k in range(c.n_houses)]
    from kgnav.sim.scene_dir import SceneDir

    return SceneDir(c.scenes_dir).scenes(c.n_houses)


def env_views(env: str, split: str, scenes: int, walk_steps: int, seed: int,
              progress=None) -> EnvLabelledViews:
    """The labelled views of the first ``scenes`` scenes of an environment's split, walked
    (``walk_steps`` a scene) from ``seed``."""
    from kgnav.envs import EnvOptions, make_env

    suite = make_env(env, EnvOptions(split=split))
    if scenes > len(suite):
        raise KgnavError(f"environment {env!r} split {split!r} has {len(suite)} scenes, not "
                         f"{scenes}")
    return EnvLabelledViews.from_suite(suite, range(scenes), walk_steps, seed,
                                       progress=progress)
