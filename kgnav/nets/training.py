"""Seeded, resumable training loops for kgnav's learned parts (encoder, segmenter).

A subclass of :class:`SeededTrainer` builds its modules and optimizer from a frozen config
dataclass (with ``to_dict`` / ``from_dict``, ``seed``, ``steps``, ``lr``, ``warmup``) and
implements :meth:`SeededTrainer._train_step`, drawing the batch of step ``k`` from
``default_rng([seed, k])``. The loop here adds what every such run needs: a time budget, thread
pinning (the thread count changes float reduction order), checkpoints holding modules, optimizer,
step and elapsed time, and resume, so that a run is a pure function of its config (on CPU, for a
given thread count) and a resumed run equals an uninterrupted one.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import torch
from torch import nn

from kgnav.errors import KgnavError


class ConfigDict:
    """Mixin for frozen config dataclasses: JSON-able dict round trip (tuples ↔ lists)."""

    def to_dict(self) -> dict:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, d: dict):
        known = {f.name for f in fields(cls)}
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()
                      if k in known})


@dataclass(frozen=True)
class TrainingConfig(ConfigDict):
    """The fields every training run has; a network's config adds its own."""

    seed: int = 0
    steps: int = 2000
    lr: float = 2e-3
    weight_decay: float = 1e-4
    warmup: int = 50
    split: str = "train-small"  # the houses the shipped weights were trained on
    n_houses: int = 20  # the first n houses of the split
    input_size: tuple[int, int] = (80, 60)  # (width, height) the network sees


def cosine_lr(lr: float, warmup: int, steps: int, step: int) -> float:
    """Linear warm-up over ``warmup`` steps, then cosine decay to zero at ``steps``."""
    if step < warmup:
        return lr * (step + 1) / warmup
    span = max(steps - warmup, 1)
    return 0.5 * lr * (1 + math.cos(math.pi * min((step - warmup) / span, 1.0)))


class SeededTrainer:
    """The training loop shared by kgnav's learned parts; ``fit`` returns ``self``.

    Subclasses set :attr:`checkpoint_format` and :attr:`error` (a :class:`KgnavError` taking
    ``(path, reason)``), create ``self.opt`` and the modules listed by :meth:`modules`, and
    implement :meth:`_train_step` (one optimisation step on the batch of :attr:`step`; it
    increments :attr:`step` and returns the loss).
    """

    checkpoint_format = "kgnav-checkpoint"
    error: type[KgnavError] = KgnavError
    opt: torch.optim.Optimizer

    def __init__(self, config, device: str = "cpu", threads: int = 1):
        self.config = config
        self.device = torch.device(device)
        self.threads = threads
        self.step = 0
        self.elapsed_s = 0.0  # training time over all sessions (checkpoints carry it)
        self.last_loss = math.nan
        self.losses: list[float] = []  # per step, over all sessions (checkpoints carry it)

    def modules(self) -> dict[str, nn.Module | None]:
        """The modules a checkpoint holds, by name (None: absent in this configuration)."""
        raise NotImplementedError

    def _train_step(self) -> float:
        raise NotImplementedError

    def extra_state(self) -> dict:
        """Plain data (lists, numbers) a subclass keeps across sessions; checkpoints carry it."""
        return {}

    def load_extra_state(self, state: dict) -> None:
        """Restore what :meth:`extra_state` returned."""

    def optimise(self, loss: torch.Tensor) -> float:
        """One optimizer step on ``loss``; advances :attr:`step`; returns the loss value."""
        self.opt.zero_grad(set_to_none=True)
        loss.backward()
        self.opt.step()
        self.step += 1
        self.last_loss = float(loss.detach())
        return self.last_loss

    def set_lr(self) -> None:
        """Set the optimizer's learning rate for :attr:`step` (:func:`cosine_lr`)."""
        c = self.config
        for g in self.opt.param_groups:
            g["lr"] = cosine_lr(c.lr, c.warmup, c.steps, self.step)

    # ------------------------------------------------------------------ optimisation
    def train_step(self) -> float:
        """One optimisation step on the batch of :attr:`step`; returns the loss."""
        # pin the thread count so that steps taken here and inside fit() give the same weights
        prev = torch.get_num_threads()
        torch.set_num_threads(self.threads)
        try:
            return self._logged_step()
        finally:
            torch.set_num_threads(prev)

    def _logged_step(self) -> float:
        loss = self._train_step()
        self.losses.append(loss)
        return loss

    def fit(self, time_budget_s: float | None = None,
            progress: Callable[[int, float], None] | None = None,
            checkpoint: str | os.PathLike[str] | None = None,
            checkpoint_every: int = 100):
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
                loss = self._logged_step()
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
        """Write modules, optimizer, step and config (atomically)."""
        from kgnav.common.atomic import atomic_open

        state = {
            "format": self.checkpoint_format,
            "config": self.config.to_dict(),
            "step": self.step,
            "elapsed_s": self.elapsed_s,
            "losses": list(self.losses),
            "extra": self.extra_state(),
            **{k: None if m is None else m.state_dict() for k, m in self.modules().items()},
            "optim": self.opt.state_dict(),
        }
        with atomic_open(path, "wb") as fh:
            torch.save(state, fh)
        return Path(path)

    def load_checkpoint(self, path: str | os.PathLike[str]):
        """Continue from a checkpoint of a run with the same configuration (``steps`` may
        differ: the learning-rate schedule then follows the new ``steps``)."""
        state = read_checkpoint(path, self.checkpoint_format, self.error)
        theirs = type(self.config).from_dict(state["config"])
        mine = self.config
        diff = [f"{k}={getattr(theirs, k)!r} (not {getattr(mine, k)!r})"
                for k in mine.to_dict() if k != "steps" and getattr(theirs, k) != getattr(mine, k)]
        if diff:
            raise self.error(path, "checkpoint of another run: " + ", ".join(diff))
        try:
            for k, m in self.modules().items():
                if m is not None:
                    m.load_state_dict(state[k])
            self.opt.load_state_dict(state["optim"])
        except (RuntimeError, KeyError, ValueError, TypeError) as exc:
            raise self.error(path, f"checkpoint does not fit the model ({exc})") from None
        self.step = int(state["step"])
        self.elapsed_s = float(state.get("elapsed_s", 0.0))
        self.losses = [float(v) for v in state.get("losses", [])]
        self.load_extra_state(state.get("extra") or {})
        return self

    def train_meta(self, curve_every: int = 0) -> dict:
        """What a weight file records about the run that made it; with ``curve_every``, the
        mean loss of every ``curve_every`` steps as ``loss_curve``."""
        meta = {**self.config.to_dict(), "train_steps": self.step, "complete": self.done,
                "train_seconds": round(self.elapsed_s, 1), "threads": self.threads,
                "torch": torch.__version__}
        if curve_every:
            ls = self.losses
            meta["loss_curve"] = [round(sum(ls[i:i + curve_every]) / len(ls[i:i + curve_every]), 4)
                                  for i in range(0, len(ls), curve_every)]
            meta["loss_curve_every"] = curve_every
        return meta


def read_checkpoint(path: str | os.PathLike[str], fmt: str,
                    error: Callable[[str | os.PathLike[str], str], Exception]) -> dict:
    """Load a training checkpoint of format ``fmt`` (tensors and plain data only), or raise
    ``error(path, reason)``."""
    path = Path(path)
    if not path.is_file():
        raise error(path, "no such checkpoint")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:
        msg = str(exc).strip().splitlines()
        why = f"{type(exc).__name__}: {msg[0]}" if msg else type(exc).__name__
        raise error(path, f"not a readable checkpoint ({why})") from None
    if not isinstance(state, dict) or state.get("format") != fmt:
        raise error(path, f"not a {fmt.replace('-checkpoint', '')} training checkpoint")
    return state
