import multiprocessing as mp

import networkx as nx
import numpy as np
import pytest

from kgnav import AbstractModel, ModelFileError, ModelStore, StoreError
from kgnav.merge import merge


def _model(mid, n=3, dim=4):
    m = AbstractModel(feature_dim=dim, model_id=mid)
    for i in range(n):
        m.add_state(np.eye(dim, dtype=np.float32)[i % dim] + i, (0.5 * i, 0, 0))
    return m


def test_save_list_load_delete(tmp_path):
    store = ModelStore(tmp_path / "mem")
    assert store.ids() == [] and len(store) == 0
    a, b = _model("house-a"), _model("house-b", 5)
    assert store.save(b).name == "house-b.graphml"
    store.save(a)
    assert store.ids() == ["house-a", "house-b"]
    assert "house-a" in store and "house-c" not in store
    assert store.load("house-b") == b
    store.delete("house-a")
    assert store.ids() == ["house-b"]
    with pytest.raises(StoreError, match="no model 'house-a'"):
        store.delete("house-a")
    with pytest.raises(StoreError, match="no model 'nope'"):
        store.load("nope")


def test_save_replaces(tmp_path):
    store = ModelStore(tmp_path)
    a = _model("a")
    store.save(a)
    a.add_state(np.ones(4), (9, 9, 0))
    store.save(a)
    assert store.load("a").n_states == 4


@pytest.mark.parametrize("bad", ["../escape", "a/b", "", "-x", "a b"])
def test_unsafe_ids_rejected(tmp_path, bad):
    with pytest.raises(StoreError, match="invalid model id"):
        ModelStore(tmp_path).path_of(bad)


def test_bad_files_reported_skipped_and_kept(tmp_path):
    store = ModelStore(tmp_path)
    store.save(_model("good"))
    (tmp_path / "corrupt.graphml").write_text("<graphml><node")
    nx.write_graphml(nx.path_graph(2), tmp_path / "foreign.graphml")
    _model("inner").save(tmp_path / "renamed.graphml")
    (tmp_path / "notes.txt").write_text("not a model")
    models, problems = store.load_all()
    assert list(models) == ["good"]
    reasons = {p.path.rsplit("/", 1)[1]: p.reason for p in problems}
    assert set(reasons) == {"corrupt.graphml", "foreign.graphml", "renamed.graphml"}
    assert "not valid XML" in reasons["corrupt.graphml"]
    assert "not a kgnav Abstract Model" in reasons["foreign.graphml"]
    assert "holds model 'inner'" in reasons["renamed.graphml"]
    for name in reasons:  # never deleted
        assert (tmp_path / name).exists()
    with pytest.raises(ModelFileError, match="corrupt.graphml"):
        store.load("corrupt")


def test_not_a_directory(tmp_path):
    f = tmp_path / "file"
    f.write_text("x")
    with pytest.raises(StoreError, match="not a directory"):
        ModelStore(f)


def _extend(args):
    root, worker = args
    store = ModelStore(root)
    for i in range(5):
        def grow(cur, i=i):
            extra = AbstractModel(feature_dim=4, model_id=f"w{worker}x{i}")
            extra.add_state(np.array([worker, i, 1, 1], dtype=np.float32), (worker * 10.0, i, 0))
            return merge(cur, extra)
        store.update("shared", grow)
    return worker


def test_two_writers_lose_nothing(tmp_path):
    store = ModelStore(tmp_path)
    store.save(_model("shared", 1))
    ctx = mp.get_context("spawn")
    with ctx.Pool(2) as pool:
        assert sorted(pool.map(_extend, [(str(tmp_path), 1), (str(tmp_path), 2)])) == [1, 2]
    final = store.load("shared")
    assert final.n_states == 1 + 2 * 5
    assert len(final.merged_from) == 10
    assert [p.name for p in tmp_path.iterdir() if p.name.endswith(".tmp")] == []


def test_update_creates_when_missing(tmp_path):
    store = ModelStore(tmp_path)
    made = store.update("fresh", lambda cur: cur if cur is not None else _model("fresh"))
    assert store.load("fresh") == made
    with pytest.raises(StoreError, match="returned model 'other'"):
        store.update("fresh", lambda cur: _model("other"))
