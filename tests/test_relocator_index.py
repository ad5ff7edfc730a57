"""A relocator fitted from a store without loading its models, saved beside it and reopened."""

import functools
import io
import os
import zipfile

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from kgnav import KgnavError, ModelStore, Relocator, StoreError
from kgnav.memory import graphdb
from tests.strategies import DIM, models, walk_model

pytest.importorskip("ladybug")


_walk = walk_model


def _store(root, ms) -> ModelStore:
    store = ModelStore(root)
    for m in ms:
        store.save(m)
    return store


def _same(a: Relocator, b: Relocator) -> None:
    assert a.model_ids_ == b.model_ids_ and a._owners == b._owners
    assert np.array_equal(a._table.vectors, b._table.vectors)
    assert {k: v.tolist() for k, v in a._rows.items()} == {k: v.tolist() for k, v in
                                                           b._rows.items()}


@settings(max_examples=15, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(ms=st.lists(models(), min_size=1, max_size=4, unique_by=lambda m: m.model_id),
       where=st.sampled_from(["dir", "m.lbug"]), batch=st.integers(1, 5))
def test_a_streamed_fit_equals_a_fit_over_the_loaded_models(tmp_path_factory, ms, where,
                                                             batch, monkeypatch):
    store = _store(tmp_path_factory.mktemp("s") / where, ms)
    monkeypatch.setattr(graphdb.GraphDBStore, "feature_batches", functools.partialmethod(
        graphdb.GraphDBStore.feature_batches, batch=batch))
    loaded = Relocator().fit(store.load_all()[0].values())
    streamed = Relocator().fit(store)
    _same(loaded, streamed)
    assert streamed.n_states_ == sum(m.n_states for m in ms) and streamed.feature_dim_ == DIM


def _spoil(db, key: str, blob: bytes) -> None:
    import ladybug

    conn = ladybug.Connection(ladybug.Database(str(db)))
    conn.execute("MATCH (s:State) WHERE s.key = $k SET s.features = $b", {"k": key, "b": blob})


@pytest.mark.parametrize("blob", [b"\0" * 12, np.full(8, np.nan, "<f4").tobytes()])
def test_a_model_with_a_bad_feature_late_in_it_is_taken_back_whole(tmp_path, blob,
                                                                     monkeypatch):
    db = tmp_path / "m.lbug"
    store = _store(db, [_walk("a", 5, 0), _walk("b", 9, 1), _walk("c", 3, 2)])
    _spoil(db, "b/s7", blob)  # in b's fourth batch of two
    problems = []
    batches = list(store.feature_batches(problems, batch=2))
    assert [(b.model_id, b.retract) for b in batches if b.model_id == "b"][-1] == ("b", True)
    assert len(problems) == 1 and "b" in problems[0].path
    monkeypatch.setattr(graphdb.GraphDBStore, "feature_batches", functools.partialmethod(
        graphdb.GraphDBStore.feature_batches, batch=2))
    r = Relocator().fit(store)
    assert r.model_ids_ == ["a", "c"] and r.n_states_ == 8 and len(r.problems_) == 1
    assert {m for m, _ in r._owners} == {"a", "c"}
    _same(r, Relocator().fit([store.load("a"), store.load("c")]))


@pytest.mark.parametrize("where", ["dir", "m.lbug"])
def test_the_revision_changes_with_every_write_and_only_then(tmp_path, where):
    store = _store(tmp_path / where, [_walk("a", 3, 0)])
    seen = {store.revision()}
    store.load("a"), store.ids(), Relocator().fit(store)
    assert store.revision() in seen
    for write in (lambda: store.save(_walk("b", 2, 1)),
                  lambda: store.update("a", lambda m: _walk("a", 4, 3)),
                  lambda: store.save(_walk("a", 4, 3)),  # the same model again still counts
                  lambda: store.delete("b")):
        write()
        assert store.revision() not in seen
        seen.add(store.revision())


def test_two_databases_with_as_many_writes_have_different_revisions(tmp_path):
    a = _store(tmp_path / "a.lbug", [_walk("a", 3, 0)])
    b = _store(tmp_path / "b.lbug", [_walk("a", 3, 0)])
    assert a.revision() != b.revision()


@pytest.mark.parametrize("backend", ["exact", "hnsw"])
def test_a_saved_index_answers_as_the_fitted_one(tmp_path, backend, monkeypatch):
    if backend == "hnsw":
        pytest.importorskip("faiss")
    params = {"min_rows": 10, "pca_dim": 4} if backend == "hnsw" else None
    store = _store(tmp_path / "m.lbug", [_walk(f"h{k}", 40, k) for k in range(3)])
    r = Relocator(backend=backend, backend_params=params).fit(store)
    r.add(_walk("h1", 30, 9))  # a replaced model leaves dead rows: saved compacted
    path = r.save(tmp_path / "index.npz")
    assert os.stat(path).st_mode & 0o777 == 0o666 & ~_umask()
    if backend == "hnsw":  # the graph comes back from the file, not rebuilt
        monkeypatch.setattr(type(r._backend), "rebuild", lambda *a: pytest.fail("rebuilt"))
    back = Relocator.load(path)
    monkeypatch.undo()
    assert back.backend == backend and back.backend_params == params
    assert back.store_revision_ == store.revision() and back.n_states_ == r.n_states_
    queries = np.random.default_rng(5).normal(size=(20, 8))
    for q in queries:
        assert back.nearest(q, 3) == r.nearest(q, 3)
    back.remove("h0")
    back.add(_walk("h3", 5, 3))  # a reopened index keeps learning
    assert back.model_ids_ == ["h2", "h1", "h3"] and back.n_states_ == 40 + 30 + 5


def test_open_reuses_a_current_index_and_refits_a_stale_one(tmp_path, monkeypatch):
    store = _store(tmp_path / "m.lbug", [_walk("a", 6, 0)])
    fits = []
    real_fit = Relocator.fit
    monkeypatch.setattr(Relocator, "fit", lambda self, *a, **k: (fits.append(1),
                                                                 real_fit(self, *a, **k))[1])
    r = Relocator.open(store)
    assert fits == [1] and store.index_path().is_file() and r.n_states_ == 6
    again = Relocator.open(store, threshold=0.1)
    assert fits == [1] and again.threshold == 0.1 and again.n_states_ == 6
    store.save(_walk("b", 4, 1))
    assert Relocator.open(store).n_states_ == 10 and fits == [1, 1]
    pytest.importorskip("faiss")
    assert Relocator.open(store, backend="hnsw", backend_params={"min_rows": 99}).n_states_ == 10
    assert fits == [1, 1, 1]  # another backend: refitted
    assert Relocator.open(store, backend="hnsw", backend_params={"min_rows": 98}).n_states_ == 10
    assert fits == [1, 1, 1, 1]  # other backend parameters: refitted
    store.index_path().write_bytes(b"PK\3\4 not really")  # damaged: refitted, not trusted
    assert Relocator.open(store).n_states_ == 10 and len(fits) == 5
    assert Relocator.load(store.index_path()).n_states_ == 10


def test_open_on_a_directory_keeps_the_index_hidden_inside_it(tmp_path):
    store = _store(tmp_path / "mem", [_walk("a", 6, 0)])
    Relocator.open(store)
    assert store.index_path() == tmp_path / "mem" / ".relocator.npz"
    assert store.ids() == ["a"] and store.check() == (["a"], [])


def test_an_index_that_cannot_be_written_is_a_warning(tmp_path):
    store = _store(tmp_path / "m.lbug", [_walk("a", 6, 0)])
    (tmp_path / "file").write_text("")
    with pytest.warns(UserWarning, match="relocator index not saved"):
        r = Relocator.open(store, path=tmp_path / "file" / "i.npz")
    assert r.n_states_ == 6


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _npz(**arrays) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


@pytest.mark.parametrize("content", [
    b"",
    b"not a zip at all",
    _npz(x=np.zeros(3)),
    _npz(meta=np.frombuffer(b'{"format": "other"}', np.uint8)),
    _npz(meta=np.frombuffer(b"\xff\xfe", np.uint8)),
    _npz(meta=np.array([{"format": "kgnav-relocator"}], dtype=object)),  # a pickle: refused
])
def test_a_file_that_is_not_an_index_is_one_line(tmp_path, content):
    path = tmp_path / "i.npz"
    path.write_bytes(content)
    with pytest.raises(KgnavError) as err:
        Relocator.load(path)
    assert str(path) in str(err.value) and "\n" not in str(err.value)


def test_an_index_with_inconsistent_arrays_is_refused(tmp_path):
    r = Relocator().fit([_walk("a", 4, 0)])
    good = r.save(tmp_path / "i.npz")
    with zipfile.ZipFile(good) as z:
        parts = {n[:-4]: np.load(z.open(n)) for n in z.namelist()}
    parts["owner_model"] = np.array([0, 0, 0, 5], np.int32)  # a row of a model not listed
    (tmp_path / "bad.npz").write_bytes(_npz(**parts))
    with pytest.raises(KgnavError, match="inconsistent"):
        Relocator.load(tmp_path / "bad.npz")
    with pytest.raises(KgnavError, match="no such"):
        Relocator.load(tmp_path / "missing.npz")


def test_reading_keeps_one_connection_and_refuses_writes(tmp_path, monkeypatch):
    store = _store(tmp_path / "m.lbug", [_walk("a", 3, 0), _walk("b", 2, 1)])
    opened = []
    real_open = graphdb._open
    monkeypatch.setattr(graphdb, "_open", lambda *a, **k: (opened.append(1),
                                                           real_open(*a, **k))[1])
    with store.reading():
        assert store.ids() == ["a", "b"] and store.load("b").n_states == 2
        with store.reading():  # nested: the same connection
            assert store.state_count() == 5
        with pytest.raises(StoreError, match="cannot write inside a reading"):
            store.save(_walk("c", 1, 2))
    assert opened == [1] and store.ids() == ["a", "b"]
    with ModelStore(tmp_path / "dir").reading() as d:  # a directory: nothing to keep open
        assert d.ids() == []


@pytest.mark.parametrize("where", ["dir", "m.lbug"])
def test_store_index_fits_once_then_finds_the_index_current(tmp_path, cli, where):
    import json

    store = _store(tmp_path / where, [_walk("a", 6, 0), _walk("b", 3, 1)])
    code, out, _ = cli("store", "index", store.root, "--json")
    first = json.loads(out)
    assert code == 0 and first["fitted"] and first["states"] == 9 and first["models"] == 2
    assert Relocator.load(store.index_path()).n_states_ == 9
    code, out, _ = cli("store", "index", store.root)
    assert code == 0 and "saved index was current" in out
    store.save(_walk("c", 2, 2))
    code, out, _ = cli("store", "index", store.root, "--json")
    assert json.loads(out)["fitted"] and json.loads(out)["states"] == 11
    code, out, err = cli("store", "index", tmp_path / "none.lbug")
    assert code == 1 and "no such store" in err and len(err.strip().splitlines()) == 1
    code, _, err = cli("store", "index", store.root, "--backend", "annoy")
    assert code == 2 and "annoy" in err
