"""Atomic writes: permissions kept, symbolic links followed, temporary files named and removed."""

from __future__ import annotations

import os
import stat
import subprocess
import sys

import numpy as np
import pytest

from kgnav import AbstractModel, ModelStore
from kgnav.common import atomic
from kgnav.common.atomic import atomic_open


@pytest.fixture
def umask():
    """Set the umask for a test, and restore it."""
    old = os.umask(0o022)
    os.umask(old)
    yield lambda mask: os.umask(mask)
    os.umask(old)


def _mode(p) -> int:
    return stat.S_IMODE(os.stat(p).st_mode)


def _write(path, text="x"):
    with atomic_open(path, "w") as fh:
        fh.write(text)


@pytest.mark.parametrize("mask", [0o022, 0o002, 0o077])
def test_new_file_follows_umask(tmp_path, umask, mask):
    umask(mask)
    assert atomic.current_umask() == mask
    _write(tmp_path / "a.txt")
    assert _mode(tmp_path / "a.txt") == 0o666 & ~mask


def test_replaced_file_keeps_its_mode(tmp_path, umask):
    umask(0o077)
    p = tmp_path / "shared.json"
    p.write_text("old")
    os.chmod(p, 0o664)
    _write(p, "new")
    assert p.read_text() == "new" and _mode(p) == 0o664


def test_model_html_and_plot_saves_are_group_readable(tmp_path, umask, tiny):
    """Every writer goes through atomic_open: models, the HTML export, plots."""
    from kgnav.memory.html import export_html

    umask(0o022)
    tiny.save(tmp_path / "m.graphml")
    export_html(tiny, tmp_path / "m.html")
    assert _mode(tmp_path / "m.graphml") == 0o644
    assert _mode(tmp_path / "m.html") == 0o644
    os.chmod(tmp_path / "m.html", 0o640)
    export_html(tiny, tmp_path / "m.html")
    assert _mode(tmp_path / "m.html") == 0o640


def test_save_through_symlink_keeps_the_link(tmp_path, tiny):
    real = tmp_path / "models" / "real.graphml"
    real.parent.mkdir()
    tiny.save(real)
    link = tmp_path / "current.graphml"
    link.symlink_to(real)
    bigger = tiny.copy()
    bigger.add_state(np.ones(4), (5, 5, 0))
    bigger.save(link)
    assert link.is_symlink() and os.readlink(link) == str(real)
    assert AbstractModel.load(real) == bigger
    assert sorted(p.name for p in real.parent.iterdir()) == ["real.graphml"]  # temp beside target


def test_dangling_link_and_loop_are_errors(tmp_path, tiny):
    dangling = tmp_path / "d.graphml"
    dangling.symlink_to(tmp_path / "nowhere" / "x.graphml")
    with pytest.raises(FileNotFoundError, match="dangling symbolic link"):
        tiny.save(dangling)
    assert not (tmp_path / "nowhere").exists()
    loop = tmp_path / "loop.graphml"
    loop.symlink_to(loop)
    with pytest.raises(OSError):
        tiny.save(loop)
    assert [p.name for p in tmp_path.iterdir() if p.name.endswith(".tmp")] == []


def test_directory_in_the_way_is_an_error(tmp_path, tiny):
    (tmp_path / "m.graphml").mkdir()
    with pytest.raises(IsADirectoryError):
        tiny.save(tmp_path / "m.graphml")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.graphml"]


def test_temp_name_names_its_writer(tmp_path):
    seen = []
    with atomic_open(tmp_path / "a.graphml", "wb") as fh:
        seen = [p.name for p in tmp_path.iterdir()]
        fh.write(b"x")
    (name,) = seen
    info = atomic.temp_file_info(name)
    assert info.target == "a.graphml" and info.pid == os.getpid() and info.this_host
    assert not atomic.stale_temp(name)  # this process is alive


def _dead_pid() -> int:
    proc = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    return int(proc.stdout)


def test_store_removes_temp_files_of_dead_writers_only(tmp_path, tiny):
    host = atomic._HOST
    dead = tmp_path / f".tiny.graphml.{_dead_pid()}-{host}.abc123.tmp"
    alive = tmp_path / f".tiny.graphml.{os.getpid()}-{host}.def456.tmp"
    other_host = tmp_path / f".tiny.graphml.{_dead_pid()}-{'0' * 8}.ghi789.tmp"
    legacy = tmp_path / ".tiny.graphml.x1y2z3.tmp"
    for p in (dead, alive, other_host, legacy):
        p.write_bytes(b"partial")
    store = ModelStore(tmp_path)
    good, problems = store.check()
    assert good == [] and {p.path for p in problems} == {str(dead), str(other_host), str(legacy)}
    assert all(p.kind == "temp" for p in problems)
    assert dead.exists()  # check changes nothing
    tiny.model_id = "tiny"
    store.save(tiny)
    assert not dead.exists()
    assert alive.exists() and other_host.exists() and legacy.exists()


def test_killed_save_leaves_a_temp_file_the_next_save_removes(tmp_path, tiny):
    """A writer killed mid-save: the model file is intact, the temp file goes at the next save."""
    store = ModelStore(tmp_path)
    store.save(tiny)
    before = (tmp_path / "tiny.graphml").read_bytes()
    script = (
        "import os, sys, numpy as np\n"
        f"sys.path.insert(0, {os.getcwd()!r})\n"
        "from kgnav import AbstractModel\n"
        "from kgnav.common.atomic import atomic_open\n"
        f"with atomic_open({str(tmp_path / 'tiny.graphml')!r}, 'wb') as fh:\n"
        "    fh.write(b'<graphml half written')\n"
        "    fh.flush()\n"
        "    os._exit(9)\n"
    )
    subprocess.run([sys.executable, "-c", script], check=False)
    temps = [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]
    assert len(temps) == 1 and (tmp_path / "tiny.graphml").read_bytes() == before
    assert [p.kind for p in store.check()[1]] == ["temp"]
    store.save(tiny)
    assert [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")] == []
    assert store.check() == (["tiny"], [])
