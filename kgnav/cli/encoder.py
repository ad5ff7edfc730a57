"""``kgnav train-encoder`` and ``kgnav relocation-bench``: the learned state-feature encoder.

Registered in :mod:`kgnav.cli`; usage errors raise :class:`click.UsageError` (exit 2), data
errors :class:`~kgnav.errors.KgnavError` (exit 1), each reported as one line.
"""

from __future__ import annotations

import json
from pathlib import Path

import click

from kgnav.cli._training import (
    DEVICE,
    OUT_FILE,
    device_option,
    finished,
    prepare,
    run_training,
    set_threads,
    training_options,
    walk_env,
)
from kgnav.errors import KgnavError
from kgnav.sim.episodes import SPLITS

#: Where the shipped threshold was calibrated (the first generator's val houses).
CALIBRATION_SPLIT = "val-small"
KGNAV = "kgnav"  # kgnav's own simulator: renders views from any pose, no walking needed


def env_options(f):
    """--env, --scenes and --walk-steps: the frames of any registered environment."""
    opts = [
        click.option("--env", "env_name", default=KGNAV, show_default=True, metavar="NAME",
                     help="Environment whose frames to use (kgnav.envs: a registered name or "
                          "MODULE:FACTORY). kgnav's simulator renders views from any pose; "
                          "another environment's views come from seeded random walks through "
                          "its protocol."),
        click.option("--scenes", type=click.IntRange(min=2), default=None,
                     help="Use the first N scenes of the split [default: all; 12 for another "
                          "environment]."),
        click.option("--walk-steps", default=400, show_default=True,
                     type=click.IntRange(min=10),
                     help="Views walked per scene (environments other than kgnav)."),
    ]
    for o in reversed(opts):
        f = o(f)
    return f


def _kgnav_split(split: str, allowed: list[str], hint: str = "--split") -> str:
    if split not in allowed:
        raise click.BadParameter(f"{split!r} is not one of {', '.join(allowed)}",
                                 param_hint=hint)
    return split


def env_sampler(env_name: str, split: str, scenes: int | None, walk_steps: int, seed: int,
                desc: str, quiet: bool):
    """Views of an environment's split walked through its protocol
    (:class:`~kgnav.nets.encoder.env_views.EnvViewSampler`), two scenes at least."""
    from kgnav.nets.encoder.env_views import EnvViewSampler

    return walk_env(EnvViewSampler, env_name, split, scenes, walk_steps, seed, desc, quiet,
                    min_scenes=2, too_few="has {n} scene(s); calibration needs two")


def domain(env_name: str, split: str) -> str:
    """How weight files and reports name the frames' visual domain."""
    return f"split {split}" if env_name == KGNAV else f"environment {env_name}, split {split}"


@click.command("train-encoder")
@click.option("--out", "out", type=OUT_FILE, required=True,
              help="Where to write the weights (.npz).")
@click.option("--seed", default=0, show_default=True, type=click.IntRange(min=0),
              help="Seed of the initial weights and of every batch.")
@click.option("--dim", default=128, show_default=True, type=click.IntRange(min=1, max=8192),
              help="Feature dimension.")
@click.option("--steps", default=2000, show_default=True, type=click.IntRange(min=1),
              help="Optimisation steps (the learning rate decays to zero at the last).")
@click.option("--objective", default="contrastive", show_default=True,
              type=click.Choice(["contrastive", "autoencoder"]),
              help="Pose-based contrastive learning, or a Taskonomy-style autoencoder.")
@click.option("--houses-per-batch", default=8, show_default=True, type=click.IntRange(min=1),
              help="Train houses drawn per batch.")
@click.option("--places-per-house", default=8, show_default=True, type=click.IntRange(min=1),
              help="Places per house per batch (each seen from 3 views).")
@click.option("--calibrate-pairs", default=2000, show_default=True, type=click.IntRange(min=0),
              help="Val places to calibrate the match threshold on (0: keep the paper's 0.3).")
@click.option("--split", default=None,
              help="Scenes to train on [default: train-small for kgnav (the shipped weights), "
                   "train for another environment].")
@click.option("--calibration-split", default=None,
              help="Scenes to calibrate the threshold on [default: val-small for kgnav, val "
                   "for another environment].")
@env_options
@training_options(threads_default=1)
def train_encoder(out: Path, seed: int, dim: int, steps: int, objective: str,
                  houses_per_batch: int, places_per_house: int, split: str | None,
                  calibration_split: str | None, env_name: str, scenes: int | None,
                  walk_steps: int, time_budget: float | None, resume: bool,
                  checkpoint: Path | None, checkpoint_every: int, calibrate_pairs: int,
                  device: str, threads: int, quiet: bool) -> None:
    """Train the state-feature encoder on the train houses; write weights with metadata.

    The same --seed, --steps, --dim and --objective give the same weights (CPU, same
    --threads). After training the match threshold is calibrated on val views
    (relocation-bench's pairs, seed 0) and stored in the weight file. With --env, both come
    from another environment's frames: the weights and their threshold then belong to that
    environment's visual domain.
    """
    from tqdm import tqdm

    from kgnav.nets.encoder.train import TrainConfig, Trainer

    kgnav_env = env_name == KGNAV
    if kgnav_env:
        split = _kgnav_split(split or "train-small", [s for s in SPLITS if s.startswith("train")])
        cal_split = _kgnav_split(calibration_split or CALIBRATION_SPLIT, list(SPLITS),
                                 "--calibration-split")
    else:
        split, cal_split = split or "train", calibration_split or "val"
    ckpt, dev = prepare(out, checkpoint, resume, device, threads)
    sampler = None
    if not kgnav_env:
        sampler = env_sampler(env_name, split, scenes, walk_steps, seed,
                              f"walking {env_name} {split}", quiet)
    cfg = TrainConfig(seed=seed, steps=steps, dim=dim, objective=objective,
                      houses_per_batch=houses_per_batch, places_per_house=places_per_house,
                      split=split if kgnav_env else f"{env_name}:{split}",
                      n_houses=(scenes or 20) if kgnav_env else len(sampler))
    trainer = Trainer(cfg, device=dev, sampler=sampler, threads=threads)
    run_training(trainer, ckpt, resume, f"train-encoder ({objective})", time_budget,
                 checkpoint_every, quiet)
    weights = trainer.export()
    if calibrate_pairs:
        from kgnav.nets.encoder.calibration import (
            CALIBRATION_SEED,
            TARGET_PRECISION,
            build_pairs,
            calibrate,
            pair_distances,
        )
        from kgnav.nets.encoder.extractor import LearnedEncoder

        enc = LearnedEncoder(weights, device=dev)
        views = (_sampler(cal_split) if kgnav_env else
                 env_sampler(env_name, cal_split, scenes, walk_steps, CALIBRATION_SEED,
                             f"walking {env_name} {cal_split}", quiet))
        with tqdm(total=3 * calibrate_pairs, desc=f"calibrating on {cal_split}",
                  unit="view", disable=quiet, dynamic_ncols=True, mininterval=1.0) as bar:
            ps = build_pairs(views, [enc], n_pos=calibrate_pairs, seed=CALIBRATION_SEED,
                             progress=lambda done, total: bar.update(done - bar.n))
        thr = calibrate(pair_distances(ps.features[enc.name], ps.pairs), ps.labels)
        weights.meta["threshold"] = round(thr, 6)
        weights.meta["threshold_source"] = (
            f"calibrated: largest with precision >= {TARGET_PRECISION} on relocation-bench "
            f"pairs of {domain(env_name, cal_split)}, {calibrate_pairs} places, seed "
            f"{CALIBRATION_SEED}")
    if not kgnav_env:
        weights.meta["domain"] = {"env": env_name, "train_split": split,
                                  "calibration_split": cal_split if calibrate_pairs else None,
                                  "walk_steps": walk_steps, "scenes": len(sampler)}
    weights.save(out)
    click.echo(f"{finished(trainer)}); weights -> {out} (dim {dim}, threshold "
               f"{weights.threshold:.4f}); checkpoint {ckpt}")
    if not trainer.done:
        more = "" if kgnav_env else (f" --env {env_name} --walk-steps {walk_steps}"
                                     f" --scenes {len(sampler)}")
        click.echo(f"continue with: kgnav train-encoder --resume --out {out} --checkpoint "
                   f"{ckpt} --seed {seed} --dim {dim} --steps {steps} --objective {objective} "
                   f"--houses-per-batch {houses_per_batch} --places-per-house "
                   f"{places_per_house} --split {split}{more}", err=True)


def _sampler(split: str):
    from kgnav.nets.encoder.views import ViewSampler
    from kgnav.sim.episodes import load_scene_of

    return ViewSampler([load_scene_of(split, k) for k in range(len(SPLITS[split]))])


def _parse_extractors(ctx, param, value: str) -> list[str]:
    names = [v.strip() for v in value.split(",") if v.strip()]
    if not names:
        raise click.BadParameter("name at least one extractor")
    if len(set(names)) != len(names):
        raise click.BadParameter(f"an extractor is named twice in {value!r}")
    return names


def _parse_thresholds(ctx, param, values: tuple[str, ...]) -> dict[str, float]:
    out = {}
    for v in values:
        name, _, num = v.partition("=")
        try:
            t = float(num)
        except ValueError:
            t = float("nan")
        if not name or not 0 < t <= 2:
            raise click.BadParameter(f"expected NAME=DISTANCE with 0 < DISTANCE <= 2, got {v!r}")
        out[name] = t
    return out


@click.command("relocation-bench")
@click.option("--split", default=None,
              help="Houses to draw views from [default: val-small for kgnav (the shipped "
                   "encoder was trained on train-small and calibrated there), val for another "
                   "environment].")
@click.option("--out", "out_dir", required=True,
              type=click.Path(file_okay=False, path_type=Path),
              help="Directory for relocation.json and relocation_roc.png.")
@click.option("--extractors", default="kgnav-encoder,opencv-gist", show_default=True,
              callback=_parse_extractors, help="Comma-separated extractor names.")
@click.option("--pairs", default=1000, show_default=True, type=click.IntRange(min=2),
              help="Places, i.e. positive pairs (each comes with 6 negative pairs).")
@click.option("--seed", default=1, show_default=True, type=click.IntRange(min=0),
              help="Seed of the views (the shipped threshold was calibrated on seed 0).")
@click.option("--weights", type=click.Path(dir_okay=False, path_type=Path),
              help="Encoder weight file for kgnav-encoder [default: the shipped weights].")
@click.option("--threshold", "thresholds", multiple=True, callback=_parse_thresholds,
              metavar="NAME=DISTANCE",
              help="Report NAME at this threshold (default: its stored threshold, else the one "
                   "calibrated on these pairs). Repeatable.")
@click.option("--target-precision", default=0.99, show_default=True,
              type=click.FloatRange(0, 1, min_open=True), help="Precision the calibration keeps.")
@click.option("--write-threshold", "write", flag_value="threshold",
              help="Store kgnav-encoder's threshold calibrated here into --weights as its "
                   "match threshold.")
@click.option("--write-loop-threshold", "write", flag_value="loop_threshold",
              help="Store it into --weights as the threshold the agent relocates with "
                   "(usually at a looser --target-precision, such as 0.9).")
@click.option("--device", default="auto", show_default=True, type=DEVICE)
@env_options
@click.option("--quiet", is_flag=True, help="No progress bar.")
def relocation_bench(split: str | None, out_dir: Path, extractors: list[str], pairs: int,
                     seed: int, weights: Path | None, thresholds: dict[str, float],
                     target_precision: float, write: str | None, device: str,
                     env_name: str, scenes: int | None, walk_steps: int, quiet: bool) -> None:
    """Precision/recall of state matching on same-place vs other-place view pairs; ROC.

    With --env, on another environment's frames (walked through its protocol): a threshold
    calibrated there belongs to that environment's visual domain.
    """
    from rich.console import Console
    from rich.table import Table
    from tqdm import tqdm

    from kgnav.agent.features import make_extractor
    from kgnav.nets.encoder.calibration import KINDS, build_pairs, evaluate
    from kgnav.nets.encoder.extractor import NAME as ENCODER
    from kgnav.nets.encoder.plot import plot_roc
    from kgnav.nets.encoder.views import NEG_DIST, NEG_TURN, POS_DIST, POS_TURN

    kgnav_env = env_name == KGNAV
    split = (_kgnav_split(split or CALIBRATION_SPLIT, list(SPLITS)) if kgnav_env
             else split or "val")
    if out_dir.exists() and not out_dir.is_dir():
        raise click.BadParameter(f"{out_dir} is not a directory", param_hint="--out")
    if write and (weights is None or ENCODER not in extractors):
        raise click.UsageError(f"--write-{write.replace('_', '-')} needs --weights and "
                               f"{ENCODER} in --extractors")
    unknown = [k for k in thresholds if k not in extractors]
    if unknown:
        raise click.BadParameter(f"{unknown[0]!r} is not in --extractors",
                                 param_hint="--threshold")
    dev = device_option(device)
    exts = []
    for name in extractors:
        params = {"weights": weights, "device": dev} if name == ENCODER else {}
        try:
            exts.append(make_extractor(name, **params))
        except KgnavError as exc:
            if "unknown feature extractor" in str(exc):
                raise click.BadParameter(str(exc), param_hint="--extractors") from None
            raise
    set_threads(1)
    views = (_sampler(split) if kgnav_env else
             env_sampler(env_name, split, scenes, walk_steps, seed,
                         f"walking {env_name} {split}", quiet))
    with tqdm(total=3 * pairs, desc=f"embedding {split} views", unit="view", disable=quiet,
              dynamic_ncols=True, mininterval=1.0) as bar:
        ps = build_pairs(views, exts, n_pos=pairs, seed=seed,
                         progress=lambda done, total: bar.update(done - bar.n))
    results = {}
    for name, e in zip(extractors, exts, strict=True):  # reported by the names asked for
        if name in thresholds:
            thr, src = thresholds[name], "--threshold"
        elif getattr(e, "threshold", None) is not None:
            thr = float(e.threshold)
            src = e.meta.get("threshold_source", "stored") if hasattr(e, "meta") else \
                "the extractor's default"
        else:
            thr, src = None, ""
        results[name] = {"dim": e.dim, **evaluate(ps, e.name, thr, src, target_precision)}
        if e.name != name:
            results[name]["features"] = e.name  # e.g. kgnav-encoder:<fingerprint>
    report = {
        "format": "kgnav-relocation-bench",
        "version": 1,
        "env": env_name,
        "split": split,
        "seed": seed,
        "places": pairs,
        "houses": ps.scene_names,
        "pairs": ps.counts(),
        "target_precision": target_precision,
        "definitions": {
            "positive": f"same house, <= {POS_DIST} m and <= {round(POS_TURN * 57.2958)} deg",
            "negative": f"other house, or > {NEG_DIST} m or > {round(NEG_TURN * 57.2958)} deg",
            "match": "cosine distance < threshold",
            "calibrated_threshold": f"largest with pair precision >= {target_precision}",
            "kinds": list(KINDS),
        },
        "extractors": results,
    }
    out_dir.mkdir(parents=True, exist_ok=True)
    from kgnav.common.atomic import atomic_open

    with atomic_open(out_dir / "relocation.json", "w") as fh:
        json.dump(report, fh, indent=1)
    plot_roc(results, out_dir / "relocation_roc.png",
             title=f"relocation on {domain(env_name, split)}: {pairs} places, seed {seed}")
    if write:
        from kgnav.nets.encoder.weights import set_threshold

        set_threshold(weights, results[ENCODER]["calibrated_threshold"],
                      f"calibrated: largest with precision >= {target_precision} on "
                      f"relocation-bench pairs of {domain(env_name, split)}, {pairs} places, "
                      f"seed {seed}", key=write)
    con = Console(highlight=False, soft_wrap=True)
    n_pos = ps.counts()["positive"]
    table = Table("extractor", "dim", "threshold", "precision", "recall", "AUC", "ms/frame",
                  title=f"relocation on {domain(env_name, split)}: {n_pos} positive, "
                        f"{len(ps.pairs) - n_pos} negative pairs")
    for name, r in results.items():
        table.add_row(name, str(r["dim"]), f"{r['threshold']:.4f}", f"{r['precision']:.4f}",
                      f"{r['recall']:.4f}", f"{r['auc']:.4f}", f"{r['ms_per_frame_batched']:.3f}")
    con.print(table)
    for name, r in results.items():
        rt = r["retrieval"]
        con.print(f"{name}: calibrated threshold {r['calibrated_threshold']:.4f} (recall "
                  f"{r['calibrated']['recall']:.4f}); nearest-neighbour relocation precision "
                  f"{rt['precision']:.4f}, recall {rt['recall']:.4f}, wrong house "
                  f"{rt['wrong_house']}")
    con.print(f"wrote {out_dir / 'relocation.json'} and {out_dir / 'relocation_roc.png'}")
