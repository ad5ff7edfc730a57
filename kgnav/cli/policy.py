"""``kgnav train-policy`` and ``kgnav policy-bench``: the learned exploration policy.

Registered in :mod:`kgnav.cli`; usage errors raise :class:`click.UsageError` (exit 2), data
errors :class:`~kgnav.errors.KgnavError` (exit 1), each reported as one line.
"""

from __future__ import annotations

from pathlib import Path

import click

from kgnav.cli._training import OUT_FILE, finished, prepare, run_training, training_options
from kgnav.nets.explore.train import PPOConfig
from kgnav.sim.episodes import SPLITS

_D = PPOConfig()


@click.command("train-policy")
@click.option("--out", "out", type=OUT_FILE, required=True,
              help="Where to write the weights (.npz).")
@click.option("--policy", "policy", default="ppo", show_default=True,
              type=click.Choice(["ppo", "ppo-semantic"]),
              help="ppo: reward = newly explored area; ppo-semantic: + progress toward the "
                   "goal class, with its map channel.")
@click.option("--seed", default=_D.seed, show_default=True, type=click.IntRange(min=0),
              help="Seed of the initial weights, the episodes and the sampled goals.")
@click.option("--steps", default=_D.steps, show_default=True, type=click.IntRange(min=1),
              help="PPO iterations (the learning rate decays to zero at the last).")
@click.option("--episodes-per-iter", default=_D.episodes_per_iter, show_default=True,
              type=click.IntRange(min=1), help="Whole episodes played per iteration.")
@click.option("--split", default=_D.split, show_default=True,
              type=click.Choice([s for s in SPLITS if s.startswith("train")]),
              help="Houses to train in (the shipped weights: train).")
@click.option("--init", "init", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Start from these weights (ppo-semantic: the shipped ppo weights; the "
                   "goal-class inputs start at zero).")
@click.option("--curve", type=OUT_FILE, default=None,
              help="Training-curve PNG [default: --out with suffix .png].")
@training_options(threads_default=1)
def train_policy(out: Path, policy: str, seed: int, steps: int, episodes_per_iter: int,
                 split: str, init: Path | None, curve: Path | None, time_budget: float | None,
                 resume: bool, checkpoint: Path | None, checkpoint_every: int, device: str,
                 threads: int, quiet: bool) -> None:
    """Train the global exploration policy with PPO in the map-level environment.

    Episodes come from the train houses only (val is for `kgnav policy-bench` and `kgnav
    eval`). The same --seed, --steps and --episodes-per-iter give the same weights (CPU, same
    --threads). Writes the weights (with the training curve in their metadata) and the curve
    as a PNG.
    """
    from kgnav.nets.explore.plot import plot_curve
    from kgnav.nets.explore.train import PPOTrainer

    ckpt, dev = prepare(out, checkpoint, resume, device, threads)
    png = curve or out.with_suffix(".png")
    cfg = PPOConfig.for_policy(policy, seed=seed, steps=steps,
                               episodes_per_iter=episodes_per_iter, split=split,
                               init="" if init is None else str(init))
    trainer = PPOTrainer(cfg, device=dev, threads=threads)
    run_training(trainer, ckpt, resume, f"train-policy {policy}", time_budget,
                 checkpoint_every, quiet)
    trainer.export().save(out)
    plot_curve(trainer.curve, png, title=f"{policy}: PPO on the {split} houses, seed {seed}")
    last = trainer.curve[-10:]
    area = sum(c[f"explored_{cfg.max_steps}"] for c in last) / max(len(last), 1)
    click.echo(f"{finished(trainer)}, {threads} thread(s) on {dev}); explored after "
               f"{cfg.max_steps} actions, last {len(last)} iterations: {area:.1f} m²; "
               f"weights -> {out}; curve -> {png}; checkpoint {ckpt}")
    if not trainer.done:
        click.echo(f"continue with: kgnav train-policy --resume --out {out} --checkpoint {ckpt} "
                   f"--policy {policy} --seed {seed} --steps {steps} --episodes-per-iter "
                   f"{episodes_per_iter} --split {split} --threads {threads}"
                   + ("" if init is None else f" --init {init}"), err=True)


def _names(ctx, param, value: str) -> list[str]:
    names = list(dict.fromkeys(v.strip() for v in value.split(",") if v.strip()))
    if not names:
        raise click.BadParameter("name at least one policy")
    from kgnav.agent.policy import policy_names

    known = [*policy_names(), "oracle"]
    bad = [n for n in names if n not in known]
    if bad:
        raise click.BadParameter(f"unknown policy {bad[0]!r} (known: {', '.join(known)})")
    return names


@click.command("policy-bench")
@click.option("--split", default="val", show_default=True, type=click.Choice(list(SPLITS)),
              help="Houses to explore (val: never seen in training).")
@click.option("--out", "out_dir", required=True,
              type=click.Path(file_okay=False, path_type=Path),
              help="Directory for policy_bench.json.")
@click.option("--policies", default="frontier,ppo,random-goal,oracle", show_default=True,
              callback=_names, help="Comma-separated global policies; oracle: the greedy "
                                    "ground-truth look-ahead.")
@click.option("--houses", type=click.IntRange(min=1), default=None,
              help="The first K houses of the split (default: all).")
@click.option("--episodes", default=3, show_default=True, type=click.IntRange(min=1),
              help="Starts per house (the split's first episodes).")
@click.option("--oracle-episodes", default=1, show_default=True, type=click.IntRange(min=1),
              help="Starts per house for the (slow) oracle.")
@click.option("--seed", default=1, show_default=True, type=click.IntRange(min=0),
              help="Seed of the policies' sampling.")
@click.option("--quiet", is_flag=True, help="No progress bar.")
def policy_bench(split: str, out_dir: Path, policies: list[str], houses: int | None,
                 episodes: int, oracle_episodes: int, seed: int, quiet: bool) -> None:
    """Explored area after 100/250/500 actions per global policy, from the same starts, in the
    map-level environment; paired differences against the first policy."""
    import json

    from tqdm import tqdm

    from kgnav.cli._training import set_threads
    from kgnav.common.atomic import atomic_open
    from kgnav.nets.explore.bench import coverage_bench

    if out_dir.exists() and not out_dir.is_dir():
        raise click.BadParameter(f"{out_dir} is not a directory", param_hint="--out")
    set_threads(1)
    n_h = len(SPLITS[split]) if houses is None else min(houses, len(SPLITS[split]))
    total = sum(n_h * (oracle_episodes if p == "oracle" else episodes) for p in policies)
    with tqdm(total=total, desc="policy-bench", unit="episode", disable=quiet,
              dynamic_ncols=True, mininterval=1.0) as bar:
        def progress(name: str) -> None:
            bar.update(1)
            bar.set_postfix(policy=name, refresh=False)

        report = coverage_bench(policies, split=split, houses=houses, episodes=episodes,
                                oracle_episodes=oracle_episodes, seed=seed, progress=progress)
    report = {"format": "kgnav-policy-bench", "version": 1, **report}
    out_dir.mkdir(parents=True, exist_ok=True)
    with atomic_open(out_dir / "policy_bench.json", "w") as fh:
        json.dump(report, fh, indent=1)
    click.echo(coverage_table(report))
    click.echo(f"wrote {out_dir / 'policy_bench.json'}")


def coverage_table(report: dict) -> str:
    """The coverage bench as text: mean explored area per mark, the paired difference at the
    last mark against the first policy (on the episodes both ran), ms per decision."""
    from kgnav.nets.explore.bench import paired

    pol = report["policies"]
    marks = [str(t) for t in report["marks"]]
    base = next(iter(pol))
    head = ["policy", "episodes", *(f"m² @{t}" for t in marks),
            f"@{marks[-1]} − {base} [95 % CI]", "ms/decision (median, p90)"]
    rows = [head]
    for name, r in pol.items():
        d = paired({k: v[marks[-1]] for k, v in r["per_episode"].items()},
                   {k: v[marks[-1]] for k, v in pol[base]["per_episode"].items()})
        same = name == base
        rows.append([name, str(r["episodes"]), *(f"{r['explored'][t]:.1f}" for t in marks),
                     "—" if same else f"{d['diff']:+.1f} [{d['low']:+.1f}, {d['high']:+.1f}] "
                                      f"({d['pairs']} pairs)",
                     f"{r['ms_per_decision']['median']:.1f}, {r['ms_per_decision']['p90']:.1f}"])
    widths = [max(len(r[i]) for r in rows) for i in range(len(head))]
    lines = [f"explored area (m²) on {report['split']}: {report['houses']} houses, "
             f"seed {report['seed']}, map-level environment"]
    for k, r in enumerate(rows):
        lines.append("  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip())
        if k == 0:
            lines.append("  ".join("-" * w for w in widths))
    return "\n".join(lines)
