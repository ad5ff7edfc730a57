"""Self-supervised training of the encoder on frames rendered from the ``train`` houses.

Each step renders a fresh batch — no dataset on disk: ``houses_per_batch`` houses, and in each
``places_per_house`` places seen three times: an anchor view, a *positive* view within 0.5 m and
30° of it, and a *hard negative* view of the same house (moved 1–2 m, or turned more than 90°).
Two objectives:

* ``contrastive`` (default): supervised-contrastive InfoNCE over the batch, where the positives
  of a view are the views :func:`~kgnav.encoder.views.relation_matrix` calls positive (its own
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
import os
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from kgnav.encoder.net import Arch, ConvEncoder, Decoder, downscale, to_tensor
from kgnav.encoder.views import (
    NEG_DIST,
    NEG_TURN,
    NEGATIVE,
    POS_DIST,
    POS_TURN,
    POSITIVE,
    ViewSampler,
    relation_matrix,
)
from kgnav.encoder.weights import PAPER_THRESHOLD, EncoderWeights, EncoderWeightsError

OBJECTIVES = ("contrastive", "autoencoder")
CHECKPOINT_FORMAT = "kgnav-encoder-checkpoint"


@dataclass(frozen=True)
class TrainConfig:
    """Everything that determines a training run (recorded in checkpoints and weight files)."""

    seed: int = 0
    steps: int = 2000
    dim: int = 128
    objective: str = "contrastive"
    houses_per_batch: int = 8
    places_per_house: int = 8
    temperature: float = 0.1
    shift_frac: float = 0.5  # share of hard negatives that are moved (the rest are turned)
    shift_max: float = 2.0  # m, farthest move of a moved hard negative (from just over 1 m)
    lr: float = 2e-3
    weight_decay: float = 1e-4
    warmup: int = 50
    split: str = "train-small"  # the houses the shipped weights were trained on
    n_houses: int = 20  # the first n houses of the split
    input_size: tuple[int, int] = (80, 60)
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

    def to_dict(self) -> dict:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, d: dict) -> TrainConfig:
        known = {f.name for f in fields(cls)}
        kw = {k: tuple(v) if isinstance(v, list) else v for k, v in d.items() if k in known}
        return cls(**kw)


def lr_at(cfg: TrainConfig, step: int) -> float:
    """Linear warm-up, then cosine decay to zero at ``cfg.steps``."""
    if step < cfg.warmup:
        return cfg.lr * (step + 1) / cfg.warmup
    span = max(cfg.steps - cfg.warmup, 1)
    return 0.5 * cfg.lr * (1 + math.cos(math.pi * min((step - cfg.warmup) / span, 1.0)))


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


class Trainer:
    """Trains a :class:`ConvEncoder` per a :class:`TrainConfig`; ``fit`` returns ``self``.

    ``sampler`` defaults to the houses of ``config.split``; pass one to train elsewhere. The
    current step is :attr:`step`; :meth:`save_checkpoint` / :meth:`load_checkpoint` persist it.
    """

    def __init__(self, config: TrainConfig, device: str = "cpu",
                 sampler: ViewSampler | None = None, threads: int = 1):
        self.config = config
        self.device = torch.device(device)
        self.threads = threads
        self._sampler = sampler
        torch.manual_seed(config.seed)
        self.net = ConvEncoder(config.arch, batchnorm=True).to(self.device)
        params = list(self.net.parameters())
        self.decoder = None
        if config.objective == "autoencoder":
            self.decoder = Decoder(config.arch).to(self.device)
            params += list(self.decoder.parameters())
        self.opt = torch.optim.AdamW(params, lr=config.lr, weight_decay=config.weight_decay)
        self.step = 0
        self.elapsed_s = 0.0  # training time over all sessions (checkpoints carry it)
        self.last_loss = math.nan

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
    def train_step(self) -> float:
        """One optimisation step on the batch of :attr:`step`; returns the loss."""
        # the thread count changes float reduction order: pin it so that steps taken here and
        # inside fit() give the same weights
        prev = torch.get_num_threads()
        torch.set_num_threads(self.threads)
        try:
            return self._train_step()
        finally:
            torch.set_num_threads(prev)

    def _train_step(self) -> float:
        c = self.config
        frames, houses, poses = self.batch(self.step)
        x = to_tensor(frames).to(self.device)
        for g in self.opt.param_groups:
            g["lr"] = lr_at(c, self.step)
        self.net.train()
        z = self.net(x)
        if c.objective == "contrastive":
            loss = supcon_loss(F.normalize(z, dim=1), relation_matrix(houses, poses),
                               c.temperature)
        else:
            loss = F.mse_loss(self.decoder(z), x)
        self.opt.zero_grad(set_to_none=True)
        loss.backward()
        self.opt.step()
        self.step += 1
        self.last_loss = float(loss.detach())
        return self.last_loss

    def fit(self, time_budget_s: float | None = None,
            progress: Callable[[int, float], None] | None = None,
            checkpoint: str | os.PathLike[str] | None = None,
            checkpoint_every: int = 100) -> Trainer:
        """Train until ``config.steps`` or until ``time_budget_s`` of this session is spent.

        ``progress(step, loss)`` is called after every step. With ``checkpoint``, a checkpoint
        is written every ``checkpoint_every`` steps and when training stops.
        """
        prev = torch.get_num_threads()
        torch.set_num_threads(self.threads)
        t0 = time.monotonic()
        last = t0
        try:
            while self.step < self.config.steps:
                if time_budget_s is not None and time.monotonic() - t0 >= time_budget_s:
                    break
                loss = self.train_step()
                now = time.monotonic()
                self.elapsed_s += now - last
                last = now
                if progress is not None:
                    progress(self.step, loss)
                if checkpoint is not None and self.step % checkpoint_every == 0:
                    self.save_checkpoint(checkpoint)
        finally:
            torch.set_num_threads(prev)
        if checkpoint is not None:
            self.save_checkpoint(checkpoint)
        return self

    @property
    def done(self) -> bool:
        return self.step >= self.config.steps

    # ------------------------------------------------------------------ persistence
    def save_checkpoint(self, path: str | os.PathLike[str]) -> Path:
        """Write model, optimizer, step and config (atomically)."""
        from kgnav.atomic import atomic_open

        state = {
            "format": CHECKPOINT_FORMAT,
            "config": self.config.to_dict(),
            "step": self.step,
            "elapsed_s": self.elapsed_s,
            "net": self.net.state_dict(),
            "decoder": None if self.decoder is None else self.decoder.state_dict(),
            "optim": self.opt.state_dict(),
        }
        with atomic_open(path, "wb") as fh:
            torch.save(state, fh)
        return Path(path)

    def load_checkpoint(self, path: str | os.PathLike[str]) -> Trainer:
        """Continue from a checkpoint of a run with the same configuration (``steps`` may
        differ: the learning-rate schedule then follows the new ``steps``)."""
        state = read_checkpoint(path)
        theirs = TrainConfig.from_dict(state["config"])
        mine = self.config
        diff = [f"{k}={getattr(theirs, k)!r} (not {getattr(mine, k)!r})"
                for k in mine.to_dict() if k != "steps" and getattr(theirs, k) != getattr(mine, k)]
        if diff:
            raise EncoderWeightsError(path, "checkpoint of another run: " + ", ".join(diff))
        try:
            self.net.load_state_dict(state["net"])
            if self.decoder is not None:
                self.decoder.load_state_dict(state["decoder"])
            self.opt.load_state_dict(state["optim"])
        except (RuntimeError, KeyError, ValueError, TypeError) as exc:
            raise EncoderWeightsError(path, f"checkpoint does not fit the model ({exc})") from None
        self.step = int(state["step"])
        self.elapsed_s = float(state.get("elapsed_s", 0.0))
        return self

    def export(self, threshold: float = PAPER_THRESHOLD,
               threshold_source: str = "paper default (not calibrated)") -> EncoderWeights:
        """The inference weights (BatchNorm folded) with their metadata."""
        from kgnav.encoder.net import fold_batchnorm

        self.net.eval()
        params = {k: v.cpu().numpy() for k, v in fold_batchnorm(self.net).items()}
        c = self.config
        meta = {
            "threshold": float(threshold),
            "threshold_source": threshold_source,
            "train": {**c.to_dict(), "train_steps": self.step, "complete": self.done,
                      "train_seconds": round(self.elapsed_s, 1), "threads": self.threads,
                      "torch": torch.__version__},
        }
        return EncoderWeights(c.arch, params, meta)


def read_checkpoint(path: str | os.PathLike[str]) -> dict:
    """Load a training checkpoint (tensors and plain data only), or raise
    :class:`EncoderWeightsError`."""
    path = Path(path)
    if not path.is_file():
        raise EncoderWeightsError(path, "no such checkpoint")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:
        msg = str(exc).strip().splitlines()
        why = f"{type(exc).__name__}: {msg[0]}" if msg else type(exc).__name__
        raise EncoderWeightsError(path, f"not a readable checkpoint ({why})") from None
    if not isinstance(state, dict) or state.get("format") != CHECKPOINT_FORMAT:
        raise EncoderWeightsError(path, "not a kgnav encoder training checkpoint")
    return state
