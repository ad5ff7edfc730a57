"""``kgnav scenes``: build, check and draw a split of your own (see :mod:`kgnav.sim.scene_dir`)."""

from __future__ import annotations

from pathlib import Path

import click

from kgnav.errors import KgnavError


def _range(ctx, param, value: str) -> tuple[int, int]:
    lo, sep, hi = value.partition("..")
    try:
        a, b = int(lo), int(hi if sep else lo)
    except ValueError:
        raise click.BadParameter(f"expected A..B (two integers), got {value!r}", ctx,
                                 param) from None
    if a > b:
        raise click.BadParameter(f"empty range {value!r}", ctx, param)
    return a, b


@click.group("scenes")
def scenes() -> None:
    """Houses of your own: generate a split directory, validate it, draw it."""


@scenes.command("generate")
@click.option("-o", "--out", "out_dir", required=True,
              type=click.Path(file_okay=False, path_type=Path), help="Directory to write.")
@click.option("--count", type=click.IntRange(min=1), default=11, show_default=True,
              help="Houses (seeds SEED, SEED+1, ...).")
@click.option("--seed", type=int, default=9000, show_default=True,
              help="First seed; the built-in splits use 1000-1019, 2000-2010, 3000-3019, "
                   "4000-4010.")
@click.option("--rooms", callback=_range, default="8..30", show_default=True,
              help="Room count range A..B (corridors included), drawn per house.")
@click.option("--size", type=click.FloatRange(5.2, 100.0), default=40.0, show_default=True,
              help="Largest floor side in metres.")
@click.option("--episodes", type=click.IntRange(min=1), default=100, show_default=True,
              help="Episodes per house.")
@click.option("--generator", type=click.Choice(["house-v2", "house-v1"]), default="house-v2",
              show_default=True, help="house-v1: the small houses of train-small/val-small "
                                      "(4..12 rooms, at most 20 m; --size is ignored).")
def generate(out_dir, count, seed, rooms, size, episodes, generator) -> None:
    """Write COUNT houses and their episodes into OUT (runnable with
    'kgnav eval --scenes-dir OUT')."""
    from tqdm.auto import tqdm

    from kgnav.sim.scene_dir import check_split_args, generate_split

    try:
        check_split_args(count, rooms, episodes, generator)
    except ValueError as e:
        raise click.UsageError(str(e)) from None
    with tqdm(total=count, desc="houses", unit="house") as bar:
        names = generate_split(out_dir, count, seed, rooms, size, episodes, generator,
                               progress=lambda _name: bar.update(1))
    click.echo(f"wrote {len(names)} houses x {episodes} episodes to {out_dir}")


@scenes.command("validate")
@click.argument("directory", type=click.Path(path_type=Path))
def validate(directory) -> None:
    """Check a split directory without changing it; exit 1 if anything is wrong."""
    from kgnav.sim.scene_dir import SceneDir, validate_split

    problems = validate_split(directory)
    for p in problems:
        click.echo(p)
    if problems:
        raise KgnavError(f"{directory}: {len(problems)} problem(s)")
    sd = SceneDir(directory)
    n = sum(len(sd.episodes(k)) for k in range(len(sd)))
    click.echo(f"{directory}: {len(sd)} houses, {n} episodes, no problems")


@scenes.command("draw")
@click.argument("directory", type=click.Path(path_type=Path))
@click.option("-o", "--out", "out_dir", required=True,
              type=click.Path(file_okay=False, path_type=Path))
def draw(directory, out_dir) -> None:
    """Top-down PNG of every house of a split directory (or a built-in split's name)."""
    from kgnav.sim.sources import scene_source
    from kgnav.sim.topdown import draw_topdown

    src = (scene_source(scenes_dir=directory) if directory.exists()
           else scene_source(str(directory)))
    out_dir.mkdir(parents=True, exist_ok=True)
    for k in range(len(src)):
        s = src.scene(k)
        draw_topdown(s, path=out_dir / f"{s.name}.png")
    click.echo(f"wrote {len(src)} pictures to {out_dir}")
