"""Self-supervised training of the encoder on frames rendered from the ``train`` houses.

Each step renders a fresh batch — no dataset on disk: ``houses_per_batch`` houses, and in each
``places_per_house`` places seen three times: an anchor view, a *positive* view within 0.5 m and
30° of it, and a *hard negative* view of the same house (moved 1–2 m, or turned more than 90°).
Two objectives:

* ``contrastive`` (default): supervised-contrastive InfoNCE over the batch, where the positives
  of a view are the views :func:`~kgnav.nets.encoder.views.relation_matrix` calls positive (its own
  place, and any other within 0.5 m / 30°), every negative view (other houses, other places of
  the same house) is pushed away, and ambiguous pairs are left out of the softmax;
* ``autoencoder``: reconstruct the downscaled frame from the embedding (the Taskonomy-style
  baseline; the embedding is the bottleneck). Same data, no use of poses.

Reproducible: the batch of step ``k`` is drawn from ``default_rng([seed, k])`` and the weights are
initialised from ``seed``, so a run is a pure function of its :class:`TrainConfig` (on CPU, for a
given thread count, 1 by default) — and a run resumed from a checkpoint equals an uninterrupted
one, since the checkpoint holds the model, the optimizer and the step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from kgnav.nets.encoder.net import Arch, ConvEncoder, Decoder, downscale, to_tensor
from kgnav.nets.encoder.views import (
    NEG_DIST,
    NEG_TURN,
    NEGATIVE,
    POS_DIST,
    POS_TURN,
    POSITIVE,
    ViewSampler,
    relation_matrix,
)
from kgnav.nets.encoder.weights import PAPER_THRESHOLD, EncoderWeights, EncoderWeightsError
from kgnav.nets.training import SeededTrainer, TrainingConfig, cosine_lr

OBJECTIVES = ("contrastive", "autoencoder")
CHECKPOINT_FORMAT = "kgnav-encoder-checkpoint"


@dataclass(frozen=True)
class TrainConfig(TrainingConfig):
    """Everything that determines a training run (recorded in checkpoints and weight files)."""

    dim: int = 128
    objective: str = "contrastive"
    houses_per_batch: int = 8
    places_per_house: int = 8
    temperature: float = 0.1
    shift_frac: float = 0.5  # share of hard negatives that are moved (the rest are turned)
    shift_max: float = 2.0  # m, farthest move of a moved hard negative (from just over 1 m)
    split: str = "train-small"  # the houses the shipped weights were trained on
    channels: tuple[int, ...] = (16, 32, 64, 128)

    def __post_init__(self):
        if self.objective not in OBJECTIVES:
            raise ValueError(f"objective must be one of {OBJECTIVES}, got {self.objective!r}")
        if self.dim < 1 or self.steps < 0 or self.houses_per_batch < 1:
            raise ValueError("dim and houses_per_batch must be positive, steps non-negative")
        if self.objective == "contrastive" and self.houses_per_batch * self.places_per_house < 2:
            raise ValueError("a contrastive batch needs at least two places")

    @property
    def arch(self) -> Arch:
        return Arch(dim=self.dim, input_size=tuple(self.input_size),
                    channels=tuple(self.channels))


def lr_at(cfg: TrainConfig, step: int) -> float:
    """Linear warm-up, then cosine decay to zero at ``cfg.steps``."""
    return cosine_lr(cfg.lr, cfg.warmup, cfg.steps, step)


def supcon_loss(z: torch.Tensor, rel: np.ndarray, temperature: float) -> torch.Tensor:
    """Supervised-contrastive loss of unit embeddings ``z`` (N, d) under relations ``rel``."""
    n = len(z)
    eye = np.eye(n, dtype=bool)
    pos = torch.from_numpy((rel == POSITIVE) & ~eye).to(z.device)
    keep = torch.from_numpy(((rel == POSITIVE) | (rel == NEGATIVE)) & ~eye).to(z.device)
    logits = (z @ z.T) / temperature
    logits = logits.masked_fill(~keep, float("-inf"))
    log_prob = logits - torch.logsumexp(logits, dim=1, keepdim=True)
    has = pos.any(dim=1)
    per = -(log_prob.masked_fill(~pos, 0.0).sum(1)[has] / pos.sum(1)[has])
    return per.mean()


class Trainer(SeededTrainer):
    """Trains a :class:`ConvEncoder` per a :class:`TrainConfig`; ``fit`` returns ``self``.

    ``sampler`` defaults to the houses of ``config.split``; pass one to train elsewhere. The
    loop, checkpoints and resume are :class:`~kgnav.nets.training.SeededTrainer`'s.
    """

    checkpoint_format = CHECKPOINT_FORMAT
    error = EncoderWeightsError

    def __init__(self, config: TrainConfig, device: str = "cpu",
                 sampler: ViewSampler | None = None, threads: int = 1):
        super().__init__(config, device, threads)
        self._sampler = sampler
        torch.manual_seed(config.seed)
        self.net = ConvEncoder(config.arch, batchnorm=True).to(self.device)
        params = list(self.net.parameters())
        self.decoder = None
        if config.objective == "autoencoder":
            self.decoder = Decoder(config.arch).to(self.device)
            params += list(self.decoder.parameters())
        self.opt = torch.optim.AdamW(params, lr=config.lr, weight_decay=config.weight_decay)

    def modules(self):
        return {"net": self.net, "decoder": self.decoder}

    @property
    def sampler(self) -> ViewSampler:
        if self._sampler is None:
            from kgnav.sim.episodes import load_scene_of

            c = self.config
            self._sampler = ViewSampler([load_scene_of(c.split, k) for k in range(c.n_houses)])
        return self._sampler

    # ------------------------------------------------------------------ data
    def batch(self, step: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(frames uint8 (N, h, w, 3) at the input size, houses (N,), poses (N, 3)) of a step."""
        c, s = self.config, self.sampler
        rng = np.random.default_rng([c.seed, step])
        chosen = rng.choice(len(s), size=min(c.houses_per_batch, len(s)), replace=False)
        frames, houses, poses = [], [], []
        for h in chosen:
            h = int(h)
            for _ in range(c.places_per_house):
                a = s.random_pose(h, rng)
                b = s.pose_near(h, a, rng) or s.pose_near(h, a, rng, dist=(0.0, 0.0))
                if rng.random() < c.shift_frac:  # hard negative: moved away, same heading ...
                    hard = s.pose_near(h, a, rng, dist=(NEG_DIST + 0.05, c.shift_max),
                                       turn=(0.0, POS_TURN))
                else:  # ... or turned away, same spot
                    hard = None
                hard = hard or s.pose_near(h, a, rng, dist=(0.0, POS_DIST),
                                           turn=(NEG_TURN + 0.05, math.pi))
                for p in (a, b, hard):
                    if p is None:
                        continue
                    frames.append(downscale(s.render(h, p), c.arch.input_size))
                    houses.append(h)
                    poses.append(p)
        return np.stack(frames), np.array(houses), np.array(poses, float)

    # ------------------------------------------------------------------ optimisation
    def _train_step(self) -> float:
        c = self.config
        frames, houses, poses = self.batch(self.step)
        x = to_tensor(frames).to(self.device)
        self.set_lr()
        self.net.train()
        z = self.net(x)
        if c.objective == "contrastive":
            loss = supcon_loss(F.normalize(z, dim=1), relation_matrix(houses, poses),
                               c.temperature)
        else:
            loss = F.mse_loss(self.decoder(z), x)
        return self.optimise(loss)

    def export(self, threshold: float = PAPER_THRESHOLD,
               threshold_source: str = "paper default (not calibrated)") -> EncoderWeights:
        """The inference weights (BatchNorm folded) with their metadata."""
        from kgnav.nets.encoder.net import fold_batchnorm

        self.net.eval()
        params = {k: v.cpu().numpy() for k, v in fold_batchnorm(self.net).items()}
        meta = {"threshold": float(threshold), "threshold_source": threshold_source,
                "train": self.train_meta()}
        return EncoderWeights(self.config.arch, params, meta)
