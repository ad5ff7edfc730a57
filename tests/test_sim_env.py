"""ObjectNavEnv (gymnasium API), metrics on hand-made cases, top-down pictures."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from kgnav.common.classes import class_id
from kgnav.sim import (
    Episode,
    ObjectInstance,
    ObjectNavEnv,
    Room,
    Scene,
    Texture,
    Wall,
    draw_topdown,
    dts,
    episode_metrics,
    mean_metrics,
    path_length,
    softspl,
    spl,
    success,
)


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("KGNAV_CACHE", str(tmp_path / "cache"))


def corridor() -> Scene:
    """A 10 m x 2 m room with a chair at its east end (footprint x in [9.0, 9.5])."""
    h = 0.05
    walls = (Wall(-h, -h, 10 + h, h), Wall(-h, 2 - h, 10 + h, 2 + h),
             Wall(-h, -h, h, 2 + h), Wall(10 - h, -h, 10 + h, 2 + h))
    room = Room(0, "hallway", 0.0, 0.0, 10.0, 2.0, (200, 200, 200), (100, 80, 60),
                Texture(), Texture(3, 0.2, 0.1))
    ch = ObjectInstance(1, "chair", 0, 9.0, 0.75, 9.5, 1.25, 0.0, 0.9, (200, 30, 30))
    return Scene("corridor", 0, 10.0, 2.0, (room,), (), walls, (ch,))


def corridor_env(start_x=5.0, theta=0.0, **kw) -> ObjectNavEnv:
    ep = Episode("c0", "corridor", (start_x, 1.0, theta), "chair", 0.0, 0.0)
    return ObjectNavEnv(scene=corridor(), episodes=[ep], **kw)


# --------------------------------------------------------------------------- metrics
def test_spl_by_hand():
    # l = 4, p = 5, success: 4 / max(5, 4) = 0.8
    assert spl(True, 4.0, 5.0) == pytest.approx(0.8)
    assert spl(False, 4.0, 5.0) == 0.0
    # a path shorter than the geodesic cannot score above 1: max(p, l) = l
    assert spl(True, 4.0, 3.0) == pytest.approx(1.0)


def test_softspl_by_hand():
    # d_T = 1, d_init = 4, l = 4, p = 5: (1 - 1/4) * 4/5 = 0.75 * 0.8 = 0.6
    assert softspl(1.0, 4.0, 4.0, 5.0) == pytest.approx(0.6)
    # ending farther than the start: progress clipped at 0
    assert softspl(6.0, 4.0, 4.0, 5.0) == 0.0
    # reaching the region (d_T = 0) with the optimal path scores 1
    assert softspl(0.0, 4.0, 4.0, 4.0) == pytest.approx(1.0)


def test_dts_by_hand():
    # L2 3.5 m from the closest goal, threshold 1 m: 2.5
    assert dts(3.5) == pytest.approx(2.5)
    assert dts(0.4) == 0.0
    assert success(True, 0.9) and not success(False, 0.9) and not success(True, 1.2)


def test_mean_metrics_by_hand():
    # three episodes: (success, l=4, p=5), (failure, stopped 2 m from the goal, l=2, p=8,
    # d_init=2, d_T=2, L2 2.0) and (success, l=3, p=3)
    e1 = episode_metrics(True, 4.0, 0.0, 0.5, 5.0)
    e2 = episode_metrics(True, 2.0, 2.0, 2.0, 8.0)
    e3 = episode_metrics(True, 3.0, 0.0, 1.0, 3.0)
    assert (e1.success, e2.success, e3.success) == (True, False, True)
    m = mean_metrics([e1, e2, e3])
    assert m["success"] == pytest.approx(2 / 3)
    assert m["spl"] == pytest.approx((0.8 + 0.0 + 1.0) / 3)
    # softspl: e1 (1-0/4)*0.8, e2 (1-2/2)*(2/8)=0, e3 1*1
    assert m["softspl"] == pytest.approx((0.8 + 0.0 + 1.0) / 3)
    # dts: max(0.5-1,0)=0, max(2-1,0)=1, max(1-1,0)=0
    assert m["dts"] == pytest.approx(1 / 3)
    assert m["episodes"] == 3
    assert path_length([(0, 0), (3, 0), (3, 4)]) == pytest.approx(7.0)


# --------------------------------------------------------------------------- env
def test_env_api_on_a_split():
    env = ObjectNavEnv(split="val", scene=0, width=160, height=120)
    obs, info = env.reset(seed=0)
    assert set(obs) == {"rgb", "depth", "semantic", "pose", "gps", "compass", "objectgoal"}
    assert obs["rgb"].shape == (120, 160, 3) and obs["rgb"].dtype == np.uint8
    assert obs["depth"].dtype == np.float32 and obs["semantic"].shape == (120, 160, 2)
    assert obs["pose"].dtype == np.float64 and obs["pose"].tolist() == [0.0, 0.0, 0.0]
    assert obs["gps"].shape == (2,) and obs["compass"].shape == (1,)
    assert int(obs["objectgoal"]) == class_id(info["goal_class"])
    assert env.observation_space.contains(obs)
    assert info["scene"] == "val_00" and info["episode"].scene == "val_00"
    assert math.isfinite(info["distance_to_goal"]) and info["distance_to_goal"] >= 1.0
    assert info["distance_to_goal"] == pytest.approx(info["episode"].geodesic_distance, abs=1e-3)
    obs, r, term, trunc, info = env.step(2)  # turn_left
    assert obs["pose"] == pytest.approx([0.0, 0.0, math.radians(30)])
    assert obs["compass"][0] == pytest.approx(math.radians(30))
    assert not term and not trunc and info["steps"] == 1
    # same seed: same episode and frames
    o1, _ = env.reset(seed=3)
    o2, _ = env.reset(seed=3)
    assert np.array_equal(o1["rgb"], o2["rgb"])
    nav = env.navigable_map()
    assert nav.grid.dtype == bool and nav.resolution == pytest.approx(0.05)
    assert env.render() is None or env.render().shape == (120, 160, 3)


def test_gymnasium_checker():
    from gymnasium.utils.env_checker import check_env

    env = corridor_env(width=32, height=24)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        check_env(env, skip_render_check=True)


def test_pose_is_relative_to_the_start():
    env = corridor_env(start_x=5.0, theta=math.pi)  # facing -x
    obs, _ = env.reset(seed=0)
    obs, *_ = env.step(1)
    # forward in the start frame is +x even though the agent moves towards world -x
    assert obs["pose"] == pytest.approx([0.25, 0.0, 0.0])
    obs, *_ = env.step(2)
    obs, _, _, _, info = env.step(1)
    assert obs["pose"][:2] == pytest.approx([0.25 + 0.25 * math.cos(math.pi / 6),
                                             0.25 * math.sin(math.pi / 6)])
    assert info["world_pose"][:2] == pytest.approx(env.start_frame_to_world(*obs["pose"][:2]))


def test_success_spl_and_distances():
    env = corridor_env(start_x=6.0)
    obs, info = env.reset(seed=0)
    # chair footprint starts at x = 9.0: L2 3.0 m, success region starts at x = 8.0
    assert info["l2_distance_to_goal"] == pytest.approx(3.0)
    assert info["distance_to_goal"] == pytest.approx(2.0, abs=0.06)
    l0 = info["shortest_path_length"]
    for _ in range(9):  # 2.25 m: x = 8.25, 0.75 m from the chair
        obs, r, term, trunc, info = env.step(1)
    assert info["distance_to_goal"] == 0.0 and not info["success"]
    obs, r, term, trunc, info = env.step(0)
    assert term and not trunc and info["success"]
    assert info["path_length"] == pytest.approx(2.25)
    assert info["spl"] == pytest.approx(l0 / 2.25)
    assert info["softspl"] == pytest.approx(l0 / 2.25)
    assert info["dts"] == 0.0 and r > 2.0
    with pytest.raises(RuntimeError):
        env.step(1)


def test_failure_and_truncation():
    env = corridor_env(start_x=2.0, max_steps=3)
    env.reset(seed=0)
    for _ in range(2):
        _, _, term, trunc, _ = env.step(1)
        assert not term and not trunc
    _, _, term, trunc, info = env.step(1)
    assert trunc and not term and not info["success"] and info["spl"] == 0.0
    # stop far from the goal: failure, DTS = L2 - 1
    env = corridor_env(start_x=2.0)
    env.reset(seed=0)
    _, _, term, _, info = env.step(0)
    assert term and not info["success"]
    assert info["dts"] == pytest.approx(7.0 - 1.0)


def test_collision_in_env():
    env = corridor_env(start_x=9.4, theta=math.pi / 2)  # facing the side wall at y = 1.95
    env.reset(seed=0)
    env.step(1)
    env.step(1)
    _, _, _, _, info = env.step(1)
    assert info["collided"] and info["world_pose"][1] < 1.95 - 0.17


def test_noise_options_reproducible():
    def run(seed):
        env = corridor_env(start_x=3.0, actuation_noise=1.0, odometry_noise=0.02)
        obs, _ = env.reset(seed=seed)
        poses = []
        for a in (1, 2, 1, 3, 1):
            obs, *_ = env.step(a)
            poses.append(obs["pose"].copy())
        return np.array(poses), env.world_pose

    a, wa = run(5)
    b, wb = run(5)
    c, _ = run(6)
    assert np.array_equal(a, b) and wa == wb
    assert not np.array_equal(a, c)


def test_topdown_png(tmp_path):
    env = ObjectNavEnv(split="val", scene=1, width=64, height=48)
    env.reset(seed=0)
    for a in (1, 1, 2, 1, 1):
        env.step(a)
    amap = np.zeros((60, 60), np.uint8)
    amap[20:40, 30:60] = 1
    p = tmp_path / "td.png"
    img = env.topdown(p, agent_map=amap, map_origin=(-1.5, -1.5))
    assert p.stat().st_size > 1000 and img.ndim == 3
    img2 = draw_topdown(env.scene, tmp_path / "plain.png")
    assert img2.shape == img.shape and not np.array_equal(img, img2)
