import multiprocessing as mp
import os

import networkx as nx
import numpy as np
import pytest

from kgnav import AbstractModel, ModelFileError, ModelStore, StoreError
from kgnav.memory.merge import merge


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


def test_entries_that_are_not_files_are_reported(tmp_path):
    store = ModelStore(tmp_path)
    store.save(_model("good"))
    (tmp_path / "dir.graphml").mkdir()
    (tmp_path / "dangling.graphml").symlink_to(tmp_path / "gone.graphml")
    (tmp_path / "loop.graphml").symlink_to(tmp_path / "loop.graphml")
    os.mkfifo(tmp_path / "fifo.graphml")
    (tmp_path / "link.graphml").symlink_to(tmp_path / "good.graphml")  # a link to a model: fine
    (tmp_path / "bad name.graphml").write_text("x")
    assert store.ids() == ["bad name", "good", "link"]
    models, problems = store.load_all()
    assert list(models) == ["good"]
    reasons = {os.path.basename(p.path): (p.kind, p.reason) for p in problems}
    assert reasons == {
        "dangling.graphml": ("entry", f"dangling symbolic link (to {tmp_path / 'gone.graphml'})"),
        "dir.graphml": ("entry", "not a regular file (a directory)"),
        "fifo.graphml": ("entry", "not a regular file (a FIFO (named pipe))"),
        "loop.graphml": ("entry", "symbolic link loop"),
        "bad name.graphml": ("model", "invalid model id 'bad name': use letters, digits and "
                             "_ . + - (max 128)"),
        "link.graphml": ("model", "holds model 'good', but its file name says 'link'"),
    }
    good, problems_checked = store.check()
    assert good == ["good"] and problems_checked == problems
    with pytest.raises(ModelFileError, match="fifo.graphml: not a regular file"):
        store.load("fifo")  # never blocks waiting for a writer


@pytest.mark.parametrize("bad", ["abc\n", "a\nb", "..", "x" * 129])
def test_ids_with_a_newline_or_too_long_rejected(tmp_path, bad):
    with pytest.raises(StoreError, match="invalid model id"):
        ModelStore(tmp_path).path_of(bad)
    with pytest.raises(ValueError):
        AbstractModel(feature_dim=2, model_id=bad)


def test_size_limit(tmp_path, monkeypatch):
    store = ModelStore(tmp_path, max_bytes=1000)
    ModelStore(tmp_path).save(_model("big", n=4, dim=64))
    with pytest.raises(ModelFileError, match=r"big.graphml: [0-9.]+ kB, over the 1.0 kB limit"):
        store.load("big")
    monkeypatch.setenv("KGNAV_MAX_MODEL_BYTES", "1K")
    with pytest.raises(ModelFileError, match="over the 1.0 kB limit"):
        ModelStore(tmp_path).load("big")
    monkeypatch.setenv("KGNAV_MAX_MODEL_BYTES", "1M")
    assert ModelStore(tmp_path).load("big").n_states == 4


def test_write_problems_are_store_errors(tmp_path):
    (tmp_path / "m.graphml").mkdir()  # a directory where the model file should be
    store = ModelStore(tmp_path)
    with pytest.raises(StoreError, match="m.graphml: cannot write"):
        store.save(_model("m"))
    with pytest.raises(ModelFileError, match="not a regular file .a directory."):
        store.update("m", lambda cur: _model("m"))
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(StoreError, match="cannot lock"):
        ModelStore(blocker / "sub").save(_model("m"))
