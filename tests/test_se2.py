import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from kgnav.common import se2

coord = st.floats(-50, 50, allow_nan=False)
angle = st.floats(-math.pi, math.pi, allow_nan=False)
poses = st.tuples(coord, coord, angle)


@given(poses)
def test_inverse_composes_to_identity(p):
    e = se2.compose(p, se2.inverse(p))
    assert e[0] == pytest.approx(0, abs=1e-9) and e[1] == pytest.approx(0, abs=1e-9)
    assert se2.angle_diff(e[2], 0.0) < 1e-9


@given(poses, poses)
def test_anchor_transform_maps_source_pose_onto_target(target, source):
    T = se2.anchor_transform(target, source)
    mapped = se2.apply_to_pose(T, source)
    assert mapped[0] == pytest.approx(target[0], abs=1e-7)
    assert mapped[1] == pytest.approx(target[1], abs=1e-7)
    assert se2.angle_diff(mapped[2], target[2]) < 1e-9


@given(poses, st.lists(st.tuples(coord, coord), min_size=1, max_size=5))
def test_points_batch_matches_single(T, pts):
    batch = se2.apply_to_points(T, np.array(pts))
    for (x, y), row in zip(pts, batch, strict=True):
        assert row == pytest.approx(se2.apply_to_point(T, x, y), abs=1e-9)


def test_compose_known_value():
    # turn 90 degrees left, then step 1 m forward: end at (0, 1) facing +y
    assert se2.compose((0, 0, math.pi / 2), (1, 0, 0)) == pytest.approx((0, 1, math.pi / 2))


def test_bad_pose_shape():
    with pytest.raises(ValueError, match="shape"):
        se2.as_pose([1, 2])
