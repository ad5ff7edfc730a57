import math

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from kgnav import AbstractModel, Detection, KgnavError, best_anchor, merge
from kgnav.common import se2
from tests.strategies import CLASSES, DIM, models

PROPS = settings(max_examples=60, suppress_health_check=[HealthCheck.function_scoped_fixture])


@PROPS
@given(models(), st.data())
def test_merge_with_itself_through_identity_anchor_changes_nothing(m, data):
    s = data.draw(st.sampled_from(sorted(m.states())))
    assert merge(m, m, anchor=(s, s)) == m


@PROPS
@given(models(model_id="src"), st.data(), st.tuples(st.floats(-5, 5), st.floats(-5, 5)))
def test_positions_land_where_the_transform_says(src, data, target_xy):
    # a target holding only a copy of one source state, at another pose
    s = data.draw(st.sampled_from(sorted(src.states())))
    theta = data.draw(st.floats(-math.pi, math.pi, exclude_max=True))
    target = AbstractModel(feature_dim=DIM, model_id="tgt", classes=CLASSES)
    t0 = target.add_state(src.features(s), (*target_xy, theta))
    objs = [src.object_info(o) for o in src.objects()]
    radius = src._tol("object_radius")
    for i, a in enumerate(objs):  # source objects far enough apart not to re-associate
        for b in objs[i + 1 :]:
            assume(
                a.cls != b.cls
                or math.dist(a.position[:2], b.position[:2]) > 2 * radius + 1e-6
            )
    merged = merge(target, src, anchor=(t0, s))
    T = se2.anchor_transform(target.pose(t0), src.pose(s))
    by_origin = {merged.graph.nodes[n]["origin"]: n for n in merged.graph.nodes}
    for o in objs:
        got = merged.object_info(by_origin[src.graph.nodes[o.id]["origin"]])
        x, y = se2.apply_to_point(T, o.position[0], o.position[1])
        assert got.position == pytest.approx((x, y, o.position[2]), abs=1e-6)
        assert got.n_views == o.n_views
    for st_ in src.states():
        n = by_origin.get(src.graph.nodes[st_]["origin"])
        if n is not None:  # not deduplicated onto the target's state
            px, py, pt = merged.pose(n)
            ex, ey, et = se2.compose(T, src.pose(st_))
            assert (px, py) == pytest.approx((ex, ey), abs=1e-6)
            assert se2.angle_diff(pt, et) < 1e-9
    assert merged.n_objects == len(objs)


@PROPS
@given(models(model_id="a"), models(model_id="b"), st.data())
def test_save_load_commutes_with_merge(tmp_path, a, b, data):
    anchor = (data.draw(st.sampled_from(sorted(a.states()))),
              data.draw(st.sampled_from(sorted(b.states()))))
    pa, pb, pm = tmp_path / "a.graphml", tmp_path / "b.graphml", tmp_path / "m.graphml"
    a.save(pa)
    b.save(pb)
    direct = merge(a, b, anchor=anchor)
    via_files = merge(AbstractModel.load(pa), AbstractModel.load(pb), anchor=anchor)
    assert via_files == direct
    direct.save(pm)
    assert AbstractModel.load(pm) == direct


@PROPS
@given(models(model_id="a"), models(model_id="b"), st.data())
def test_merge_does_not_modify_inputs(a, b, data):
    a0, b0 = a.copy(), b.copy()
    merge(a, b, anchor=(data.draw(st.sampled_from(sorted(a.states()))),
                        data.draw(st.sampled_from(sorted(b.states())))))
    assert a == a0 and b == b0


def _two_episodes():
    """Episode A and B of one room; B starts 1 m ahead of A, turned 90 degrees left."""
    f = np.eye(4, dtype=np.float32)
    a = AbstractModel(feature_dim=4, model_id="A")
    a0 = a.add_state(f[0], (0, 0, 0), [Detection("chair", (2.0, 0.0, 0.5))], episode=0)
    a1 = a.add_state(f[1], (1.0, 0.0, math.pi / 2), [Detection("sofa", (1.0, 2.0, 0.4))], step=1)
    a.add_transition(a0, "move_forward", a1)
    b = AbstractModel(feature_dim=4, model_id="B")
    # in B's frame (origin at A's (1, 0, 90°)) the sofa is 2 m ahead, a bed 1 m to the right
    b0 = b.add_state(f[1], (0, 0, 0), [Detection("sofa", (2.0, 0.0, 0.4))], episode=1)
    b1 = b.add_state(f[2], (0, 0, -math.pi / 2), [Detection("bed", (0.0, -1.0, 0.5))],
                     episode=1, step=1)
    b.add_transition(b0, "turn_right", b1)
    return a, b


def test_merge_two_episodes_of_one_room():
    a, b = _two_episodes()
    m = merge(a, b, anchor=("s1", "s0"))
    assert m.model_id == "A" and m.merged_from == ["B"]
    assert m.n_states == 3  # b0 coincides with a1
    assert m.episodes == [0, 1]
    classes = {m.object_info(o).cls: m.object_info(o) for o in m.objects()}
    assert set(classes) == {"chair", "sofa", "bed"}
    assert classes["sofa"].n_views == 1 and classes["sofa"].n_obs == 2  # same state, same sofa
    assert classes["bed"].position == pytest.approx((2.0, 0.0, 0.5))
    assert m.pose("s2") == pytest.approx((1.0, 0.0, 0.0))
    assert m.graph.has_edge("s1", "s2", "turn_right")
    assert m.graph.nodes["s2"]["origin"] == "B/s1"


def test_transition_counts_add_across_episodes():
    a, b = _two_episodes()
    b2 = b.copy()
    b2.model_id = "B2"  # the same walk recorded again in another episode
    for node in b2.graph.nodes:
        b2.graph.nodes[node]["origin"] = "B2/" + node
    m = merge(merge(a, b, anchor=("s1", "s0")), b2, anchor=("s1", "s0"))
    assert m.graph.edges["s1", "s2", "turn_right"]["count"] == 2
    assert m.merged_from == ["B", "B2"]
    # merging B again adds nothing: it is already in
    assert merge(m, b, anchor=("s1", "s0")) == m


def test_merge_rejects_incompatible_models():
    a, _ = _two_episodes()
    with pytest.raises(KgnavError, match="feature_dim 8"):
        merge(a, AbstractModel(feature_dim=8))
    other = AbstractModel(feature_dim=4, extractor="taskonomy")
    with pytest.raises(KgnavError, match="taskonomy"):
        merge(a, other)


def test_merge_extends_vocabulary():
    a = AbstractModel(feature_dim=2, classes=("chair",), model_id="a")
    a.add_state(np.ones(2), (0, 0, 0))
    b = AbstractModel(feature_dim=2, classes=("chair", "door"), model_id="b")
    b.add_state(np.array([1.0, 0]), (0, 0, 0), [Detection("door", (1, 0, 1))])
    assert merge(a, b).classes == ("chair", "door")


def test_best_anchor_finds_the_shared_view(world):
    a = world.explore(60, episode=0, seed=1)
    b = world.explore(60, episode=1, seed=2)
    ta, sb, dist = best_anchor(a, b)
    fa, fb = a.features(ta), b.features(sb)
    cos = float(fa @ fb / np.linalg.norm(fa) / np.linalg.norm(fb))
    assert dist == pytest.approx(1 - cos, abs=1e-5)
    _, fa_all = a.state_features()
    _, fb_all = b.state_features()
    na = fa_all / np.linalg.norm(fa_all, axis=1, keepdims=True)
    nb = fb_all / np.linalg.norm(fb_all, axis=1, keepdims=True)
    assert dist == pytest.approx(1 - (na @ nb.T).max(), abs=1e-5)


def test_merge_with_true_transform_reassociates_objects(world):
    """Two episodes of one world merged through the exact frame change share their objects."""
    a = world.explore(120, episode=0, seed=5)
    start_a = world.last_start
    b = world.explore(120, episode=1, seed=6)
    start_b = world.last_start
    T = se2.compose(se2.inverse(start_a), start_b)  # B's frame -> A's frame
    m = merge(a, b, transform=T)
    seen = {(o.cls, round(o.position[0], 1)) for o in map(m.object_info, m.objects())}
    assert m.n_objects <= len(world.objects)
    assert m.n_objects < a.n_objects + b.n_objects or not seen


def test_merge_keeps_the_target_s_relocation_threshold():
    f = np.eye(4, dtype=np.float32)
    a = AbstractModel(4, model_id="a", relocation_threshold=0.1)
    b = AbstractModel(4, model_id="b", relocation_threshold=0.2)
    c = AbstractModel(4, model_id="c")
    for m in (a, b, c):
        m.add_state(f[0], (0.0, 0.0, 0.0))
    assert merge(a, b).relocation_threshold == 0.1
    assert merge(c, b).relocation_threshold == 0.2  # the target records none: the source's
    assert merge(c, c).relocation_threshold is None
