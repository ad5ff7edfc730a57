"""SE(2) poses and transforms as plain ``(x, y, theta)`` triples.

A pose ``p = (x, y, theta)`` is read as the transform taking points from the pose's local frame to
the frame it is expressed in. ``compose(a, b)`` is ``a ∘ b`` (apply ``b`` first), so the transform
that maps episode coordinates into a stored model's frame, given a state ``s`` of the episode that
matches a state ``s*`` of the model, is ``compose(pose(s*), inverse(pose(s)))`` (DESIGN.md §4).

>>> T = compose((1.0, 0.0, 0.0), inverse((0.0, 0.0, 0.0)))
>>> apply_to_pose(T, (0.0, 0.0, 0.0))
(1.0, 0.0, 0.0)
"""

from __future__ import annotations

import math

import numpy as np

Pose = tuple[float, float, float]

IDENTITY: Pose = (0.0, 0.0, 0.0)


def wrap_angle(theta: float) -> float:
    """Angle in [-pi, pi)."""
    return (theta + math.pi) % (2.0 * math.pi) - math.pi


def as_pose(p) -> Pose:
    """Accept ``(x, y, theta)`` or a 3×3 homogeneous matrix; return a float triple."""
    a = np.asarray(p, dtype=float)
    if a.shape == (3, 3):
        return (float(a[0, 2]), float(a[1, 2]), float(math.atan2(a[1, 0], a[0, 0])))
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ValueError(f"an SE(2) pose is (x, y, theta) or a 3x3 matrix, got shape {a.shape}")
    return (float(a[0]), float(a[1]), float(a[2]))


def compose(a: Pose, b: Pose) -> Pose:
    """``a ∘ b``: the pose ``b`` expressed in the frame where ``a`` lives."""
    ax, ay, at = a
    bx, by, bt = b
    c, s = math.cos(at), math.sin(at)
    return (ax + c * bx - s * by, ay + s * bx + c * by, wrap_angle(at + bt))


def inverse(a: Pose) -> Pose:
    """The inverse transform: ``compose(a, inverse(a)) == IDENTITY``."""
    ax, ay, at = a
    c, s = math.cos(at), math.sin(at)
    return (-(c * ax + s * ay), -(-s * ax + c * ay), wrap_angle(-at))


def apply_to_point(T: Pose, x: float, y: float) -> tuple[float, float]:
    """Map a point through ``T``."""
    tx, ty, tt = T
    c, s = math.cos(tt), math.sin(tt)
    return (tx + c * x - s * y, ty + s * x + c * y)


def apply_to_points(T: Pose, xy: np.ndarray) -> np.ndarray:
    """Map an ``(N, 2)`` array of points through ``T``."""
    tx, ty, tt = T
    c, s = math.cos(tt), math.sin(tt)
    R = np.array([[c, -s], [s, c]])
    return np.asarray(xy, dtype=float) @ R.T + np.array([tx, ty])


def fit_points(src, dst) -> Pose:
    """The transform ``T`` minimising the squared distances from ``apply_to_points(T, src)``
    to ``dst`` (two ``(N, 2)`` arrays of paired points, N >= 1; 2-D Kabsch, no scale).

    >>> fit_points(np.array([[0.0, 0.0], [1.0, 0.0]]), np.array([[1.0, 1.0], [1.0, 2.0]]))
    (1.0, 1.0, 1.5707963267948966)
    """
    src, dst = np.asarray(src, dtype=float), np.asarray(dst, dtype=float)
    cs, cd = src.mean(axis=0), dst.mean(axis=0)
    a, b = src - cs, dst - cd
    theta = math.atan2(float((a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]).sum()),
                       float((a * b).sum()))
    c, s = math.cos(theta), math.sin(theta)
    t = cd - np.array([c * cs[0] - s * cs[1], s * cs[0] + c * cs[1]])
    return float(t[0]), float(t[1]), theta


def apply_to_pose(T: Pose, p: Pose) -> Pose:
    """Map a pose through ``T`` (same as ``compose(T, p)``)."""
    return compose(T, p)


def anchor_transform(target_pose: Pose, source_pose: Pose) -> Pose:
    """``T = target ∘ source⁻¹``: the transform taking ``source_pose`` onto ``target_pose``."""
    return compose(target_pose, inverse(source_pose))


def angle_diff(a: float, b: float) -> float:
    """Absolute angular distance in [0, pi]."""
    return abs(wrap_angle(a - b))
