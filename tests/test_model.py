import math

import numpy as np
import pytest

from kgnav import (
    AbstractModel,
    Detection,
    FeatureDimError,
    UnknownClassError,
    UnknownStateError,
)
from kgnav.common import se2


def test_tiny_structure(tiny):
    assert tiny.n_states == 3
    assert tiny.n_objects == 2
    assert tiny.n_transitions == 2
    chair = next(tiny.object_info(o) for o in tiny.objects() if tiny.object_info(o).cls == "chair")
    assert chair.n_views == 3 and chair.n_obs == 3


def test_duplicate_state_returns_existing_id(tiny):
    f = tiny.features("s1")
    again = tiny.add_state(f, (0.25 + 0.01, 0.0, 0.01), [Detection("bed", (5.0, 5.0, 0.5))])
    assert again == "s1"
    assert tiny.n_states == 3
    assert "bed" not in {tiny.object_info(o).cls for o in tiny.objects()}


def test_same_pose_other_features_is_a_new_state(tiny):
    new = tiny.add_state(np.array([0, 0, 0, 1.0]), (0.25, 0.0, 0.0))
    assert new == "s3"


def test_same_features_far_away_is_a_new_state(tiny):
    assert tiny.add_state(tiny.features("s0"), (3.0, 0.0, 0.0)) == "s3"


def test_object_position_is_mean_of_observations():
    m = AbstractModel(feature_dim=2)
    s0 = m.add_state(np.array([1.0, 0]), (0, 0, 0), [Detection("table", (1.0, 1.0, 0.5))])
    m.add_state(np.array([0, 1.0]), (1, 0, 0), [Detection("table", (1.3, 0.7, 0.8))])
    (o,) = list(m.objects())
    info = m.object_info(o)
    assert info.position == pytest.approx((1.15, 0.85, 0.65))
    assert info.n_views == 2 and info.n_obs == 2
    assert s0 == "s0"


def test_detections_beyond_radius_are_separate_objects():
    m = AbstractModel(feature_dim=2, object_radius=0.5)
    m.add_state(np.array([1.0, 0]), (0, 0, 0), [Detection("table", (1.0, 1.0, 0.5))])
    m.add_state(np.array([0, 1.0]), (1, 0, 0), [Detection("table", (1.6, 1.0, 0.5))])
    m.add_state(np.array([1.0, 1.0]), (2, 0, 0), [Detection("chair", (1.0, 1.0, 0.5))])
    assert m.n_objects == 3


def test_nearest_object_of_a_class_or_of_any():
    m = AbstractModel(feature_dim=2, object_radius=0.5)
    m.add_state(np.array([1.0, 0]), (0, 0, 0), [Detection("table", (1.0, 1.0, 0.5)),
                                                  Detection("chair", (3.0, 1.0, 0.5))])
    table, chair = (next(o for o in m.objects() if m.object_info(o).cls == c)
                    for c in ("table", "chair"))
    assert m.nearest_object("chair", 1.2, 1.0, 1.0) is None  # the table is near, not a chair
    assert m.nearest_object(None, 1.2, 1.0, 1.0) == table
    assert m.nearest_object(None, 2.5, 1.0, 1.0) == chair  # the nearer of the two
    assert m.nearest_object(None, 2.0, 5.0, 1.0) is None


def test_two_detections_of_one_object_in_one_state_count_one_view():
    m = AbstractModel(feature_dim=2)
    d = Detection("chair", (1.0, 1.0, 0.5))
    m.add_state(np.array([1.0, 0]), (0, 0, 0), [d, d])
    (o,) = list(m.objects())
    assert m.object_info(o).n_views == 1
    assert m.object_info(o).n_obs == 2


def test_wrong_feature_size_is_rejected():
    m = AbstractModel(feature_dim=8)
    with pytest.raises(FeatureDimError, match=r"shape \(7,\), expected \(8,\)"):
        m.add_state(np.zeros(7), (0, 0, 0))
    with pytest.raises(FeatureDimError):
        m.add_state(np.zeros((2, 4)), (0, 0, 0))


def test_non_finite_features_rejected():
    m = AbstractModel(feature_dim=2)
    with pytest.raises(ValueError, match="NaN"):
        m.add_state(np.array([np.nan, 1.0]), (0, 0, 0))


def test_unknown_class_rejected_and_model_unchanged():
    m = AbstractModel(feature_dim=2)
    with pytest.raises(UnknownClassError, match="'spaceship'"):
        m.add_state(np.ones(2), (0, 0, 0), [Detection("spaceship", (0, 0, 0))])
    assert m.n_states == 0


def test_custom_vocabulary():
    m = AbstractModel(feature_dim=2, classes=("door", "window"))
    m.add_state(np.ones(2), (0, 0, 0), [Detection("door", (1, 0, 2))])
    with pytest.raises(UnknownClassError):
        m.add_state(np.ones(2), (5, 0, 0), [Detection("chair", (1, 0, 2))])


def test_transition_counts_and_unknown_states(tiny):
    tiny.add_transition("s0", "move_forward", "s1")
    assert tiny.graph.edges["s0", "s1", "move_forward"]["count"] == 2
    assert tiny.n_transitions == 2
    with pytest.raises(UnknownStateError, match="'s9'"):
        tiny.add_transition("s0", "move_forward", "s9")
    with pytest.raises(UnknownStateError):
        tiny.add_transition("s0", "move_forward", "o0")  # an object is not a state


def test_features_are_float32_readonly_copies():
    m = AbstractModel(feature_dim=3)
    src = np.array([1.0, 2.0, 3.0])
    s = m.add_state(src, (0, 0, 0))
    src[0] = 99
    f = m.features(s)
    assert f.dtype == np.float32 and f[0] == 1.0
    with pytest.raises(ValueError):
        f[0] = 5


def test_transform_moves_states_objects_and_views(tiny):
    T = (1.0, -2.0, math.pi / 2)
    before = {s: tiny.pose(s) for s in tiny.states()}
    objs = {o: tiny.object_info(o).position for o in tiny.objects()}
    tiny.transform(T)
    for s, p in before.items():
        assert tiny.pose(s) == pytest.approx(se2.compose(T, p))
    for o, (x, y, z) in objs.items():
        nx_, ny_ = se2.apply_to_point(T, x, y)
        assert tiny.object_info(o).position == pytest.approx((nx_, ny_, z))
    # the indexes follow: a duplicate at the new pose is still found
    s1 = tiny.pose("s1")
    assert tiny.add_state(tiny.features("s1"), s1) == "s1"


def test_transform_accepts_matrix(tiny):
    a, b = tiny.copy(), tiny.copy()
    T = (0.5, 0.25, 0.3)
    c, s = math.cos(T[2]), math.sin(T[2])
    a.transform(T)
    b.transform(np.array([[c, -s, T[0]], [s, c, T[1]], [0, 0, 1]]))
    for st in a.states():
        assert a.pose(st) == pytest.approx(b.pose(st))


def test_copy_is_independent(tiny):
    c = tiny.copy()
    assert c == tiny
    c.add_state(np.array([0, 0, 0, 1.0]), (9, 9, 0))
    assert c != tiny and tiny.n_states == 3


def test_equality_sees_feature_bits(tiny):
    other = tiny.copy()
    f = other.features("s0").copy()
    f[0] = np.nextafter(f[0], np.float32(2))
    f.setflags(write=False)
    other.graph.nodes["s0"]["features"] = f
    assert other != tiny
