"""What every ``kgnav`` command prints with: one console, terminal-safe strings, tables, JSON,
and the error that names the file it concerns."""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import click
from rich.console import Console
from rich.table import Table

from kgnav.errors import KgnavError

# markup off: a class or file name like "[/bold]" is text, not a style
out = Console(highlight=False, soft_wrap=True, markup=False, emoji=False)

def wide_console(**options) -> Console:
    """A console for wide tables: the terminal's width, or 140 columns for a log file or pipe
    (which rich would squeeze to 80); ``options`` go to :class:`~rich.console.Console`."""
    con = Console(highlight=False, **options)
    return con if con.is_terminal else Console(highlight=False, width=140, **options)


# C0/C1 controls, line and paragraph separators, bidirectional overrides
_UNSAFE = re.compile("[\x00-\x1f\x7f-\x9f\u2028\u2029\u202a-\u202e\u2066-\u2069]")


def safe(value) -> str:
    """``str(value)`` for a terminal: control characters escaped, so it prints as one line and
    shows what the string holds.

    >>> safe("a\\nb\\x1b[31m")
    'a\\\\nb\\\\x1b[31m'
    """
    return _UNSAFE.sub(lambda m: m.group().encode("unicode_escape").decode("ascii"), str(value))



class DataError(KgnavError):
    """A KgnavError already prefixed with the file it concerns."""


def _about(path: Path, exc: KgnavError) -> DataError:
    msg = str(exc)
    return DataError(msg if str(path) in msg else f"{path}: {msg}")


def _table(*columns: str, title: str) -> Table:
    return Table(*columns, title=safe(title))


def _row(table: Table, *cells) -> None:
    table.add_row(*(safe(c) for c in cells))


def _emit_json(obj) -> None:
    sys.stdout.write(json.dumps(obj, indent=2, sort_keys=False) + "\n")


_FILE = click.Path(dir_okay=False, path_type=Path)
_JSON = click.option("--json", "as_json", is_flag=True, help="Print JSON.")
