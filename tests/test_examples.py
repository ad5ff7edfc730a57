"""Every script in queries/ runs against a stored memory and prints what the API says."""

import subprocess
import sys
from pathlib import Path

import pytest

from kgnav import ModelStore, query
from kgnav.memory.demo import build_demo_memory

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = sorted(p.name for p in (ROOT / "queries").glob("*.py") if not p.name.startswith("_"))


@pytest.fixture(scope="module")
def memory(tmp_path_factory):
    path = tmp_path_factory.mktemp("memory")
    rows = build_demo_memory(path, worlds=2, episodes=2, steps=120, feature_dim=64)
    return path, rows


def run(script, *args):
    return subprocess.run([sys.executable, str(ROOT / "queries" / script), *map(str, args)],
                          capture_output=True, text=True, cwd=ROOT)


def test_every_example_is_covered():
    assert set(SCRIPTS) == {"goal_lookup.py", "visibility_ranking.py", "inventory_and_views.py",
                            "action_path.py", "relocate_and_merge.py", "store_questions.py"}


def test_goal_lookup(memory):
    path, _ = memory
    res = run("goal_lookup.py", "table", "--near", "1,1", "--store", path)
    assert res.returncode == 0, res.stderr
    store = ModelStore(path)
    for model_id in store.ids():
        goal = query.goal_point(store.load(model_id), "table", near=(1.0, 1.0))
        expect = f"{model_id}: no table" if goal is None else f"{model_id}: table {goal.id} at"
        assert expect in res.stdout


def test_visibility_ranking(memory):
    path, _ = memory
    res = run("visibility_ranking.py", "table", "--top", "2", "--store", path)
    assert res.returncode == 0, res.stderr
    store = ModelStore(path)
    for model_id in store.ids():
        ranked = query.ranked_objects(store.load(model_id), "table")[:2]
        for rank, obj in enumerate(ranked, 1):
            assert f"{rank}. {obj.id} views={obj.n_views}" in res.stdout


def test_inventory_and_views(memory):
    path, rows = memory
    model_id = rows[0].model_id
    res = run("inventory_and_views.py", model_id, "--state", "s5", "--store", path)
    assert res.returncode == 0, res.stderr
    model = ModelStore(path).load(model_id)
    for cls, counts in query.class_inventory(model).items():
        assert f"{cls}: {counts['objects']} objects, {counts['views']} views" in res.stdout
    for obj in query.visible_from(model, "s5"):
        assert f"{obj.cls} {obj.id}" in res.stdout


def test_action_path(memory):
    path, rows = memory
    model = ModelStore(path).load(rows[0].model_id)
    res = run("action_path.py", rows[0].model_id, "s0", "s12", "--store", path)
    assert res.returncode == 0, res.stderr
    actions = query.action_path(model, "s0", "s12")
    assert f"{len(actions)} actions: {' '.join(actions)}" in res.stdout
    bad = run("action_path.py", rows[0].model_id, "s0", "s99999", "--store", path)
    assert bad.returncode == 1 and "no state 's99999'" in bad.stderr


def test_relocate_and_merge(memory, tmp_path):
    from kgnav.memory.synthetic import SyntheticWorld

    path, _ = memory
    # a new episode in the demo's first world (seed 0) relocates into that world's model
    episode = SyntheticWorld(seed=0, feature_dim=64).explore(120, episode=7, seed=77)
    f = tmp_path / "ep.graphml"
    episode.save(f)
    res = run("relocate_and_merge.py", f, "--store", path)
    assert res.returncode == 0, res.stderr
    assert "matches w0-" in res.stdout
    stranger = SyntheticWorld(seed=999, feature_dim=64).explore(60, episode=0, seed=1)
    stranger.save(f)
    res = run("relocate_and_merge.py", f, "--store", path)
    assert "a new environment" in res.stdout


def test_empty_store_message(tmp_path):
    res = run("goal_lookup.py", "chair", "--store", tmp_path)
    assert res.returncode == 1 and "no models here" in res.stderr


def test_store_questions_answer_alike_on_a_directory_and_a_database(memory, cli):
    pytest.importorskip("ladybug")
    path, _ = memory
    db = path.parent / "memory.lbug"
    if not db.exists():
        assert cli("store", "convert", path, db)[0] == 0
    store = ModelStore(path)
    model_id = store.ids()[0]
    model = store.load(model_id)
    chair = query.ranked_objects(model, "chair")[0].id
    a_cls, b_cls = list(query.class_inventories(store)[model_id])[:2]
    asked = [("objects", "chair"), ("objects", "chair", "--min-views", "3"),
             ("near", a_cls, b_cls, "6"), ("saw", model_id, chair), ("inventory",),
             ("within", model_id, "s0", "2")]
    for args in asked:
        a = run("store_questions.py", "--store", path, *args)
        b = run("store_questions.py", "--store", db, *args)
        assert a.returncode == 0 and b.returncode == 0, (args, a.stderr, b.stderr)
        assert a.stdout == b.stdout and a.stdout.strip(), args
    saw = run("store_questions.py", "--store", db, "saw", model_id, chair).stdout.split("\n")
    dists = [float(line.split()[-2]) for line in saw if line]
    assert dists == sorted(dists) and len(dists) == query.ranked_objects(model, "chair")[0].n_views
