import numpy as np
import pytest

from kgnav import AbstractModel, FeatureDimError, KgnavError, ModelStore, Relocator
from kgnav.memory.relocator import BACKENDS
from kgnav.memory.synthetic import SyntheticWorld, clustered_features


def _model(mid, feats, extractor="unspecified"):
    m = AbstractModel(feature_dim=feats.shape[1], model_id=mid, extractor=extractor)
    for i, f in enumerate(feats):
        m.add_state(f, (float(i), 0.0, 0.0), step=i)
    return m


def test_match_threshold_and_distance():
    a = _model("a", np.array([[1.0, 0, 0], [0, 1.0, 0]]))
    r = Relocator(threshold=0.3).fit([a])
    assert r.n_states_ == 2 and r.model_ids_ == ["a"] and r.feature_dim_ == 3
    m = r.match(np.array([2.0, 0.2, 0.0]))  # scale does not matter
    assert m.model_id == "a" and m.state_id == "s0"
    assert m.distance == pytest.approx(1 - 2 / np.sqrt(4.04), abs=1e-6)
    model_id, state_id, dist = m  # unpacks as the tuple
    assert (model_id, state_id) == ("a", "s0")
    assert r.match(np.array([1.0, 1.0, 1.0])) is None  # 0.42 from both
    assert Relocator(threshold=0.5).fit([a]).match(np.array([1.0, 1.0, 1.0])) is not None


def test_empty_and_zero_queries():
    r = Relocator().fit([])
    assert r.match(np.ones(3)) is None and r.nearest(np.ones(3)) == []
    a = _model("a", np.eye(3))
    r.add(a)
    assert r.match(np.zeros(3)) is None


def test_wrong_query_size():
    r = Relocator().fit([_model("a", np.eye(3))])
    with pytest.raises(FeatureDimError, match=r"expected \(3,\)"):
        r.match(np.ones(4))


def test_models_must_agree():
    r = Relocator().fit([_model("a", np.eye(3))])
    with pytest.raises(FeatureDimError):
        r.add(_model("b", np.eye(4)))
    with pytest.raises(KgnavError, match="taskonomy"):
        r.add(_model("c", np.eye(3), extractor="taskonomy"))


def test_add_replaces_a_model_and_remove_forgets_it():
    r = Relocator().fit([_model("a", np.eye(4)[:2]), _model("b", np.eye(4)[2:3])])
    assert r.match(np.eye(4)[3]) is None
    r.add(_model("b", np.eye(4)[2:4]))  # b grew: its old rows are replaced
    assert r.n_states_ == 4
    assert r.match(np.eye(4)[3]).model_id == "b"
    r.remove("a")
    assert r.match(np.eye(4)[0]) is None and r.n_states_ == 2
    for _ in range(10):  # many replacements trigger compaction; results stay right
        r.add(_model("b", np.eye(4)[2:4]))
    assert r.n_states_ == 2 and r.match(np.eye(4)[2]) == ("b", "s0", pytest.approx(0, abs=1e-6))


def test_fit_from_store_skips_bad_files(tmp_path):
    store = ModelStore(tmp_path)
    store.save(_model("a", np.eye(3)))
    (tmp_path / "bad.graphml").write_text("garbage")
    r = Relocator().fit(store)
    assert r.model_ids_ == ["a"]
    assert len(r.problems_) == 1 and r.problems_[0].path.endswith("bad.graphml")


def test_unknown_backend():
    with pytest.raises(ValueError, match="unknown relocator backend 'annoy'"):
        Relocator(backend="annoy")


def test_relocates_in_the_right_world():
    """One store, several worlds: a new episode matches a model of its own world."""
    worlds = [SyntheticWorld(seed=s, feature_dim=64) for s in range(4)]
    models = [w.explore(150, episode=0, seed=s, model_id=f"world{s}") for s, w in enumerate(worlds)]
    r = Relocator(threshold=0.3).fit(models)
    for s, w in enumerate(worlds):
        probe = w.explore(150, episode=1, seed=100 + s)
        ids, feats = probe.state_features()
        matches = [m for m in (r.match(f) for f in feats) if m is not None]
        assert matches, f"world {s} never relocated"
        assert {m.model_id for m in matches} == {f"world{s}"}


@pytest.mark.skipif("hnsw" not in BACKENDS, reason="faiss not installed")
def test_hnsw_agrees_with_exact():
    pytest.importorskip("faiss")
    feats, _, worlds = clustered_features(3000, feature_dim=128, n_worlds=6, seed=1)
    models = [_model(f"m{i}", feats[i::6]) for i in range(6)]
    exact = Relocator().fit(models)
    approx = Relocator(backend="hnsw", backend_params={"pca_dim": 32, "min_rows": 100}).fit(models)
    assert approx._backend._index is not None  # the graph index is really in use
    queries, _, _ = clustered_features(200, feature_dim=128, n_worlds=6, seed=1)
    queries = queries + np.random.default_rng(0).normal(0, 0.01, queries.shape).astype(np.float32)
    agree = sum(exact.nearest(q)[0][:2] == approx.nearest(q)[0][:2] for q in queries)
    assert agree >= 0.97 * len(queries)
    # incremental adds and replacements keep working
    fresh, _, _ = clustered_features(50, feature_dim=128, n_worlds=6, seed=7)
    approx.add(_model("m0", fresh))
    assert approx.n_states_ == exact.n_states_ - len(feats[0::6]) + 50
    hit = approx.nearest(fresh[10])[0]
    assert hit[:2] == ("m0", "s10") and hit.distance == pytest.approx(0, abs=1e-5)
    assert approx.nearest(feats[0])[0].model_id != "m0"  # the old m0 rows are gone
