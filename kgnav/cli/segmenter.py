"""``kgnav train-segmenter`` and ``kgnav segmenter-bench``: the learned RGB-D segmenter.

Registered in :mod:`kgnav.cli`; usage errors raise :class:`click.UsageError` (exit 2), data
errors :class:`~kgnav.errors.KgnavError` (exit 1), each reported as one line.
"""

from __future__ import annotations

from pathlib import Path

import click

from kgnav.agent.noise_segmenters import GROUND_TRUTH_SEGMENTERS
from kgnav.cli._training import (
    ENV_SCENES,
    OUT_FILE,
    env_suite,
    finished,
    prepare,
    run_training,
    set_threads,
    training_options,
    walk_env,
)
from kgnav.cli.encoder import KGNAV, domain, env_options
from kgnav.nets.segnet.train import SegTrainConfig, training_houses
from kgnav.sim.episodes import SPLITS

_D = SegTrainConfig()
CALIBRATION_SEED = 3  # frames of the train houses for the score threshold (not training's)


def _walk(env_name: str, split: str, scenes: int | None, walk_steps: int, seed: int,
          desc: str, quiet: bool):
    """Labelled views of an environment's split walked through its protocol
    (:class:`~kgnav.nets.segnet.env_data.EnvLabelledViews`)."""
    from kgnav.nets.segnet.env_data import EnvLabelledViews

    return walk_env(EnvLabelledViews, env_name, split, scenes, walk_steps, seed, desc, quiet)


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
@click.option("--split", default=None,
              help="Scenes to train and calibrate on [default: train; for kgnav one of "
                   f"{', '.join(s for s in SPLITS if s.startswith('train'))}].")
@click.option("--scenes-dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Train and calibrate on houses of your own instead of --split: a "
                   "directory written by 'kgnav scenes generate' (--scenes N: its first N).")
@env_options
@training_options(threads_default=1)
def train_segmenter(out: Path, seed: int, steps: int, batch: int, calibrate_frames: int,
                    split: str | None, scenes_dir: Path | None, env_name: str,
                    scenes: int | None, walk_steps: int,
                    time_budget: float | None, resume: bool, checkpoint: Path | None,
                    checkpoint_every: int, device: str, threads: int, quiet: bool) -> None:
    """Train the RGB-D segmenter on frames of the train houses; write weights with metadata.

    The same --seed, --steps and --batch give the same weights (CPU, same --threads). After
    training, the segment-score threshold with the best F1 on frames of the train houses is
    stored with the weights. Val houses are never rendered here: measure on them with
    `kgnav segmenter-bench`. With --env, the frames are walked through another environment's
    protocol and labelled by its semantic channel (at training time only); the weights then
    label its classes and record it as their domain, which `kgnav eval --env` checks.
    """
    from kgnav.nets.segnet.train import SegTrainer

    kgnav_env = env_name == KGNAV
    split = split or _D.split
    trains = [s for s in SPLITS if s.startswith("train")]
    if kgnav_env and split not in trains:
        raise click.BadParameter(f"{split!r} is not one of {', '.join(trains)}",
                                 param_hint="--split")
    houses = None
    if scenes_dir is not None:
        if not kgnav_env:
            raise click.BadParameter("houses of your own are kgnav's; another environment's "
                                     "scenes are named by --split", param_hint="--scenes-dir")
        from kgnav.sim.scene_dir import SceneDir

        sd = SceneDir(scenes_dir)  # a missing or empty directory: one line, exit 1
        houses = min(scenes or len(sd), len(sd))
    ckpt, dev = prepare(out, checkpoint, resume, device, threads)
    if kgnav_env:
        sampler = None
        cfg = SegTrainConfig(seed=seed, steps=steps, batch=batch, split=split,
                             n_houses=houses or scenes or _D.n_houses,
                             scenes_dir=None if scenes_dir is None else str(scenes_dir))
    else:
        sampler = _walk(env_name, split, scenes, walk_steps, seed,
                        f"walking {env_name} {split}", quiet)
        cfg = SegTrainConfig(seed=seed, steps=steps, batch=batch, split=split,
                             n_houses=len(sampler), env=env_name, classes=sampler.classes,
                             walk_steps=walk_steps)
    trainer = SegTrainer(cfg, device=dev, sampler=sampler, threads=threads)
    run_training(trainer, ckpt, resume, "train-segmenter", time_budget, checkpoint_every, quiet)
    weights = trainer.export()
    if calibrate_frames:
        _calibrate(weights, env_name, split, scenes, calibrate_frames, dev, quiet,
                   houses=None if scenes_dir is None else (scenes_dir, training_houses(cfg)))
    weights.save(out)
    click.echo(f"{finished(trainer)}, {threads} thread(s) on {dev}); score threshold "
               f"{weights.score_threshold:.2f}; weights -> {out}; checkpoint {ckpt}")
    if not trainer.done:
        more = ((f" --scenes-dir {scenes_dir} --scenes {cfg.n_houses}" if scenes_dir else "")
                if kgnav_env else (f" --env {env_name} --walk-steps {walk_steps}"
                                   f" --scenes {len(sampler)}"))
        click.echo(f"continue with: kgnav train-segmenter --resume --out {out} --checkpoint "
                   f"{ckpt} --seed {seed} --steps {steps} --batch {batch} --threads {threads} "
                   f"--calibrate-frames {calibrate_frames} --split {split}{more}", err=True)


def _calibrate(weights, env_name: str, split: str, scenes: int | None, n: int, dev: str,
               quiet: bool, houses: tuple[Path, list] | None = None) -> None:
    """Store in ``weights`` the segment-score threshold with the best F1 on ``n`` frames of
    the training scenes (seed :data:`CALIBRATION_SEED`, not the training frames); ``houses``:
    (a scenes directory, the houses of it trained on) instead of the split's."""
    import math

    from tqdm import tqdm

    from kgnav.nets.segnet.bench import calibrate_min_score, render_frames, walked_frames
    from kgnav.nets.segnet.segmenter import LearnedSegmenter

    if env_name == KGNAV:
        with tqdm(total=n, desc="calibrating on training-house frames", unit="frame",
                  disable=quiet, dynamic_ncols=True, mininterval=1.0) as bar:
            source, where = ((split, f"the {split} houses") if houses is None
                             else (houses[1], f"the houses of {houses[0]}"))
            frames = render_frames(source, n, seed=CALIBRATION_SEED,
                                   progress=lambda k: bar.update(k - bar.n))
    else:
        # twice as many views as frames drawn, so that the class-balanced draw has a choice
        views = _walk(env_name, split, scenes, max(10, math.ceil(2 * n / (scenes or ENV_SCENES))),
                      CALIBRATION_SEED, f"walking {env_name} {split} to calibrate", quiet)
        frames = walked_frames(views, n, CALIBRATION_SEED)
        where = f"environment {env_name}'s {split} scenes (walked)"
    thr, curve = calibrate_min_score(LearnedSegmenter(weights, device=dev), frames)
    weights.meta["score_threshold"] = thr
    weights.meta["score_threshold_source"] = (
        f"best F1 of instance recall and segment precision on {n} frames of {where}, seed "
        f"{CALIBRATION_SEED}")
    weights.meta["score_threshold_curve"] = curve


_PRESETS = ("clean", "default", "heavy")


def _parse_segmenters(ctx, param, value: str) -> list[str]:
    names = [v.strip() for v in value.split(",") if v.strip()]
    if not names:
        raise click.BadParameter("name at least one segmenter")
    if len(set(names)) != len(names):
        raise click.BadParameter(f"a segmenter is named twice in {value!r}")
    return names


@click.command("segmenter-bench")
@click.option("--split", default="val", show_default=True,
              help=f"Houses to render (val: never seen in training); for kgnav one of "
                   f"{', '.join(SPLITS)}, another environment's own names otherwise.")
@click.option("--scenes-dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Render your own houses instead of --split: a directory written by "
                   "'kgnav scenes generate' (houses no split and no training used are where "
                   "a segmenter is judged fairly).")
@click.option("--out", "out_dir", required=True,
              type=click.Path(file_okay=False, path_type=Path),
              help="Directory for segmenter_bench.json and confusion.png.")
@click.option("--frames", "n_frames", default=300, show_default=True,
              type=click.IntRange(min=1), help="Frames, drawn from the split's houses in turn.")
@click.option("--segmenters", default="learned," + ",".join(_PRESETS), show_default=True,
              callback=_parse_segmenters,
              help="Comma-separated segmenter names (learned, clean, default, heavy, ...).")
@click.option("--weights", type=click.Path(dir_okay=False, path_type=Path),
              help="Weight file for the learned segmenter [default: the ones --env names as its "
                   "own, else the shipped weights].")
@click.option("--seed", default=1, show_default=True, type=click.IntRange(min=0),
              help="Seed of the frames (and of the noise presets).")
@click.option("--object-share", default=0.5, show_default=True,
              type=click.FloatRange(0, 1), help="Share of frames aimed at an object.")
@env_options
@click.option("--quiet", is_flag=True, help="No progress bar.")
def segmenter_bench(split: str, scenes_dir: Path | None, out_dir: Path, n_frames: int,
                    segmenters: list[str],
                    weights: Path | None, seed: int, object_share: float, env_name: str,
                    scenes: int | None, walk_steps: int, quiet: bool) -> None:
    """IoU, instance precision/recall by distance and size, false positives, confusions and
    time per frame of segmenters on the same rendered frames.

    With --env, on frames walked through another environment's protocol, scored against its
    semantic channel in its vocabulary (a segmenter labelling other classes is mapped to it by
    name, the rest dropped); frames "aimed at an object" are walked frames showing one.
    """
    import json

    from tqdm import tqdm

    from kgnav.agent.segmentation import make_segmenter
    from kgnav.cli._output import wide_console
    from kgnav.common.atomic import atomic_open
    from kgnav.common.classes import OBJECT_CLASSES
    from kgnav.errors import KgnavError
    from kgnav.nets.segnet.bench import bench, plot_confusion, render_frames, walked_frames

    kgnav_env = env_name == KGNAV
    if scenes_dir is not None and not kgnav_env:
        raise click.BadParameter("houses of your own are kgnav's; another environment's scenes "
                                 "are named by --split", param_hint="--scenes-dir")
    if kgnav_env and scenes_dir is None and split not in SPLITS:
        raise click.BadParameter(f"{split!r} is not one of {', '.join(SPLITS)}",
                                 param_hint="--split")
    houses = None
    if scenes_dir is not None:
        from kgnav.sim.scene_dir import SceneDir

        sd = SceneDir(scenes_dir)  # a missing or empty directory: one line, exit 1
        houses = sd.scenes(min(scenes or len(sd), len(sd)))
    if out_dir.exists() and not out_dir.is_dir():
        raise click.BadParameter(f"{out_dir} is not a directory", param_hint="--out")
    # the segmenters first: a bad name is a usage error before any frame is rendered
    classes, truth = (OBJECT_CLASSES, {}) if kgnav_env else _env_truth(env_name, split)
    if weights is None:
        from kgnav.envs import env_weights

        weights = env_weights(env_name).get("segmenter")
    segs = []
    for name in segmenters:
        params = {"weights": weights} if name in ("learned", "kgnav-segnet") and weights else {}
        if name in GROUND_TRUTH_SEGMENTERS:
            params = truth  # the presets label the environment's classes, sized by its camera
        try:
            segs.append((name, make_segmenter(name, seed, **params)))
        except KgnavError as exc:
            if "unknown segmenter" in str(exc):
                raise click.BadParameter(str(exc), param_hint="--segmenters") from None
            raise
    set_threads(1)
    if kgnav_env:
        with tqdm(total=n_frames, desc=f"rendering {split if houses is None else scenes_dir} "
                                       f"frames", unit="frame",
                  disable=quiet, dynamic_ncols=True, mininterval=1.0) as bar:
            frames = render_frames(houses or split, n_frames, seed, object_share,
                                   progress=lambda k: bar.update(k - bar.n))
    else:
        views = _walk(env_name, split, scenes, walk_steps, seed, f"walking {env_name} {split}",
                      quiet)
        frames = walked_frames(views, n_frames, seed, object_share)
    with tqdm(total=n_frames * len(segs), desc="segmenting", unit="frame", disable=quiet,
              dynamic_ncols=True, mininterval=1.0) as bar:
        def progress(label: str, k: int) -> None:
            bar.update(1)
            bar.set_postfix(segmenter=label, refresh=False)

        scorers = bench(segs, frames, progress=progress, classes=classes)
    results = {label: {"name": seg.name, **scorers[label].report()} for label, seg in segs}
    where = domain(env_name, split) if houses is None else f"the houses of {scenes_dir}"
    report = {"format": "kgnav-segmenter-bench", "version": 1, "env": env_name,
              "classes": list(classes), "split": None if houses else split,
              "scenes_dir": None if scenes_dir is None else str(scenes_dir), "seed": seed,
              "frames": n_frames, "object_share": object_share,
              "houses": sorted(set(frames.scenes)), "min_pixels": 20, "segmenters": results}
    out_dir.mkdir(parents=True, exist_ok=True)
    with atomic_open(out_dir / "segmenter_bench.json", "w") as fh:
        json.dump(report, fh, indent=1)
    plot_confusion({label: scorers[label].conf for label in list(scorers)[:2]},
                   out_dir / "confusion.png",
                   title=f"pixel confusion on {where}: {n_frames} frames, "
                         f"seed {seed}", classes=classes)
    con = wide_console(soft_wrap=True)
    con.print(bench_table(results, f"segmenters on {where}: {n_frames} "
                                   f"frames, seed {seed}"))
    for label, r in results.items():
        pairs = ", ".join(f"{t}->{p} {n}" for t, p, n in r["confusion_pairs"][:8]) or "none"
        con.print(f"{label}: mislabelled segments (true->predicted): {pairs}")
    con.print(f"wrote {out_dir / 'segmenter_bench.json'} and {out_dir / 'confusion.png'}")


def _env_truth(env_name: str, split: str) -> tuple[tuple[str, ...], dict]:
    """An environment's vocabulary, and what a noise preset needs of it: its camera and that
    vocabulary (no frame is rendered here)."""
    from kgnav.agent.camera import Camera

    spec = env_suite(env_name, split).make(0, 1).env_spec
    cam = Camera.from_spec(spec.camera)
    return spec.classes, {"hfov_deg": cam.hfov_deg, "min_depth": cam.min_depth,
                          "max_depth": cam.max_depth, "classes": spec.classes}


def bench_table(results: dict, title: str):
    """The bench's side-by-side table (rich)."""
    from rich.table import Table

    from kgnav.nets.segnet.bench import DIST_BANDS, SIZE_BANDS

    table = Table("figure", *results, title=title)

    def row(label: str, get) -> None:
        table.add_row(label, *(_fmt(get(r)) for r in results.values()))

    row("mean IoU (classes present)", lambda r: r["mean_iou"])
    row("mean IoU, goal classes", lambda r: r["mean_iou_goal"])
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
