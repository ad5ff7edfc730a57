"""Hypothesis strategies for Abstract Models built through the public API."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import strategies as st

from kgnav import ACTIONS, AbstractModel, Detection
from kgnav.memory.geometry import ScanGeometry

CLASSES = ("chair", "sofa", "table", "bed")
DIM = 6

coord = st.floats(-20, 20, allow_nan=False, allow_infinity=False)
angle = st.floats(-math.pi, math.pi, allow_nan=False, exclude_max=True)
feature = st.lists(
    st.floats(-1, 1, allow_nan=False, width=32), min_size=DIM, max_size=DIM
).filter(lambda v: any(abs(x) > 1e-3 for x in v))
detection = st.builds(
    Detection,
    st.sampled_from(CLASSES),
    st.tuples(coord, coord, st.floats(0, 2, allow_nan=False)),
    st.tuples(*[st.floats(0, 160, allow_nan=False)] * 4),
    st.floats(0, 5, allow_nan=False),
    st.integers(0, 5000),
    st.floats(0, 1.0, allow_nan=False),
    st.floats(0, 1, allow_nan=False),
)
state = st.tuples(feature, st.tuples(coord, coord, angle), st.lists(detection, max_size=3))
#: A small scan geometry for range profiles in property tests.
SCAN = ScanGeometry(79.0, 8, 5.0)
profile = st.lists(st.floats(0.5, 5.0, allow_nan=False, width=16), min_size=SCAN.bins,
                   max_size=SCAN.bins)


@st.composite
def models(draw, model_id: str | None = None, min_states: int = 1, max_states: int = 8,
           scan: bool = False):
    """Models built through the public API; ``scan``: states carry range profiles."""
    m = AbstractModel(
        feature_dim=DIM,
        model_id=model_id or draw(st.sampled_from(["ma", "mb", "mc"])),
        classes=CLASSES,
        scan=SCAN if scan else None,
    )
    ids = []
    for f, pose, dets in draw(st.lists(state, min_size=min_states, max_size=max_states)):
        ranges = draw(profile) if scan else None
        episode = draw(st.integers(0, 2))
        ids.append(m.add_state(np.array(f, dtype=np.float32), pose, dets, ranges=ranges,
                               episode=episode))
    n = len(ids)
    for i, a, j in draw(
        st.lists(
            st.tuples(st.integers(0, n - 1), st.sampled_from(ACTIONS), st.integers(0, n - 1)),
            max_size=10,
        )
    ):
        m.add_transition(ids[i], a, ids[j])
    # loop closures (schema 4): recorded on some models, kept or rejected
    m.add_loop_closures({"state": f"{m.model_id}/{ids[i]}", "episode": e, "kept": k}
                        for i, e, k in draw(st.lists(st.tuples(st.integers(0, n - 1),
                                                               st.integers(0, 2), st.booleans()),
                                                     max_size=3)))
    # raw odometry and closure links (schema 5)
    if draw(st.booleans()):
        m.add_odometry({f"{m.model_id}/{s}": [k, *draw(st.tuples(coord, coord, angle)),
                                               0.25 * k, 0.1 * k]
                        for k, s in enumerate(ids)})
        m.add_loop_closures({"state": f"{m.model_id}/{ids[i]}", "episode": 3, "kept": True,
                             "to": f"{m.model_id}/{ids[j]}", "rel": rel}
                            for i, j, rel in draw(st.lists(st.tuples(
                                st.integers(0, n - 1), st.integers(0, n - 1),
                                st.tuples(coord, coord, angle)), max_size=2)))
    return m


def walk_model(mid: str, n: int, seed: int, dim: int = 8) -> AbstractModel:
    """A straight walk of ``n`` states 0.5 m apart with seeded random features (relocator
    tests: every state its own row)."""
    rng = np.random.default_rng(seed)
    m = AbstractModel(feature_dim=dim, model_id=mid)
    for i in range(n):
        m.add_state(rng.normal(size=dim), (0.5 * i, 0.0, 0.0), step=i)
    return m
