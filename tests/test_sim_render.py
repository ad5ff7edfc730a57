"""Renderer and dynamics of the embedded simulator, on hand-made and generated scenes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from kgnav.common.classes import class_id
from kgnav.sim import (
    MOVE_FORWARD,
    STOP,
    TURN_LEFT,
    TURN_RIGHT,
    Dynamics,
    NavMap,
    NoiseModel,
    ObjectInstance,
    Renderer,
    Room,
    Scene,
    Texture,
    Wall,
    generate_house,
)

T = 0.1  # wall thickness of the hand-made room


def square_room(size: float = 6.0, objects=()) -> Scene:
    """One square room [0, size]^2; wall faces at 0.05 and size - 0.05."""
    h = T / 2
    walls = (
        Wall(-h, -h, size + h, h),
        Wall(-h, size - h, size + h, size + h),
        Wall(-h, -h, h, size + h),
        Wall(size - h, -h, size + h, size + h),
    )
    room = Room(0, "living_room", 0.0, 0.0, size, size, (200, 180, 160), (120, 90, 60),
                Texture(1, 0.5, 0.1), Texture(3, 0.2, 0.1))
    return Scene("square", 0, size, size, (room,), (), walls, tuple(objects))


def chair(x0, y0, x1, y1, top=0.9, bottom=0.0, id_=1):
    return ObjectInstance(id_, "chair", 0, x0, y0, x1, y1, bottom, top, (30, 200, 40))


def test_depth_to_a_wall_is_exact():
    r = Renderer(square_room(), 160, 120)
    # facing +x, 2 m from the wall face at x = 5.95
    rgb, depth, sem = r.render(3.95, 3.0, 0.0)
    assert rgb.shape == (120, 160, 3) and rgb.dtype == np.uint8
    assert depth.shape == (120, 160) and depth.dtype == np.float32
    assert sem.shape == (120, 160, 2) and sem.dtype == np.int32
    mid = depth[60, :]
    # z-depth is constant along a flat wall facing the camera (not the ray length)
    np.testing.assert_allclose(mid, 2.0, atol=1e-4)
    np.testing.assert_allclose(depth[50:70, 80], 2.0, atol=1e-4)
    assert (sem == 0).all()


def test_floor_depth_and_clipping():
    r = Renderer(square_room(), 160, 120)
    _, depth, _ = r.render(3.0, 3.0, 0.0)
    # the bottom row sees the floor: z = camera height / tan(angle below the axis)
    y = (120 / 2 - 119.5) / r.focal
    assert depth[119, 80] == pytest.approx(0.88 / -y, abs=1e-4)
    assert depth.min() >= 0.5 and depth.max() <= 5.0
    # far wall (2.95 m) with an opening FOV: near-horizon pixels read the wall
    assert depth[60, 80] == pytest.approx(2.95, abs=1e-4)
    # standing 5.5 m away: farther than max_depth, clipped to 5.0 ("no return")
    _, depth, _ = r.render(0.3, 3.0, 0.0)
    assert depth[60, 80] == pytest.approx(5.0)


def test_rotation_convention():
    r = Renderer(square_room(), 64, 48)
    # theta = +pi/2 faces +y (counter-clockwise from +x): wall face at y = 5.95
    _, depth, _ = r.render(3.0, 4.95, math.pi / 2)
    assert depth[24, 32] == pytest.approx(1.0, abs=1e-4)
    _, depth, _ = r.render(3.0, 1.05, -math.pi / 2)
    assert depth[24, 32] == pytest.approx(1.0, abs=1e-4)


def test_semantic_ids_match_the_object_in_front():
    # a chair 0.55 m in front, a wall-mounted box (bottom 1.2 m) above the horizon, behind it
    objs = (chair(4.5, 2.75, 5.0, 3.25),
            ObjectInstance(2, "tv_monitor", 0, 5.8, 2.0, 5.95, 4.0, 1.2, 1.8, (10, 10, 10)))
    r = Renderer(square_room(objects=objs), 160, 120)
    rgb, depth, sem = r.render(3.95, 3.0, 0.0)
    assert tuple(sem[60, 80]) == (class_id("chair"), 1)
    assert depth[60, 80] == pytest.approx(0.55, abs=1e-4)
    # the tv above the chair: first row from the top of the image that hits it
    tv_rows = np.flatnonzero(sem[:, 80, 1] == 2)
    assert len(tv_rows) > 0
    d = depth[tv_rows, 80]
    assert d.min() == pytest.approx(1.85, abs=1e-3)  # its front face at x = 5.8
    # below the tv and above the chair we see the wall behind (class 0, depth 2.0)
    between = np.flatnonzero(sem[: tv_rows[0] + 30, 80, 1] == 0)
    assert len(between) > 0
    # rgb differs where the chair is
    assert not np.array_equal(rgb[60, 80], rgb[10, 80])


def test_low_object_does_not_hide_what_is_behind():
    # a low table (0.4 m) in front of a tall object: the tall one shows above the table
    objs = (chair(4.5, 2.5, 5.0, 3.5, top=0.4, id_=1),
            ObjectInstance(2, "wardrobe", 0, 5.4, 2.5, 5.9, 3.5, 0.0, 2.0, (90, 60, 20)))
    r = Renderer(square_room(objects=objs), 160, 120)
    _, depth, sem = r.render(3.95, 3.0, 0.0)
    col = sem[:, 80, 1]
    assert (col == 1).any() and (col == 2).any()
    rows1, rows2 = np.flatnonzero(col == 1), np.flatnonzero(col == 2)
    assert rows2.max() < rows1.min()  # wardrobe above the table in the image
    # looking down on the table's top: depth between its front (0.55) and back (1.05) faces
    top = depth[rows1.min(), 80]
    assert 0.55 < top <= 1.05 + 1e-4


def test_same_pose_same_frame_and_places_differ():
    s = generate_house(2001)
    nav = NavMap.from_scene(s)
    r = Renderer(s, 96, 72)
    cells = nav.navigable_cells()
    rng = np.random.default_rng(0)
    poses = [(*nav.to_world(*cells[rng.integers(len(cells))]), rng.uniform(-3, 3))
             for _ in range(6)]
    frames = [r.render(*p)[0] for p in poses]
    again = Renderer(generate_house(2001), 96, 72).render(*poses[0])
    assert np.array_equal(frames[0], again[0])
    for i in range(len(frames)):
        for j in range(i + 1, len(frames)):
            assert np.abs(frames[i].astype(int) - frames[j].astype(int)).mean() > 3
    # two houses look different from the "same" spot
    other = Renderer(generate_house(2002), 96, 72)
    x, y, t = poses[0]
    o = other.render(min(x, other.scene.width - 1), min(y, other.scene.depth - 1), t)[0]
    assert not np.array_equal(o, frames[0])


def test_resolution_is_configurable():
    r = Renderer(square_room(), 640, 480)
    rgb, depth, sem = r.render(3.95, 3.0, 0.0)
    assert rgb.shape == (480, 640, 3) and depth.shape == (480, 640)
    np.testing.assert_allclose(depth[240, :], 2.0, atol=1e-4)


# --------------------------------------------------------------------------- dynamics
def test_actions():
    d = Dynamics(NavMap.from_scene(square_room()))
    p = d.step((3.0, 3.0, 0.0), MOVE_FORWARD)
    assert p.pose == pytest.approx((3.25, 3.0, 0.0)) and not p.collided
    assert p.travelled == pytest.approx(0.25)
    p = d.step((3.0, 3.0, 0.0), TURN_LEFT)
    assert p.pose == pytest.approx((3.0, 3.0, math.radians(30)))
    p = d.step((3.0, 3.0, 0.0), TURN_RIGHT)
    assert p.pose == pytest.approx((3.0, 3.0, -math.radians(30)))
    assert d.step((3.0, 3.0, 0.0), STOP).pose == (3.0, 3.0, 0.0)
    # twelve left turns come back to the start heading
    pose = (3.0, 3.0, 0.0)
    for _ in range(12):
        pose = d.step(pose, TURN_LEFT).pose
    assert pose[2] == pytest.approx(0.0, abs=1e-9)
    # moving at 60 degrees
    p = d.step((3.0, 3.0, math.radians(60)), MOVE_FORWARD)
    assert p.pose[:2] == pytest.approx((3.125, 3.0 + 0.25 * math.sin(math.radians(60))))
    with pytest.raises(ValueError):
        d.step((3.0, 3.0, 0.0), 7)


def test_collision_stops_motion():
    nav = NavMap.from_scene(square_room())
    d = Dynamics(nav)
    # wall face at 5.95, radius 0.18: the centre may not pass ~5.77
    p = d.step((5.6, 3.0, 0.0), MOVE_FORWARD)
    assert p.collided
    assert 5.6 <= p.pose[0] < 5.85 and p.travelled < 0.25
    assert nav.is_navigable(p.pose[0], p.pose[1])
    again = d.step(p.pose, MOVE_FORWARD)
    assert again.collided and again.pose[0] <= p.pose[0] + 0.05


def test_noise_is_seeded():
    nav = NavMap.from_scene(square_room())
    noise = NoiseModel.scaled(1.0)

    def run(seed):
        d = Dynamics(nav, noise, np.random.default_rng(seed))
        pose, out = (3.0, 3.0, 0.0), []
        for a in (MOVE_FORWARD, TURN_LEFT, MOVE_FORWARD, TURN_RIGHT, MOVE_FORWARD):
            pose = d.step(pose, a).pose
            out.append(pose)
        return out

    assert run(1) == run(1)
    assert run(1) != run(2)
    assert run(1)[-1] != pytest.approx(Dynamics(nav).step((3.0, 3.0, 0.0), MOVE_FORWARD).pose)
    # off by default
    assert not NoiseModel().active
