"""What the training commands (``train-encoder``, ``train-segmenter``) share: argument checks,
the common options and the resumable run with a progress bar.

Usage errors raise :class:`click.BadParameter` (exit 2); data errors (a checkpoint of another
run) :class:`~kgnav.errors.KgnavError` (exit 1), each reported as one line by :mod:`kgnav.cli`.
"""

from __future__ import annotations

import os
from pathlib import Path

import click

OUT_FILE = click.Path(dir_okay=False, path_type=Path)
#: Scenes of another environment's split walked unless ``--scenes`` says.
ENV_SCENES = 12
DEVICE = click.Choice(["auto", "cpu", "cuda"])


def device_option(value: str) -> str:
    """``--device`` resolved (auto → cuda when available), or a usage error."""
    from kgnav.nets.encoder.extractor import resolve_device

    try:
        return str(resolve_device(value))
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--device") from None


def writable_file(path: Path, hint: str) -> None:
    """A usage error unless ``path`` can be created or replaced."""
    parent = path.parent if str(path.parent) else Path(".")
    if path.is_dir():
        raise click.BadParameter(f"{path} is a directory", param_hint=hint)
    if parent.exists() and not parent.is_dir():
        raise click.BadParameter(f"{parent} is not a directory", param_hint=hint)
    probe = parent
    while not probe.exists():
        probe = probe.parent
    if not os.access(probe, os.W_OK):
        raise click.BadParameter(f"cannot write under {probe}", param_hint=hint)


def set_threads(threads: int) -> None:
    import torch

    torch.set_num_threads(threads)


def training_options(threads_default: int = 1):
    """The options every training command takes: --time-budget, --resume, --checkpoint,
    --checkpoint-every, --device, --threads, --quiet."""
    opts = [
        click.option("--time-budget", type=click.FloatRange(min=0, min_open=True),
                     metavar="MIN", help="Stop after this many minutes of training "
                                         "(checkpointed; --resume goes on)."),
        click.option("--resume", is_flag=True, help="Continue from --checkpoint."),
        click.option("--checkpoint", type=OUT_FILE,
                     help="Training checkpoint [default: --out with suffix .ckpt]."),
        click.option("--checkpoint-every", default=100, show_default=True,
                     type=click.IntRange(min=1), help="Steps between checkpoints."),
        click.option("--device", default="auto", show_default=True, type=DEVICE,
                     help="auto: cuda when available, else cpu."),
        click.option("--threads", default=threads_default, show_default=True,
                     type=click.IntRange(min=1),
                     help="CPU threads (results are reproducible for a given thread count)."),
        click.option("--quiet", is_flag=True, help="No progress bar."),
    ]

    def deco(f):
        for o in reversed(opts):
            f = o(f)
        return f

    return deco


def prepare(out: Path, checkpoint: Path | None, resume: bool, device: str,
            threads: int) -> tuple[Path, str]:
    """Check the output and checkpoint paths, pin the threads; (checkpoint path, device)."""
    writable_file(out, "--out")
    ckpt = checkpoint or out.with_suffix(".ckpt")
    writable_file(ckpt, "--checkpoint")
    if resume and not ckpt.is_file():
        raise click.BadParameter(f"no checkpoint at {ckpt} to resume from",
                                 param_hint="--resume")
    dev = device_option(device)
    set_threads(threads)
    return ckpt, dev


def run_training(trainer, ckpt: Path, resume: bool, desc: str, time_budget: float | None,
                 checkpoint_every: int, quiet: bool) -> None:
    """Resume (when asked) and fit ``trainer`` (a :class:`~kgnav.nets.training.SeededTrainer`)
    with a progress bar, within ``time_budget`` minutes, checkpointing to ``ckpt``."""
    from tqdm import tqdm

    steps = trainer.config.steps
    if resume:
        trainer.load_checkpoint(ckpt)
        click.echo(f"resuming {ckpt} at step {trainer.step}/{steps}", err=True)
    with tqdm(total=steps, initial=trainer.step, desc=desc, unit="step", disable=quiet,
              dynamic_ncols=True, mininterval=1.0) as bar:
        def progress(step: int, loss: float) -> None:
            bar.update(step - bar.n)
            bar.set_postfix(loss=f"{loss:.3f}", refresh=False)

        budget = None if time_budget is None else 60.0 * time_budget
        trainer.fit(time_budget_s=budget, progress=progress, checkpoint=ckpt,
                    checkpoint_every=checkpoint_every)


def finished(trainer) -> str:
    """``done at step k/n (m min of training`` or the time-budget variant."""
    state = "done" if trainer.done else "stopped by --time-budget"
    return (f"{state} at step {trainer.step}/{trainer.config.steps} "
            f"({trainer.elapsed_s / 60:.1f} min of training")


def env_suite(env_name: str, split: str, min_scenes: int = 1,
              too_few: str = "has no scenes"):
    """An environment's split (:func:`kgnav.envs.make_env`), or a usage error naming the
    option: it does not load, or has fewer than ``min_scenes`` scenes (the error says
    ``too_few``, ``{n}`` standing for the split's scenes)."""
    from kgnav.envs import EnvOptions, make_env
    from kgnav.errors import KgnavError

    try:
        suite = make_env(env_name, EnvOptions(split=split))
    except KgnavError as exc:
        raise click.BadParameter(str(exc), param_hint="--env/--split") from None
    if len(suite) < min_scenes:
        raise click.BadParameter(f"environment {env_name!r} split {split!r} "
                                 + too_few.format(n=len(suite)), param_hint="--split")
    return suite


def walk_env(views, env_name: str, split: str, scenes: int | None, walk_steps: int, seed: int,
             desc: str, quiet: bool, *, min_scenes: int = 1,
             too_few: str = "has no scenes"):
    """``views.from_suite`` over the first ``scenes`` scenes of an environment's split
    (:func:`env_suite`), walked through its protocol with a progress bar (``views``: the
    encoder's :class:`~kgnav.nets.encoder.env_views.EnvViewSampler` or the segmenter's
    :class:`~kgnav.nets.segnet.env_data.EnvLabelledViews`)."""
    from tqdm import tqdm

    suite = env_suite(env_name, split, min_scenes, too_few)
    n = min(scenes or ENV_SCENES, len(suite))
    with tqdm(total=n * walk_steps, desc=desc, unit="view", disable=quiet, dynamic_ncols=True,
              mininterval=1.0) as bar:
        return views.from_suite(suite, range(n), walk_steps, seed,
                                progress=lambda done, total: bar.update(done - bar.n))
