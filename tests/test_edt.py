"""The exact distance transform is exact and the same on every run (kgnav.common.edt)."""

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage

from kgnav.common.edt import distance_to_zero


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), h=st.integers(1, 90), w=st.integers(1, 90),
       density=st.floats(0.001, 0.5))
def test_equals_the_exact_transform(seed, h, w, density):
    free = np.random.default_rng(seed).random((h, w)) > density
    free[0, 0] = False  # at least one zero cell, or every distance is undefined
    want = ndimage.distance_transform_edt(free).astype(np.float32)
    assert np.array_equal(distance_to_zero(free), want)


@pytest.mark.parametrize("threads", [1, 2])
def test_the_same_bits_whatever_the_threads(threads):
    # OpenCV's own result differs in the last bit between calls here (about 5 % of cells)
    free = np.random.default_rng(0).random((600, 700)) > 0.02
    want = ndimage.distance_transform_edt(free).astype(np.float32)
    old = cv2.getNumThreads()
    try:
        cv2.setNumThreads(threads)
        for _ in range(4):
            assert np.array_equal(distance_to_zero(free), want)
    finally:
        cv2.setNumThreads(old)
