"""The ``kgnav`` command line: the memory's commands (:mod:`kgnav.cli.memory`), the benchmark
(:mod:`kgnav.cli.eval`), the scenes (:mod:`kgnav.cli.scenes`) and the learned parts
(:mod:`kgnav.cli.encoder`, :mod:`kgnav.cli.segmenter`, :mod:`kgnav.cli.policy`).

Exit status: 0 on success, 1 for bad data (a corrupt file, an unknown state or class, a store
with problems), 2 for bad usage (a missing or malformed argument). Either error is one line on
stderr naming the problem. Everything printed from a file (names, ids, classes) is printed as it
is: rich markup is off, and control characters are shown escaped (``\x1b``, ``\n``).
"""

from __future__ import annotations

import os
import sys

import click

from kgnav.cli._output import safe
from kgnav.errors import KgnavError


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="kgnav")
def app() -> None:
    """Reusable Abstract Models for Object Goal Navigation."""


def _register() -> None:
    # one module per command group: the memory's own commands, the benchmark, the scenes, and the
    # training and benchmarking of the agent's learned parts
    from kgnav.cli import encoder, memory, policy, scenes, segmenter
    from kgnav.cli import eval as eval_group

    for cmd in (memory.inspect, memory.merge_cmd, memory.query_cmd, memory.export_cmd,
                memory.store_app, memory.cypher_cmd, memory.demo, eval_group.eval_cmd,
                eval_group.memory_map, eval_group.goal_floors,
                scenes.scenes, encoder.train_encoder, encoder.relocation_bench,
                segmenter.train_segmenter, segmenter.segmenter_bench, policy.train_policy,
                policy.policy_bench):
        app.add_command(cmd)


_register()


def main(argv: list[str] | None = None) -> None:
    """Entry point: run the CLI, mapping errors to one stderr line and an exit status."""
    try:
        rv = app.main(args=argv, prog_name="kgnav", standalone_mode=False)
    except click.exceptions.NoArgsIsHelpError as exc:
        click.echo(exc.ctx.get_help() if exc.ctx else exc.format_message())
        sys.exit(0)
    except click.UsageError as exc:
        path = exc.ctx.command_path if exc.ctx else "kgnav"
        where = f" ({path})" if " " in path else ""  # name the subcommand, if any
        click.echo(f"kgnav: usage error{where}: {safe(exc.format_message())}", err=True)
        sys.exit(2)
    except KgnavError as exc:
        click.echo(f"kgnav: error: {safe(exc)}", err=True)
        sys.exit(1)
    except OSError as exc:  # an output that cannot be written, a full disk...
        where = f"{exc.filename}: " if exc.filename else ""
        click.echo(f"kgnav: error: {safe(where)}{safe(exc.strerror or exc)}", err=True)
        sys.exit(1)
    except click.exceptions.Abort:
        click.echo("kgnav: aborted", err=True)
        sys.exit(130)
    except click.exceptions.Exit as exc:
        sys.exit(exc.exit_code)
    except Exception as exc:  # a bug: still one line, unless asked for the traceback
        if os.environ.get("KGNAV_DEBUG"):
            raise
        click.echo(f"kgnav: internal error: {safe(type(exc).__name__)}: {safe(exc)} "
                   "(KGNAV_DEBUG=1 shows the traceback)", err=True)
        sys.exit(1)
    sys.exit(rv if isinstance(rv, int) else 0)

