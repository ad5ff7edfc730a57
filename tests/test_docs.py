"""The README and docs/ stay navigable: every relative link and image resolves (anchors
included), every command the README marks runnable answers ``--help``, and the README's
``make demo`` command is the Makefile's. No network; a few seconds.

A command block is marked runnable by an HTML comment on the line right before its fence::

    <!-- runnable -->
    ```bash
    kgnav inspect m.graphml --json      # each line starting with "kgnav " is a command
    ```
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path
from urllib.parse import unquote

import pytest

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
DOC_FILES = [README, *sorted((ROOT / "docs").glob("*.md"))]
RUNNABLE = "<!-- runnable -->"

_FENCE = re.compile(r"^\s{0,3}(```|~~~)")
_HEADING = re.compile(r"^\s{0,3}(#{1,6})\s+(.*?)\s*#*\s*$")
# [text](target) and ![alt](target); the text may hold one level of brackets
_LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
_CODE_SPAN = re.compile(r"(`+)(?:(?!\1).)+?\1")
_SCHEME = re.compile(r"^[A-Za-z][A-Za-z0-9+.-]*:")


# ------------------------------------------------------------------------------ helpers


def _prose_lines(text: str):
    """(line number, line) of the lines outside fenced code blocks, inline code blanked."""
    fence = None
    for no, line in enumerate(text.splitlines(), 1):
        m = _FENCE.match(line)
        if m:
            if fence is None:
                fence = m.group(1)
            elif m.group(1) == fence:
                fence = None
            continue
        if fence is None:
            yield no, _CODE_SPAN.sub(lambda s: " " * len(s.group()), line)


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: its text (links reduced to their text, code marks
    dropped), lowercased, punctuation other than ``-`` and ``_`` removed, spaces to ``-``."""
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading)
    text = re.sub(r"[^\w\- ]", "", text.strip().lower())
    return text.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    """Every heading anchor of a markdown file; repeated headings get -1, -2, ... as on
    GitHub."""
    seen: dict[str, int] = {}
    out = set()
    fence = None
    for line in path.read_text(encoding="utf-8").splitlines():
        m = _FENCE.match(line)
        if m:
            fence = m.group(1) if fence is None else (None if m.group(1) == fence else fence)
            continue
        if fence is None and (h := _HEADING.match(line)):
            base = slug(h.group(2))
            n = seen.get(base, 0)
            seen[base] = n + 1
            out.add(base if n == 0 else f"{base}-{n}")
    return out


def links(path: Path) -> list[tuple[int, str]]:
    """(line, target) of every link and image in a markdown file, outside code."""
    return [(no, m.group(1)) for no, line in _prose_lines(path.read_text(encoding="utf-8"))
            for m in _LINK.finditer(line)]


def broken_links(path: Path) -> list[str]:
    """One line per relative link or image of ``path`` that does not resolve: a missing file,
    or an anchor that names no heading of its markdown file. External links (http, https,
    mailto, any scheme) are not checked."""
    problems = []
    for no, target in links(path):
        if _SCHEME.match(target):
            continue
        file_part, _, anchor = target.partition("#")
        dest = (path.parent / unquote(file_part)).resolve() if file_part else path
        where = f"{path.name}:{no}: ({target})"
        if not dest.exists():
            problems.append(f"{where}: {file_part} does not exist")
        elif anchor and dest.suffix == ".md" and unquote(anchor).lower() not in anchors(dest):
            problems.append(f"{where}: no heading #{anchor} in {dest.name}")
    return problems


def runnable_blocks(path: Path) -> list[list[str]]:
    """The lines of each fenced block marked runnable (continuation lines joined)."""
    lines = path.read_text(encoding="utf-8").splitlines()
    blocks = []
    for i, line in enumerate(lines):
        if line.strip() != RUNNABLE:
            continue
        assert i + 1 < len(lines) and lines[i + 1].strip().startswith("```bash"), (
            f"{path.name}:{i + 1}: {RUNNABLE} must be right before a ```bash fence")
        block, j = [], i + 2
        while j < len(lines) and not lines[j].strip().startswith("```"):
            block.append(lines[j])
            j += 1
        assert j < len(lines), f"{path.name}:{i + 1}: unclosed runnable block"
        joined = "\n".join(block).replace("\\\n", " ")
        blocks.append(joined.splitlines())
    return blocks


def runnable_commands(path: Path) -> list[str]:
    return [line.strip() for block in runnable_blocks(path) for line in block
            if line.strip().startswith("kgnav ")]


def _cli_group():
    """The click group behind the ``kgnav`` command (``kgnav.cli``'s ``main``, or the group
    ``main`` runs)."""
    import click

    import kgnav.cli as cli

    for name in ("main", "app", "cli"):
        if isinstance(obj := getattr(cli, name, None), click.Group):
            return obj
    groups = [o for o in vars(cli).values() if isinstance(o, click.Group)]
    assert groups, "kgnav.cli defines no click group"
    return groups[0]


def subcommand_path(group, words: list[str]) -> list[str]:
    """The leading words that name (sub)commands; at a group, the next word must name one of
    its commands or be an option."""
    import click

    cmd, path = group, []
    for word in words:
        if not isinstance(cmd, click.Group) or word.startswith("-"):
            break
        sub = cmd.get_command(click.Context(cmd), word)
        assert sub is not None, (
            f"{' '.join(['kgnav', *path])}: no subcommand {word!r} "
            f"(known: {', '.join(sorted(cmd.list_commands(click.Context(cmd))))})")
        cmd = sub
        path.append(word)
    return path


# ------------------------------------------------------------------------------ tests


@pytest.mark.parametrize("path", DOC_FILES, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(path):
    problems = broken_links(path)
    assert not problems, "broken links:\n" + "\n".join(problems)


def test_link_checker_reports_broken_links(tmp_path):
    (tmp_path / "other.md").write_text("# Other page\n\n## A section: here (`x`)\n")
    (tmp_path / "pic.png").write_bytes(b"")
    page = tmp_path / "page.md"
    page.write_text(
        "# Title\n\n"
        "[ok](other.md) [ok](other.md#a-section-here-x) [ok](#title) ![ok](pic.png)\n"
        "[web](https://example.com/nope.md) [mail](mailto:a@b.c) `[code](gone.md)`\n"
        "[bad](missing.md) ![bad](missing.png) [bad](#nowhere) [bad](other.md#nothing)\n"
        "```\n[in a fence](also-missing.md)\n```\n"
    )
    problems = broken_links(page)
    assert len(problems) == 4, problems
    for target in ("(missing.md)", "(missing.png)", "(#nowhere)", "(other.md#nothing)"):
        assert any(target in p for p in problems), (target, problems)
    assert all(p.startswith("page.md:5:") for p in problems)


def test_slug_is_githubs():
    assert slug("The agent (`kgnav.agent`)") == "the-agent-kgnavagent"
    assert slug("Running on a cluster (`--engine ray`)") == "running-on-a-cluster---engine-ray"
    assert slug("Memory: geometry, evidence, verified relocation") == (
        "memory-geometry-evidence-verified-relocation")
    assert slug("Houses × 20 episodes") == "houses--20-episodes"


def test_readme_is_short_and_marks_the_cli_block_runnable():
    assert len(README.read_text(encoding="utf-8").splitlines()) <= 400
    commands = runnable_commands(README)
    assert any(c.startswith("kgnav inspect ") for c in commands), commands
    assert any(c.startswith("kgnav eval ") for c in commands), commands


RUNNABLE_COMMANDS = runnable_commands(README)


@pytest.mark.parametrize("line", RUNNABLE_COMMANDS)
def test_runnable_command_answers_help(line):
    from click.testing import CliRunner

    words = shlex.split(line, comments=True)
    assert words[0] == "kgnav", line
    group = _cli_group()
    path = subcommand_path(group, words[1:])
    assert path, f"{line}: names no kgnav subcommand"
    result = CliRunner().invoke(group, [*path, "--help"], prog_name="kgnav")
    assert result.exit_code == 0, (line, result.output, result.exception)
    assert "Usage:" in result.output


def test_readme_make_demo_command_is_the_makefiles():
    """The README says what `make demo` runs; the Makefile's defaults must give that line."""
    make = (ROOT / "Makefile").read_text(encoding="utf-8")
    defaults = dict(re.findall(r"^(\w+) \?= (.*)$", make, re.M))
    recipe = re.search(r"^demo:.*\n\t(.+)$", make, re.M).group(1)
    size = "--scenes $(SCENES) --episodes $(EPISODES)"  # SIZE without FULL=1
    assert f"SIZE := {size}" in make
    recipe = recipe.replace("$(SIZE)", size).replace("$(VENV)/bin/kgnav", "kgnav")
    recipe = re.sub(r"\$\((\w+)\)", lambda m: defaults[m.group(1)], recipe)
    assert " ".join(recipe.split()) in [" ".join(c.split()) for c in RUNNABLE_COMMANDS]
