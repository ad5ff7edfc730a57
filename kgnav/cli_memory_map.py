"""``kgnav memory-map``: a stored benchmark memory drawn over its houses (see
:mod:`kgnav.evaluation.memory_map`)."""

from __future__ import annotations

from pathlib import Path

import click


@click.command("memory-map")
@click.argument("run_dir", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--variant", default="si", show_default=True,
              help="Whose memory: si, sem+si, or pre-explored (the hp/sp memory).")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path),
              default=None, help="Where the PNGs go [default: RUN_DIR/memory].")
@click.option("--ppm", type=click.FloatRange(min=2, max=200), default=30.0, show_default=True,
              help="Pixels per metre.")
def memory_map(run_dir: Path, variant: str, out_dir: Path | None, ppm: float) -> None:
    """Draw every object the memory of a `kgnav eval` run holds, house by house, over the
    house from above: colour per model, disc for a real object, cross for a phantom."""
    from kgnav.evaluation.memory_map import draw_run

    for path in draw_run(run_dir, variant, out_dir, ppm):
        click.echo(str(path))
