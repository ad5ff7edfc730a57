"""The graph-database store: the same models as GraphML, one transaction a save, bad files
refused, no update lost, and a killed writer never leaves half a model."""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import signal
import subprocess
import sys
import time

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

try:
    import ladybug  # noqa: F401
except ImportError:  # pragma: no cover - the dev extra installs it
    if os.environ.get("KGNAV_REQUIRE_GRAPHDB") == "1":  # CI: a missing database fails
        raise
    pytest.skip("ladybug is not installed (pip install 'kgnav[graphdb]')", allow_module_level=True)

from kgnav import AbstractModel, ModelStore, StoreError  # noqa: E402
from kgnav.memory import graphdb  # noqa: E402
from kgnav.memory.graphml import to_graphml  # noqa: E402
from kgnav.memory.synthetic import SyntheticWorld  # noqa: E402
from tests.strategies import models  # noqa: E402


def _walk(seed: int = 0, steps: int = 120, model_id: str | None = None) -> AbstractModel:
    world = SyntheticWorld(seed=seed, size=(12.0, 12.0), n_objects=30, feature_dim=16)
    m = world.explore(steps, seed=seed)
    if model_id is not None:
        m.graph.graph["model_id"] = model_id
    return m


@settings(max_examples=25, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(m=models(scan=True), tag=st.sampled_from([None, 7, 2.5, "note", True]))
def test_a_model_comes_back_equal_and_in_order(tmp_path_factory, m, tag):
    if tag is not None:  # an attribute outside the schema, as another tool may add
        first = next(iter(m.graph.nodes))
        m.graph.nodes[first]["other_tool"] = tag
    root = tmp_path_factory.mktemp("db") / "memory.lbug"
    store = ModelStore(root)
    assert isinstance(store, graphdb.GraphDBStore)
    store.save(m)
    back = store.load(m.model_id)
    path = root.parent / "m.graphml"
    m.save(path)
    assert back == m == AbstractModel.load(path)
    assert to_graphml(back) == to_graphml(m)  # same order: the same file byte for byte
    for s in m.states():
        assert back.features(s).tobytes() == m.features(s).tobytes()


def test_a_store_of_walks_round_trips_and_lists(tmp_path):
    store = ModelStore(tmp_path / "memory.lbug")
    walks = {f"house-{i}": _walk(i, model_id=f"house-{i}") for i in range(3)}
    for w in walks.values():
        store.save(w)
    assert store.ids() == sorted(walks)
    models_, problems = store.load_all()
    assert problems == [] and models_ == walks
    assert store.check() == (sorted(walks), [])
    store.delete("house-1")
    assert store.ids() == ["house-0", "house-2"]
    with pytest.raises(StoreError, match="no model 'house-1'"):
        store.load("house-1")
    with pytest.raises(StoreError, match="no model 'house-1'"):
        store.delete("house-1")
    smaller = _walk(0, steps=30, model_id="house-0")
    store.save(smaller)  # a new version replaces the old one whole
    assert store.load("house-0") == smaller


def test_an_empty_or_missing_database_holds_nothing(tmp_path):
    store = ModelStore(tmp_path / "none.lbug")
    assert store.ids() == [] and len(store) == 0
    assert not (tmp_path / "none.lbug").exists()  # reading creates nothing
    with pytest.raises(StoreError, match="invalid model id"):
        store.load("../x")


def test_bad_files_are_refused_in_one_line_and_left_alone(tmp_path):
    text = tmp_path / "text.lbug"
    text.write_text("<graphml/>")
    with pytest.raises(StoreError, match="not a LadybugDB database"):
        ModelStore(text)
    fifo = tmp_path / "fifo.lbug"
    os.mkfifo(fifo)
    t = time.perf_counter()
    with pytest.raises(StoreError, match="not a regular file"):
        ModelStore(fifo)
    assert time.perf_counter() - t < 1.0
    (tmp_path / "dir.lbug").mkdir()
    with pytest.raises(StoreError, match="a directory"):
        ModelStore(tmp_path / "dir.lbug")
    junk = tmp_path / "junk.lbug"
    junk.write_bytes(bytes(range(256)) * 64)
    before = junk.read_bytes()
    with pytest.raises(StoreError, match="not a LadybugDB database|not a kgnav memory"):
        ModelStore(junk).ids()
    assert junk.read_bytes() == before


def test_another_layout_or_another_database_is_refused(tmp_path):
    import ladybug

    other = tmp_path / "other.lbug"
    db = ladybug.Database(str(other))
    conn = ladybug.Connection(db)
    conn.execute("CREATE NODE TABLE Person(name STRING, PRIMARY KEY(name))")
    conn.close()
    db.close()
    with pytest.raises(StoreError, match="not a kgnav memory"):
        ModelStore(other).ids()
    old = tmp_path / "old.lbug"
    ModelStore(old).save(_walk(1, steps=10, model_id="h"))
    db = ladybug.Database(str(old))
    conn = ladybug.Connection(db)
    conn.execute("MATCH (m:Meta) SET m.version = 99")
    conn.close()
    db.close()
    with pytest.raises(StoreError, match="layout version 99") as exc:
        ModelStore(old).load("h")
    assert "upgrade" not in str(exc.value)  # only version 1 has a way up
    with pytest.raises(StoreError, match="layout version 99, this kgnav upgrades version 1"):
        ModelStore(old).upgrade()


def _as_layout_1(root) -> None:
    """Turn a database into what kgnav wrote before layout version 2: no Model -> State/Object
    relationships."""
    db = ladybug.Database(str(root))
    conn = ladybug.Connection(db)
    for rel in ("HasState", "HasObject"):
        conn.execute(f"DROP TABLE {rel}")
    conn.execute("MATCH (m:Meta) WHERE m.key = 'kgnav' SET m.version = 1")
    conn.close()
    db.close()


def _orphans(store) -> int:
    """States and objects that no model holds."""
    return sum(store.cypher(f"MATCH (n:{t}) WHERE NOT EXISTS {{ MATCH (:Model)-[:{r}]->(n) }} "
                            f"RETURN count(*)")[1][0][0]
               for t, r in (("State", "HasState"), ("Object", "HasObject")))


def test_each_model_holds_its_nodes_through_every_write(tmp_path):
    store = ModelStore(tmp_path / "memory.lbug")
    walks = [_walk(i, steps=40, model_id=f"h{i}") for i in range(3)]
    for w in walks:
        store.save(w)
    store.save(_walk(7, steps=25, model_id="h1"))  # replaced: the old nodes go with the model
    store.update("h2", lambda m: _walk(8, steps=30, model_id="h2"))
    store.delete("h0")
    held = dict(store.cypher("MATCH (m:Model)-[:HasState]->(s:State) RETURN m.id, count(s)")[1])
    assert held == {"h1": _walk(7, steps=25).n_states, "h2": _walk(8, steps=30).n_states}
    assert store.state_count() == sum(held.values()) and _orphans(store) == 0


def test_a_layout_1_database_is_refused_until_upgraded(tmp_path, cli, monkeypatch):
    root = tmp_path / "old.lbug"
    walks = {f"h{i}": _walk(i, steps=40, model_id=f"h{i}") for i in range(2)}
    for w in walks.values():
        ModelStore(root).save(w)
    revision = ModelStore(root).revision()
    _as_layout_1(root)
    with pytest.raises(StoreError, match="layout version 1.*kgnav store upgrade"):
        ModelStore(root).load("h0")

    def boom(conn, version):
        raise RuntimeError("disk full")

    monkeypatch.setattr(graphdb, "_set_version", boom)  # the transaction's last statement
    with pytest.raises(RuntimeError, match="disk full"):
        ModelStore(root).upgrade()
    monkeypatch.undo()
    with pytest.raises(StoreError, match="layout version 1"):  # as it was
        ModelStore(root).ids()

    code, out, err = cli("store", "upgrade", root)
    assert code == 0, err
    assert "layout version 1 -> 2" in out
    store = ModelStore(root)
    assert {k: store.load(k) for k in store.ids()} == walks and _orphans(store) == 0
    assert store.revision() == revision  # no model changed: a saved relocator index stays valid
    assert store.upgrade() == graphdb.DB_SCHEMA_VERSION  # already current: nothing to do
    (tmp_path / "dir").mkdir()
    code, _, err = cli("store", "upgrade", tmp_path / "dir")
    assert code == 1 and len(err.strip().splitlines()) == 1 and "no layout to upgrade" in err


def test_a_failed_save_keeps_the_previous_version(tmp_path, monkeypatch):
    store = ModelStore(tmp_path / "memory.lbug")
    first = _walk(2, model_id="h")
    store.save(first)
    real = graphdb._insert

    def half(conn, rows):  # the new version's model and states are written, then it fails
        real(conn, {**rows, "edges": {"transition": [], "sees": []}})
        raise OSError("disk full")

    monkeypatch.setattr(graphdb, "_insert", half)
    with pytest.raises(OSError, match="disk full"):
        store.save(_walk(3, model_id="h"))
    monkeypatch.setattr(graphdb, "_insert", real)
    assert store.load("h") == first


def test_two_processes_updating_one_database_lose_nothing(tmp_path):
    from tests.test_store import _extend, _model  # the directory store's own concurrency test

    root = tmp_path / "memory.lbug"
    ModelStore(root).save(_model("shared", 1))
    with mp.get_context("spawn").Pool(2) as pool:
        assert sorted(pool.map(_extend, [(str(root), 1), (str(root), 2)])) == [1, 2]
    final = ModelStore(root).load("shared")
    assert final.n_states == 1 + 2 * 5 and len(final.merged_from) == 10


_WRITER = """
import sys
from kgnav import ModelStore
from kgnav.memory.synthetic import SyntheticWorld
store = ModelStore(sys.argv[1])
walks = [SyntheticWorld(seed=s, size=(12.0, 12.0), n_objects=30, feature_dim=16).explore(
    400, seed=s) for s in (5, 6)]
for w in walks:
    w.graph.graph["model_id"] = "h"
print("ready", flush=True)
i = 0
while True:
    store.save(walks[i % 2])
    i += 1
"""


@pytest.mark.parametrize("trial", range(4))
def test_kill_9_mid_save_leaves_a_whole_model(tmp_path, trial):
    root = tmp_path / "memory.lbug"
    versions = []
    for s in (5, 6):
        w = SyntheticWorld(seed=s, size=(12.0, 12.0), n_objects=30, feature_dim=16).explore(
            400, seed=s)
        w.graph.graph["model_id"] = "h"
        versions.append(w)
    ModelStore(root).save(versions[0])
    proc = subprocess.Popen([sys.executable, "-c", _WRITER, str(root)], stdout=subprocess.PIPE,
                            text=True)
    assert proc.stdout.readline().strip() == "ready"
    time.sleep(0.15 + 0.37 * trial)  # somewhere inside a save
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    back = ModelStore(root).load("h")
    assert back == versions[0] or back == versions[1]


def test_store_commands_work_on_a_database(tmp_path, cli):
    root = tmp_path / "memory.lbug"
    ModelStore(root).save(_walk(1, steps=20, model_id="h1"))
    code, out, err = cli("store", "ls", root, "--json")
    assert code == 0, err
    assert [r["model_id"] for r in json.loads(out)["models"]] == ["h1"]
    assert cli("store", "check", root)[0] == 0


def test_convert_both_ways_gives_equal_models_and_skips_bad_files(tmp_path, cli, world):
    src = tmp_path / "dir"
    store = ModelStore(src)
    walks = {f"h{i}": world.explore(60, episode=i, seed=30 + i) for i in range(2)}
    for k, w in walks.items():
        w.graph.graph["model_id"] = k
        store.save(w)
    (src / "broken.graphml").write_text("<graphml")
    code, out, err = cli("store", "convert", src, tmp_path / "m.lbug")
    assert code == 0, err
    assert "broken.graphml" in err and "skipped" in err
    assert "2 models" in out
    code, out, err = cli("store", "convert", tmp_path / "m.lbug", tmp_path / "back")
    assert code == 0, err
    again, problems = ModelStore(tmp_path / "back").load_all()
    assert problems == [] and again == walks
    code, _, err = cli("store", "convert", tmp_path / "missing", tmp_path / "x.lbug")
    assert code == 1 and "no such store" in err and len(err.strip().splitlines()) == 1


def test_cypher_reads_and_refuses_writes(tmp_path, cli):
    root = tmp_path / "memory.lbug"
    w = _walk(1, steps=40, model_id="h1")
    ModelStore(root).save(w)
    code, out, err = cli("cypher", root, "MATCH (o:Object) RETURN o.cls AS cls, o.x AS x "
                         "ORDER BY o.ord", "--json")
    assert code == 0, err
    rows = json.loads(out)["rows"]
    objects = [w.object_info(o) for o in w.objects()]
    assert [(r["cls"], r["x"]) for r in rows] == [(o.cls, o.position[0]) for o in objects]
    before = root.read_bytes()
    for write in ("MATCH (o:Object) DETACH DELETE o", "CREATE (:Model {id: 'x'})",
                  "MATCH (o:Object) SET o.cls = 'bed'"):
        code, _, err = cli("cypher", root, write)
        assert code == 1 and "would write is refused" in err and len(err.splitlines()) == 1
    assert ModelStore(root).load("h1") == w and root.read_bytes() == before
    code, _, err = cli("cypher", tmp_path, "RETURN 1")
    assert code == 1 and "directory store" in err


def test_the_documented_questions_run_on_the_demo_memory(tmp_path, cli):
    import re
    from pathlib import Path

    from kgnav.memory.demo import build_demo_memory

    build_demo_memory(tmp_path / "memory", worlds=3, episodes=3, steps=200, seed=0)
    code, _, err = cli("store", "convert", tmp_path / "memory", tmp_path / "memory.lbug")
    assert code == 0, err
    doc = (Path(__file__).resolve().parents[1] / "docs" / "graphdb.md").read_text()
    queries = re.findall(r"```cypher\n(.*?)\n```", doc, re.S)
    assert len(queries) == 10
    store = ModelStore(tmp_path / "memory.lbug")
    answered = 0
    for q in queries:
        columns, rows = store.cypher(q)
        assert columns
        answered += bool(rows)
    assert answered == 10  # every question has an answer in the demo memory


def test_eval_keeps_its_memory_in_a_database_with_the_same_results(tmp_path, cli):
    from kgnav.benchmark.runner import EvalConfig, run_eval

    quick = dict(split="val-small", scenes=1, episodes=3, max_steps=100,
                 extractor="opencv-gist", pre_explore_steps=120, variants=("si", "sp"))
    run_eval(EvalConfig(**quick), tmp_path / "dir", progress=False)
    run_eval(EvalConfig(**quick, store="ladybug"), tmp_path / "db", progress=False)
    a, b = tmp_path / "dir", tmp_path / "db"
    assert (a / "episodes.jsonl").read_bytes() == (b / "episodes.jsonl").read_bytes()
    for name, db in (("si", "si.lbug"), ("pre-explored", "pre-explored/models.lbug")):
        files, _ = ModelStore(a / "memory" / name).load_all()
        stored, problems = ModelStore(b / "memory" / db).load_all()
        assert problems == [] and stored == files and files
    config = json.loads((b / "config.json").read_text())
    assert config["execution"]["store"] == "ladybug" and "store" not in config
    code, out, err = cli("memory-map", b, "--variant", "si", "--out", tmp_path / "maps")
    assert code == 0, err
    assert out.strip().endswith(".png")
