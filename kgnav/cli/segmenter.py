"""``kgnav train-segmenter`` and ``kgnav segmenter-bench``: the learned RGB-D segmenter.

Registered in :mod:`kgnav.cli`; usage errors raise :class:`click.UsageError` (exit 2), data
errors :class:`~kgnav.errors.KgnavError` (exit 1), each reported as one line.
"""

from __future__ import annotations

from pathlib import Path

import click

from kgnav.cli._training import (
    OUT_FILE,
    finished,
    prepare,
    run_training,
    set_threads,
    training_options,
)
from kgnav.nets.segnet.train import SegTrainConfig
from kgnav.sim.episodes import SPLITS

_D = SegTrainConfig()
CALIBRATION_SEED = 3  # frames of the train houses for the score threshold (not training's)


@click.command("train-segmenter")
@click.option("--out", "out", type=OUT_FILE, required=True,
              help="Where to write the weights (.npz).")
@click.option("--seed", default=_D.seed, show_default=True, type=click.IntRange(min=0),
              help="Seed of the initial weights and of every batch.")
@click.option("--steps", default=_D.steps, show_default=True, type=click.IntRange(min=1),
              help="Optimisation steps (the learning rate decays to zero at the last).")
@click.option("--batch", default=_D.batch, show_default=True, type=click.IntRange(min=2),
              help="Frames rendered per step.")
@click.option("--calibrate-frames", default=300, show_default=True,
              type=click.IntRange(min=0),
              help="Train-house frames to calibrate the segment-score threshold on (0: none).")
@click.option("--split", default=_D.split, show_default=True,
              type=click.Choice([s for s in SPLITS if s.startswith("train")]),
              help="Houses to train and calibrate on (the shipped weights: train).")
@training_options(threads_default=1)
def train_segmenter(out: Path, seed: int, steps: int, batch: int, calibrate_frames: int,
                    split: str, time_budget: float | None, resume: bool,
                    checkpoint: Path | None, checkpoint_every: int, device: str, threads: int,
                    quiet: bool) -> None:
    """Train the RGB-D segmenter on frames of the train houses; write weights with metadata.

    The same --seed, --steps and --batch give the same weights (CPU, same --threads). After
    training, the segment-score threshold with the best F1 on frames of the train houses is
    stored with the weights. Val houses are never rendered here: measure on them with
    `kgnav segmenter-bench`.
    """
    from tqdm import tqdm

    from kgnav.nets.segnet.train import SegTrainer

    ckpt, dev = prepare(out, checkpoint, resume, device, threads)
    trainer = SegTrainer(SegTrainConfig(seed=seed, steps=steps, batch=batch, split=split),
                         device=dev, threads=threads)
    run_training(trainer, ckpt, resume, "train-segmenter", time_budget, checkpoint_every, quiet)
    weights = trainer.export()
    if calibrate_frames:
        from kgnav.nets.segnet.bench import calibrate_min_score, render_frames
        from kgnav.nets.segnet.segmenter import LearnedSegmenter

        with tqdm(total=calibrate_frames, desc="calibrating on train frames", unit="frame",
                  disable=quiet, dynamic_ncols=True, mininterval=1.0) as bar:
            frames = render_frames(split, calibrate_frames, seed=CALIBRATION_SEED,
                                   progress=lambda k: bar.update(k - bar.n))
        thr, curve = calibrate_min_score(LearnedSegmenter(weights, device=dev), frames)
        weights.meta["score_threshold"] = thr
        weights.meta["score_threshold_source"] = (
            f"best F1 of instance recall and segment precision on {calibrate_frames} frames "
            f"of the {split} houses, seed {CALIBRATION_SEED}")
        weights.meta["score_threshold_curve"] = curve
    weights.save(out)
    click.echo(f"{finished(trainer)}, {threads} thread(s) on {dev}); score threshold "
               f"{weights.score_threshold:.2f}; weights -> {out}; checkpoint {ckpt}")
    if not trainer.done:
        click.echo(f"continue with: kgnav train-segmenter --resume --out {out} --checkpoint "
                   f"{ckpt} --seed {seed} --steps {steps} --batch {batch} --threads {threads} "
                   f"--calibrate-frames {calibrate_frames} --split {split}", err=True)


_PRESETS = ("clean", "default", "heavy")


def _parse_segmenters(ctx, param, value: str) -> list[str]:
    names = [v.strip() for v in value.split(",") if v.strip()]
    if not names:
        raise click.BadParameter("name at least one segmenter")
    if len(set(names)) != len(names):
        raise click.BadParameter(f"a segmenter is named twice in {value!r}")
    return names


@click.command("segmenter-bench")
@click.option("--split", default="val", show_default=True, type=click.Choice(list(SPLITS)),
              help="Houses to render (val: never seen in training).")
@click.option("--out", "out_dir", required=True,
              type=click.Path(file_okay=False, path_type=Path),
              help="Directory for segmenter_bench.json and confusion.png.")
@click.option("--frames", "n_frames", default=300, show_default=True,
              type=click.IntRange(min=1), help="Frames, drawn from the split's houses in turn.")
@click.option("--segmenters", default="learned," + ",".join(_PRESETS), show_default=True,
              callback=_parse_segmenters,
              help="Comma-separated segmenter names (learned, clean, default, heavy, ...).")
@click.option("--weights", type=click.Path(dir_okay=False, path_type=Path),
              help="Weight file for the learned segmenter [default: the shipped weights].")
@click.option("--seed", default=1, show_default=True, type=click.IntRange(min=0),
              help="Seed of the frames (and of the noise presets).")
@click.option("--object-share", default=0.5, show_default=True,
              type=click.FloatRange(0, 1), help="Share of frames aimed at an object.")
@click.option("--quiet", is_flag=True, help="No progress bar.")
def segmenter_bench(split: str, out_dir: Path, n_frames: int, segmenters: list[str],
                    weights: Path | None, seed: int, object_share: float, quiet: bool) -> None:
    """IoU, instance precision/recall by distance and size, false positives, confusions and
    time per frame of segmenters on the same rendered frames."""
    import json

    from rich.console import Console
    from tqdm import tqdm

    from kgnav.agent.segmentation import make_segmenter
    from kgnav.common.atomic import atomic_open
    from kgnav.errors import KgnavError
    from kgnav.nets.segnet.bench import bench, plot_confusion, render_frames

    if out_dir.exists() and not out_dir.is_dir():
        raise click.BadParameter(f"{out_dir} is not a directory", param_hint="--out")
    segs = []
    for name in segmenters:
        params = {"weights": weights} if name in ("learned", "kgnav-segnet") and weights else {}
        try:
            segs.append((name, make_segmenter(name, seed, **params)))
        except KgnavError as exc:
            if "unknown segmenter" in str(exc):
                raise click.BadParameter(str(exc), param_hint="--segmenters") from None
            raise
    set_threads(1)
    with tqdm(total=n_frames, desc=f"rendering {split} frames", unit="frame", disable=quiet,
              dynamic_ncols=True, mininterval=1.0) as bar:
        frames = render_frames(split, n_frames, seed, object_share,
                               progress=lambda k: bar.update(k - bar.n))
    with tqdm(total=n_frames * len(segs), desc="segmenting", unit="frame", disable=quiet,
              dynamic_ncols=True, mininterval=1.0) as bar:
        def progress(label: str, k: int) -> None:
            bar.update(1)
            bar.set_postfix(segmenter=label, refresh=False)

        scorers = bench(segs, frames, progress=progress)
    results = {label: {"name": seg.name, **scorers[label].report()} for label, seg in segs}
    report = {"format": "kgnav-segmenter-bench", "version": 1, "split": split, "seed": seed,
              "frames": n_frames, "object_share": object_share,
              "houses": sorted(set(frames.scenes)), "min_pixels": 20, "segmenters": results}
    out_dir.mkdir(parents=True, exist_ok=True)
    with atomic_open(out_dir / "segmenter_bench.json", "w") as fh:
        json.dump(report, fh, indent=1)
    plot_confusion({label: scorers[label].conf for label in list(scorers)[:2]},
                   out_dir / "confusion.png",
                   title=f"pixel confusion on {split}: {n_frames} frames, seed {seed}")
    con = Console(highlight=False, soft_wrap=True)
    if not con.is_terminal:  # a log file or pipe: do not squeeze the table to 80 columns
        con = Console(highlight=False, soft_wrap=True, width=140)
    con.print(bench_table(results, f"segmenters on {split}: {n_frames} frames, seed {seed}"))
    for label, r in results.items():
        pairs = ", ".join(f"{t}->{p} {n}" for t, p, n in r["confusion_pairs"][:8]) or "none"
        con.print(f"{label}: mislabelled segments (true->predicted): {pairs}")
    con.print(f"wrote {out_dir / 'segmenter_bench.json'} and {out_dir / 'confusion.png'}")


def bench_table(results: dict, title: str):
    """The bench's side-by-side table (rich)."""
    from rich.table import Table

    from kgnav.nets.segnet.bench import DIST_BANDS, SIZE_BANDS

    table = Table("figure", *results, title=title)

    def row(label: str, get) -> None:
        table.add_row(label, *(_fmt(get(r)) for r in results.values()))

    row("mean IoU (classes present)", lambda r: r["mean_iou"])
    row("mean IoU, 6 goal classes", lambda r: r["mean_iou_goal"])
    row("instance recall (all / goal)", lambda r: (r["recall"], r["recall_goal"]))
    row("segment precision", lambda r: r["precision"])
    for _, _, band in DIST_BANDS:
        row(f"recall / precision {band}", lambda r, b=band: (
            r["recall_by_distance"].get(b, {}).get("value"),
            r["precision_by_distance"].get(b, {}).get("value")))
    for _, _, band in SIZE_BANDS:
        row(f"recall / precision {band}", lambda r, b=band: (
            r["recall_by_size"].get(b, {}).get("value"),
            r["precision_by_size"].get(b, {}).get("value")))
    row("false-positive segments / frame", lambda r: r["fp_per_frame"])
    row("  on background / of a goal class", lambda r: (r["fp_background_per_frame"],
                                                        r["fp_goal_per_frame"]))
    row("objects mislabelled in most / all views", lambda r: (
        r["persistence"]["mislabelled_in_most_views"],
        r["persistence"]["mislabelled_in_all_views"]))
    row("ms / frame (median, p90)", lambda r: (r["ms_per_frame"]["median"],
                                               r["ms_per_frame"]["p90"]))
    return table


def _fmt(v) -> str:
    if isinstance(v, tuple):
        return " / ".join(_fmt(x) for x in v)
    if v is None:
        return "—"
    return f"{v:.3f}" if isinstance(v, float) else str(v)
