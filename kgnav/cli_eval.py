"""``kgnav eval``: the ObjectNav benchmark from the command line (see
:mod:`kgnav.evaluation.runner`)."""

from __future__ import annotations

from pathlib import Path

import click
from rich.console import Console
from rich.table import Table

from kgnav.agent.segmenter import SEGMENTER_PRESETS
from kgnav.evaluation.failures import FAILURE_CLASSES
from kgnav.evaluation.variants import VARIANTS

_ABBREV = {"Last Mile": "LM", "Hallucination": "Hal", "Detection": "Det",
           "Exploration": "Exp", "Misc": "Misc"}


def _variants(ctx, param, value: str) -> tuple[str, ...]:
    names = tuple(dict.fromkeys(v.strip() for v in value.split(",") if v.strip()))
    if not names:
        raise click.BadParameter("give at least one variant", ctx, param)
    bad = [n for n in names if n not in VARIANTS]
    if bad:
        raise click.BadParameter(f"unknown variant {bad[0]!r} (known: {', '.join(VARIANTS)})",
                                 ctx, param)
    return names


def _show(ctx, param, value: str | None) -> tuple[int, int] | None:
    if value is None:
        return None
    try:
        scene, ep = (int(v) for v in value.split(":"))
    except ValueError:
        raise click.BadParameter(f"expected SCENE:EPISODE (two integers), got {value!r}",
                                 ctx, param) from None
    return scene, ep


@click.command("eval")
@click.option("--split", type=click.Choice(["val", "train"]), default="val", show_default=True)
@click.option("--variants", callback=_variants, default="ans", show_default=True,
              help=f"Comma-separated: {', '.join(VARIANTS)}.")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path),
              default=Path("export/eval"), show_default=True,
              help="Where episodes.jsonl, summary.json, plots and memories go.")
@click.option("--scenes", type=click.IntRange(min=1), default=None,
              help="Run only the first K scenes of the split (default: all).")
@click.option("--episodes", type=click.IntRange(min=1), default=None,
              help="Episodes per scene (default: the split's, 20 for val).")
@click.option("--workers", type=click.IntRange(min=1), default=1, show_default=True,
              help="Processes; results are identical to one.")
@click.option("--segmenter", type=click.Choice(["learned", *sorted(SEGMENTER_PRESETS)]),
              default="learned", show_default=True,
              help="learned: the RGB-D network; or a noise preset on ground truth ('clean').")
@click.option("--extractor", default="auto", show_default=True,
              help="State features: kgnav-encoder, opencv-gist, or auto (the encoder if it "
                   "loads).")
@click.option("--threshold", type=click.FloatRange(0.0, 2.0), default=None,
              help="Relocation cosine-distance threshold (default: the extractor's loop "
                   "one).")
@click.option("--pre-explore-steps", type=click.IntRange(min=10), default=1500,
              show_default=True, help="Budget of the hp/sp pre-exploration per house.")
@click.option("--show", callback=_show, default=None, metavar="SCENE:EPISODE",
              help="Draw this episode from above for every variant (default: 0:LAST).")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--quiet", is_flag=True, help="No progress bars.")
def eval_cmd(split, variants, out_dir, scenes, episodes, workers, segmenter, extractor,
             threshold, pre_explore_steps, show, seed, quiet) -> None:
    """Run agent variants over a split; write episodes.jsonl, summary.json and plots."""
    from kgnav.evaluation.runner import EvalConfig, run_eval
    from kgnav.sim.episodes import DEFAULT_EPISODES_PER_SCENE

    if show is None:
        show = (0, (episodes or DEFAULT_EPISODES_PER_SCENE[split]) - 1)
    cfg = EvalConfig(split=split, variants=variants, scenes=scenes, episodes=episodes,
                     workers=workers, segmenter=segmenter, extractor=extractor,
                     threshold=threshold, seed=seed, pre_explore_steps=pre_explore_steps,
                     show=show)
    _records, summary = run_eval(cfg, out_dir, progress=not quiet)
    print_summary(summary)
    click.echo(f"wrote {out_dir / 'episodes.jsonl'}, {out_dir / 'summary.json'} and plots")


def print_summary(summary: dict) -> None:
    """The paper's Table 1/3 analogue, plus relocation and failure counts."""
    table = Table("variant", "episodes", "Success", "SPL", "SoftSPL", "DTS (m)", "relocated",
                  *(_ABBREV[c] for c in FAILURE_CLASSES), "ep/s",
                  title="ObjectNav (failures: Last Mile, Hallucination, Detection, "
                        "Exploration, Misc)")
    for name, s in summary.items():
        table.add_row(
            name, str(s["episodes"]), f"{s['success']:.3f}", f"{s['spl']:.3f}",
            f"{s['softspl']:.3f}", f"{s['dts']:.3f}", f"{s['relocation_rate']:.2f}",
            *(str(s["failures"][c]) for c in FAILURE_CLASSES),
            f"{s['episodes_per_second']:.2f}" if s.get("episodes_per_second") else "",
        )
    console = Console(highlight=False)
    if not console.is_terminal:  # a log file or pipe: do not squeeze the table to 80 columns
        console = Console(highlight=False, width=140)
    console.print(table)
