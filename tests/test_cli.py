import json
import subprocess
import sys

import pytest


def run(*args):
    """Run the CLI in a subprocess (as a user would); returns the CompletedProcess."""
    return subprocess.run([sys.executable, "-m", "kgnav.cli", *map(str, args)],
                          capture_output=True, text=True)


@pytest.fixture
def files(tmp_path, world):
    a = world.explore(100, episode=0, seed=21)
    b = world.explore(100, episode=1, seed=22)
    pa, pb = tmp_path / "a.graphml", tmp_path / "b.graphml"
    a.save(pa)
    b.save(pb)
    return tmp_path, a, b, pa, pb


def test_inspect_json(cli, files):
    _, a, _, pa, _ = files
    code, out, err = cli("inspect", pa, "--json")
    assert code == 0, err
    info = json.loads(out)
    assert info["states"] == a.n_states and info["model_id"] == a.model_id
    code, out, _ = cli("inspect", pa)
    assert code == 0 and a.model_id in out and "class inventory" in out


def test_query_json(cli, files):
    from kgnav import query

    _, a, _, pa, _ = files
    cls = next(iter(query.class_inventory(a)))
    code, out, err = cli("query", pa, "--goal", cls, "--near", "1,-2", "--json")
    assert code == 0, err
    res = json.loads(out)
    expect = query.goal_point(a, cls, near=(1.0, -2.0))
    assert res["goal_point"]["id"] == expect.id
    assert len(res["ranking"]) == len(query.ranked_objects(a, cls))


def test_merge_auto_and_explicit(cli, files):
    from kgnav import AbstractModel, best_anchor, merge

    tmp, a, b, pa, pb = files
    out_path = tmp / "m.graphml"
    code, out, err = cli("merge", pa, pb, "-o", out_path)
    assert code == 0, err
    ta, sb, _ = best_anchor(a, b)
    assert AbstractModel.load(out_path) == merge(a, b, anchor=(ta, sb))
    code, _, err = cli("merge", pa, pb, "-o", out_path, "--anchor", "s3:s4")
    assert code == 0, err
    assert AbstractModel.load(out_path) == merge(a, b, anchor=("s3", "s4"))


def test_store_ls(cli, tmp_path, files):
    from kgnav import ModelStore

    _, a, b, _, _ = files
    store = ModelStore(tmp_path / "mem")
    store.save(a)
    store.save(b)
    (tmp_path / "mem" / "broken.graphml").write_text("<graphml")
    code, out, err = cli("store", "ls", tmp_path / "mem", "--json")
    assert code == 0
    listing = json.loads(out)
    assert sorted(r["model_id"] for r in listing["models"]) == sorted([a.model_id, b.model_id])
    assert listing["skipped"][0]["path"].endswith("broken.graphml")
    assert "broken.graphml" in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize(
    "args, needle",
    [
        (["inspect"], "Missing argument 'FILE'"),
        (["frobnicate"], "No such command 'frobnicate'"),
        (["query", "{a}", "--goal", "chair", "--near", "1"], "expected X,Y"),
        (["merge", "{a}", "{b}", "-o", "{o}", "--anchor", "s1"], "TARGET_STATE:SOURCE_STATE"),
        (["merge", "{a}", "{b}"], "Missing option '-o'"),
        (["query", "{a}", "--goal", "chair", "--top", "0"], "--top"),
    ],
)
def test_usage_errors_exit_2_with_one_line(files, args, needle):
    tmp, _, _, pa, pb = files
    args = [x.format(a=pa, b=pb, o=tmp / "o.graphml") for x in args]
    res = run(*args)
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0] and lines[0].startswith("kgnav: usage error")


@pytest.mark.parametrize(
    "args, needle",
    [
        (["inspect", "{missing}"], "missing.graphml: no such file"),
        (["inspect", "{corrupt}"], "corrupt.graphml: not valid XML"),
        (["query", "{a}", "--goal", "spaceship"], "a.graphml: unknown object class 'spaceship'"),
        (["merge", "{a}", "{b}", "-o", "{o}", "--anchor", "s1:s9999"],
         "b.graphml: no state 's9999'"),
        (["export", "{corrupt}", "--html", "{o}"], "corrupt.graphml"),
        (["store", "ls", "{missing}"], "missing.graphml: not a directory"),
    ],
)
def test_data_errors_exit_1_with_one_line(files, args, needle):
    tmp, _, _, pa, pb = files
    corrupt = tmp / "corrupt.graphml"
    corrupt.write_text("<graphml><node id=")
    args = [x.format(a=pa, b=pb, o=tmp / "o.graphml", missing=tmp / "missing.graphml",
                     corrupt=corrupt) for x in args]
    res = run(*args)
    assert res.returncode == 1, res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0] and lines[0].startswith("kgnav: error")


def test_failed_merge_leaves_output_untouched(files):
    tmp, _, _, pa, pb = files
    out = tmp / "keep.graphml"
    out.write_text("precious")
    res = run("merge", pa, pb, "-o", out, "--anchor", "s1:s9999")
    assert res.returncode == 1 and out.read_text() == "precious"


def test_printed_text_is_text(cli, tmp_path):
    """Rich markup in a class or file name is printed as it is; control characters escaped."""
    import numpy as np

    from kgnav import AbstractModel, Detection

    m = AbstractModel(feature_dim=2, model_id="m", classes=("[/bold]", "[red]x[/red]"),
                      extractor="ext\nline")
    m.add_state(np.ones(2), (0, 0, 0), [Detection("[/bold]", (1.0, 0.0, 0.0))])
    m.add_state(np.ones(2), (1, 0, 0), [Detection("[red]x[/red]", (1.0, 0.0, 0.0))])
    path = tmp_path / "[bold]odd\x1b[31m\nname.graphml"
    m.save(path)
    code, out, err = cli("inspect", path)
    assert code == 0, err
    assert "[bold]odd\\x1b[31m\\nname.graphml" in out and "\x1b" not in out
    assert "[/bold]" in out and "[red]x[/red]" in out and "ext\\nline" in out
    code, out, err = cli("query", path, "--goal", "[/bold]")
    assert code == 0 and "object o0 at" in out
    code, _, err = cli("query", path, "--goal", "[bold]nope\n")
    assert code == 1 and err.count("\n") == 1 and "'[bold]nope\\n'" in err


def test_store_check(cli, tmp_path, files):
    from kgnav import ModelStore

    _, a, _, _, _ = files
    store_dir = tmp_path / "mem"
    ModelStore(store_dir).save(a)
    code, out, err = cli("store", "check", store_dir)
    assert code == 0 and out.strip().endswith("1 models load, 0 problems"), err
    (store_dir / "broken.graphml").write_text("<graphml")
    (store_dir / "d.graphml").mkdir()
    (store_dir / ".x.graphml.abc.tmp").write_text("partial")
    before = sorted(p.name for p in store_dir.iterdir())
    code, out, err = cli("store", "check", store_dir, "--json")
    assert code == 1
    report = json.loads(out)
    assert report["models"] == [a.model_id]
    assert sorted(p["kind"] for p in report["problems"]) == ["entry", "model", "temp"]
    assert sorted(p.name for p in store_dir.iterdir()) == before  # nothing changed
    code, out, err = cli("store", "check", store_dir)
    assert code == 1 and len(out.strip().splitlines()) == 4 and "3 problems" in out
    code, out, _ = cli("store", "ls", store_dir)
    assert code == 0


def test_hostile_inputs_get_one_line(cli, tmp_path):
    import os

    fifo = tmp_path / "pipe.graphml"
    os.mkfifo(fifo)  # inspect must not wait for a writer
    loop = tmp_path / "loop.graphml"
    loop.symlink_to(loop)
    for path, needle in [(fifo, "not a regular file (a FIFO"), (loop, "symbolic link loop")]:
        code, _, err = cli("inspect", path)
        assert code == 1 and err.count("\n") == 1 and needle in err, err


def test_unwritable_output_is_one_line(cli, files, tmp_path):
    _, _, _, pa, pb = files
    blocker = tmp_path / "not-a-dir"
    blocker.write_text("x")
    code, _, err = cli("merge", pa, pb, "-o", blocker / "m.graphml")
    assert code == 1 and err.count("\n") == 1 and err.startswith("kgnav: error: "), err
    assert "not-a-dir" in err and "Traceback" not in err
