"""Print benchmark rows as an aligned text table (and optionally JSON)."""

from __future__ import annotations

import json
import sys


def print_table(title: str, header: list[str], rows: list[list], json_path: str | None = None):
    cells = [[str(c) for c in header]] + [[_fmt(c) for c in r] for r in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(header))]
    print(f"\n{title}")
    for k, r in enumerate(cells):
        print("  ".join(c.rjust(w) for c, w in zip(r, widths, strict=True)))
        if k == 0:
            print("  ".join("-" * w for w in widths))
    sys.stdout.flush()
    if json_path:
        with open(json_path, "w") as fh:
            json.dump([dict(zip(header, r, strict=True)) for r in rows], fh, indent=2)


def _fmt(c) -> str:
    if isinstance(c, float):
        return f"{c:.3g}" if abs(c) < 1000 else f"{c:.0f}"
    return str(c)
