"""Store-wide questions: the same answers from a directory of GraphML files (networkx) and from
a graph database (Cypher), on random stores and on constructed ones."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

pytest.importorskip("ladybug")

from kgnav import AbstractModel, Detection, ModelStore, query  # noqa: E402
from tests.strategies import CLASSES, models  # noqa: E402


def _both(tmp, ms):
    stores = (ModelStore(tmp / "dir"), ModelStore(tmp / "m.lbug"))
    for s in stores:
        for m in ms:
            s.save(m)
    return stores


def _answers(store, ms, within):
    out = {"inventory": query.class_inventories(store)}
    for cls in CLASSES:
        out["find", cls] = query.find_objects(store, cls)
        out["find2", cls] = query.find_objects(store, cls, min_views=2)
        for other in CLASSES:
            out["near", cls, other] = query.models_with_classes_near(store, cls, other, within)
    for m in ms:
        for o in m.objects():
            out["saw", m.model_id, o] = query.states_that_saw(store, m.model_id, o)
        for s in list(m.states())[:3]:
            for hops in (0, 1, 3):
                out["hops", m.model_id, s, hops] = query.objects_near_state(
                    store, m.model_id, s, hops)
    return out


@settings(max_examples=10, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(ms=st.lists(st.sampled_from(["ma", "mb", "mc"]), min_size=1, max_size=3, unique=True)
       .flatmap(lambda ids: st.tuples(*(models(model_id=i, max_states=6) for i in ids))),
       within=st.sampled_from([0.0, 0.5, 2.0, 50.0]))
def test_both_backends_answer_alike(tmp_path_factory, ms, within):
    directory, db = _both(tmp_path_factory.mktemp("s"), ms)
    assert _answers(directory, ms, within) == _answers(db, ms, within)


def _house(model_id: str, far: float) -> AbstractModel:
    """A corridor of three states: s0 sees a bed and a sofa ``far`` metres apart; s2 sees a
    chair twice as far as s1 does."""
    m = AbstractModel(feature_dim=2, model_id=model_id)
    box = (0, 0, 9, 9)
    s0 = m.add_state(np.array([1.0, 0.0]), (0.0, 0.0, 0.0), detections=[
        Detection("bed", (1.0, 0.0, 0.5), box, 1.0),
        Detection("sofa", (1.0 + far, 0.0, 0.4), box, 1.0 + far)])
    s1 = m.add_state(np.array([0.0, 1.0]), (1.0, 0.0, 0.0), detections=[
        Detection("chair", (5.0, 0.0, 0.4), box, 1.0)])
    s2 = m.add_state(np.array([1.0, 1.0]), (2.0, 0.0, 0.0), detections=[
        Detection("chair", (5.0, 0.0, 0.4), box, 3.0)])
    m.add_transition(s0, "move_forward", s1)
    m.add_transition(s1, "move_forward", s2)
    return m


@pytest.mark.parametrize("backend", ["dir", "m.lbug"])
def test_constructed_store(tmp_path, backend):
    store = ModelStore(tmp_path / backend)
    store.save(_house("near", 1.5))
    store.save(_house("far", 6.0))
    assert query.models_with_classes_near(store, "bed", "sofa", 2.0) == ["near"]
    assert query.models_with_classes_near(store, "bed", "sofa", 6.0) == ["far", "near"]
    assert query.models_with_classes_near(store, "bed", "bed", 100.0) == []  # one bed each
    assert query.class_inventories(store) == {"far": {"bed": 1, "chair": 1, "sofa": 1},
                                              "near": {"bed": 1, "chair": 1, "sofa": 1}}
    chairs = query.find_objects(store, "chair")
    assert [(c.model_id, c.n_views, c.n_obs) for c in chairs] == [("far", 2, 2), ("near", 2, 2)]
    assert query.find_objects(store, "bed", min_views=2) == []
    chair = chairs[1].id
    assert query.states_that_saw(store, "near", chair) == [("s1", 1.0), ("s2", 3.0)]
    assert query.states_that_saw(store, "nowhere", chair) == []
    objs = {c: query.find_objects(store, c)[0].id for c in ("bed", "sofa", "chair")}
    assert query.objects_near_state(store, "near", "s0", 0) == sorted([objs["bed"], objs["sofa"]])
    assert query.objects_near_state(store, "near", "s0", 1) == sorted(objs.values())
    assert query.objects_near_state(store, "near", "s2", 5) == [objs["chair"]]  # forward only
    with pytest.raises(ValueError, match="hops"):
        query.objects_near_state(store, "near", "s0", -1)
