"""The MiniWorld adapter (environment ``miniworld``, ``kgnav[miniworld]``).

MiniWorld renders with OpenGL through pyglet, headless on EGL (Debian: libegl1 libegl-mesa0
libgl1-mesa-dri libglu1-mesa). Without it these tests skip, except where
``KGNAV_REQUIRE_MINIWORLD=1`` (CI installs both and sets it): there a missing MiniWorld is a
failure.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest

from kgnav.agent.camera import Camera
from kgnav.benchmark.runner import EvalConfig, run_eval
from kgnav.envs import EnvOptions, check_env, check_observation, make_env
from kgnav.errors import KgnavError

mwh = pytest.importorskip("kgnav.envs.miniworld_house")


def _missing(reason: str):
    if os.environ.get("KGNAV_REQUIRE_MINIWORLD") == "1":
        pytest.fail(f"{reason}, but KGNAV_REQUIRE_MINIWORLD=1 is set")
    pytest.skip(reason)


@pytest.fixture(scope="module")
def suite():
    try:
        return make_env("miniworld", EnvOptions(split="tiny"))
    except KgnavError as e:
        _missing(f"MiniWorld is not installed ({e})")


@pytest.fixture(scope="module")
def env(suite):
    e = suite.make(0, 3)
    try:
        e.reset(seed=0, options={"episode": 0})
    except KgnavError as exc:
        _missing(f"MiniWorld cannot render here ({exc})")
    return e


def _face(env, x, y, theta):
    """Put the agent at a world pose (through the motion rule's own state) and observe."""
    env._world = (x, y, theta)
    return env._observe(np.zeros(3))


# ---------------------------------------------------------------------- the protocol
def test_adapter_satisfies_the_protocol(env):
    spec = check_env(env, "miniworld")
    assert spec.semantic and spec.classes == mwh.CLASSES
    space = spec.observation_space()
    obs, _ = env.reset(seed=3, options={"episode": 1})
    assert obs["pose"].tolist() == [0.0, 0.0, 0.0]
    rng = np.random.default_rng(0)
    for a in rng.integers(1, 4, 20):
        check_observation(obs, spec)
        assert space.contains(obs)
        obs, _r, term, trunc, info = env.step(int(a))
        assert not term and not trunc
    obs, _r, term, _trunc, info = env.step(spec.actions.index("stop"))
    assert term and isinstance(info["success"], bool)
    for key in ("spl", "softspl", "dts", "path_length", "shortest_path_length", "episode_id"):
        assert info[key] is not None
    for hook in ("episode_start", "scene_objects", "l2_distance_to_goal", "navigable_map",
                 "start_frame_to_world", "topdown"):
        assert callable(getattr(env, hook)), hook
    assert env.scene_name == "mw0000" and len(env.world_pose) == 3


def test_motion_is_exactly_a_quarter_metre_and_thirty_degrees(env):
    """MiniWorld's randomised step and turn sizes are not used: every forward move on free
    floor is 0.25 m, every turn 30°, in the world and in the pose observation."""
    obs, _ = env.reset(seed=0, options={"episode": 0})
    assert obs["pose"].tolist() == [0.0, 0.0, 0.0]
    nav = env.navigable_map()
    free = np.argwhere(nav.grid)
    rng = np.random.default_rng(1)
    forward = 0
    for i, j in free[rng.choice(len(free), 10, replace=False)]:
        env.reset(seed=0, options={"episode": 0})
        x, y = nav.to_world(int(i), int(j))
        env._world = (x, y, float(rng.uniform(-math.pi, math.pi)))
        env._start = env._world
        env.odometry.reset()
        for a in (2, 1, 3, 3, 1, 2, 1):
            before, pose_before = env.world_pose, env.odometry.pose
            obs, *_ = env.step(a)
            after, pose = env.world_pose, obs["pose"]
            turn = math.remainder(after[2] - before[2], 2 * math.pi)
            obs_turn = math.remainder(pose[2] - pose_before[2], 2 * math.pi)
            if a == 1:
                ahead = [(before[0] + s * math.cos(before[2]), before[1] + s * math.sin(
                    before[2])) for s in np.linspace(0.025, 0.25, 10)]
                if all(nav.is_navigable(*p) for p in ahead):
                    assert math.dist(before[:2], after[:2]) == pytest.approx(0.25, abs=1e-9)
                    assert math.dist(pose_before[:2], pose[:2]) == pytest.approx(0.25, abs=1e-9)
                    forward += 1
                assert turn == obs_turn == 0.0
            else:
                sign = 1 if a == 2 else -1
                assert turn == pytest.approx(sign * math.radians(30), abs=1e-12)
                assert obs_turn == pytest.approx(sign * math.radians(30), abs=1e-12)
                assert before[:2] == after[:2]
    assert forward >= 10


def test_forward_stops_at_walls(env):
    env.reset(seed=0, options={"episode": 0})
    nav = env.navigable_map()
    room = env.house.rooms[0]
    # facing the west outer wall from 0.6 m: blocked after at most 0.25 m, never through it
    y = (room.y0 + room.y1) / 2
    env._world = (room.x0 + 0.6, y, math.pi)
    for _ in range(4):
        _obs, _r, _t, _tr, info = env.step(1)
    x, _y, _t = env.world_pose
    assert info["collided"] and x >= room.x0 + mwh.AGENT_RADIUS and nav.is_navigable(x, y)


# ---------------------------------------------------------------------- the frames
def _world_points(env, obs):
    cam = Camera.from_spec(env.env_spec.camera)
    fwd, left, up = cam.points(obs["depth"])
    x, y, t = env.world_pose
    c, s = math.cos(t), math.sin(t)
    return x + c * fwd - s * left, y + s * fwd + c * left, up


def _off_walls(house, wx, wy):
    """Distance (m) of world points from the nearest wall line."""
    d = np.full(wx.shape, np.inf)
    for r in house.rooms:
        for v, at in ((wx, r.x0), (wx, r.x1), (wy, r.y0), (wy, r.y1)):
            d = np.minimum(d, np.abs(v - at))
    return d


def test_semantic_labels_and_depth_match_the_objects(env):
    """Every labelled pixel back-projects onto its own object's box (footprint and height),
    and every unlabelled floor pixel lies on the floor: labels, depth and the declared camera
    agree per pixel, for every object of the house seen from 1.6 m."""
    env.reset(seed=0, options={"episode": 0})
    house, nav = env.house, env.navigable_map()
    checked = 0
    for o in house.objects:
        cx, cy = (o.x0 + o.x1) / 2, (o.y0 + o.y1) / 2
        views = [(cx - math.cos(a) * 1.6, cy - math.sin(a) * 1.6, a)
                 for a in np.arange(8) * math.pi / 4]
        r = house.rooms[o.room]  # from the object's own room: nothing between
        views = [v for v in views if nav.is_navigable(v[0], v[1])
                 and r.x0 < v[0] < r.x1 and r.y0 < v[1] < r.y1]
        if not views:
            continue
        obs = _face(env, *views[0])
        wx, wy, up = _world_points(env, obs)
        sem = obs["semantic"]
        mine = sem[..., 1] == o.id
        assert mine.sum() > 40, (o, views[0])
        assert (sem[..., 0][mine] == mwh.CLASSES.index(o.cls) + 1).all()
        # interior pixels (not at the label's edge, where depth may be the neighbour's)
        inner = mine & np.roll(mine, 1, 0) & np.roll(mine, -1, 0) & np.roll(mine, 1, 1) \
            & np.roll(mine, -1, 1)
        gap = np.hypot(np.maximum(np.maximum(o.x0 - wx, 0), wx - o.x1),
                       np.maximum(np.maximum(o.y0 - wy, 0), wy - o.y1))
        assert np.percentile(gap[inner], 99) < 0.03, o
        assert up[inner].min() > -0.03 and up[inner].max() < o.top + 0.03
        floor = (sem[..., 1] == 0) & (up < 0.3) & (_off_walls(house, wx, wy) > 0.05) \
            & (obs["depth"] < 4.99)
        assert floor.sum() > 100 and np.abs(up[floor]).max() < 0.03
        checked += 1
    assert checked >= len(house.objects) - 1


def test_rendered_walls_and_doors_are_where_the_floor_plan_has_them(env):
    env.reset(seed=0, options={"episode": 0})
    house = env.house
    cam_w = env.env_spec.camera.width
    for d in house.doors:
        a, b = house.rooms[d.a], house.rooms[d.b]
        mid = (d.lo + d.hi) / 2
        if d.axis == 1:  # the wall at x = d.at; look east through the door from 1 m west
            obs = _face(env, d.at - 1.0, mid, 0.0)
            far_side = b.x1 - d.at
        else:  # the wall at y = d.at; look north
            obs = _face(env, mid, d.at - 1.0, math.pi / 2)
            far_side = b.y1 - d.at
        centre = obs["depth"][:, cam_w // 2]
        assert centre.max() > min(1.0 + 0.5 * far_side, 4.9), d  # through the door
        # and 0.8 m beside the door the wall stands 1 m ahead
        beside = d.hi + 0.8 if d.hi + 0.8 < (a.y1 if d.axis == 1 else a.x1) - 0.3 else \
            d.lo - 0.8
        obs = _face(env, d.at - 1.0, beside, 0.0) if d.axis == 1 else \
            _face(env, beside, d.at - 1.0, math.pi / 2)
        wx, wy, up = _world_points(env, obs)
        wall = (obs["semantic"][..., 1] == 0) & (up > 0.3) & (up < 2.0)
        coord = wx if d.axis == 1 else wy
        assert np.abs(coord[:, cam_w // 2][wall[:, cam_w // 2]] - d.at).max() < 0.03


def test_frames_are_deterministic(suite, env):
    a = _face(env, *env.episode_start(0))
    other = suite.make(1, 1)
    other.reset(seed=0, options={"episode": 0})  # another house draws in between
    b = _face(env, *env.episode_start(0))
    assert np.array_equal(a["rgb"], b["rgb"]) and np.array_equal(a["depth"], b["depth"])
    assert np.array_equal(a["semantic"], b["semantic"])


def test_labels_are_rendered_only_when_asked_for(env):
    """An episode that declines labels gets none, and the same RGB and depth, bit for bit."""
    obs, _ = env.reset(seed=4, options={"episode": 1, "semantic": False})
    assert "semantic" not in obs and env.env_spec.semantic
    check_observation(obs, env.env_spec, semantic=False)
    start = env.world_pose
    plain = [obs] + [env.step(a)[0] for a in (1, 2, 1, 3)]
    poses = list(env.trajectory)
    env.reset(seed=4, options={"episode": 1})
    assert env.world_pose == start
    labelled = [_face(env, *p) for p in poses]
    for a, b in zip(plain, labelled, strict=True):
        assert "semantic" in b and "semantic" not in a
        assert np.array_equal(a["rgb"], b["rgb"]) and np.array_equal(a["depth"], b["depth"])
    rgb, depth, sem = env.render_at(*poses[-1], semantic=False)
    assert sem is None and np.array_equal(depth, labelled[-1]["depth"])


@pytest.mark.parametrize(("fmt", "pitch_sign"), [("RGB", -1), ("RGB", 1), ("RGBA", -1),
                                                 ("L", -1), ("LA", 1), ("BGRA", -1)])
def test_textures_load_as_pyglet_converts_them(env, fmt, pitch_sign):
    """The numpy conversion of MiniWorld's texture pixels gives pyglet's bytes (the upload's
    data), whatever the decoded format and row order."""
    import pyglet

    from kgnav.envs.miniworld_render import _rgba_rows

    w, h = 7, 5
    raw = np.random.default_rng(len(fmt)).integers(0, 256, w * h * len(fmt), np.uint8)
    img = pyglet.image.ImageData(w, h, fmt, raw.tobytes(), pitch=pitch_sign * w * len(fmt))
    want = np.frombuffer(img.get_data("RGBA", w * 4), np.uint8).reshape(h, w, 4)
    assert np.array_equal(_rgba_rows(img), want)


def test_mesh_footprints_are_miniworld_s(env):
    """The footprints the floor plan uses (read from the mesh files) are the extents of the
    meshes MiniWorld loaded and scaled."""
    env.reset(seed=0, options={"episode": 0})
    house = env.house
    for e, p, o in zip(env._renderer.entities, house.placed, house.objects, strict=True):
        if p.mesh is None:
            continue
        lo, hi = e.mesh.min_coords * e.scale, e.mesh.max_coords * e.scale
        x0, x1, z0, z1, h = mwh.local_box(o.cls, p.color)
        assert (x0, x1, z0, z1) == pytest.approx((lo[0], hi[0], lo[2], hi[2]), abs=1e-5)
        assert h == pytest.approx(hi[1], abs=1e-5)


# ---------------------------------------------------------------------- ground truth
def test_houses_are_seeded_and_connected(suite):
    a, b = mwh.generate_house(7, "a"), mwh.generate_house(7, "a")
    assert a.objects == b.objects and a.doors == b.doors and np.array_equal(a.nav.grid,
                                                                             b.nav.grid)
    assert mwh.generate_house(8, "a").objects != a.objects
    for seed in range(6):
        h = mwh.generate_house(seed, f"h{seed}")
        assert len(h.doors) >= len(h.rooms) - 1
        assert sorted(h.nav.reachable_objects()) == [o.id for o in h.objects]
        eps = mwh.generate_episodes(h, 5)
        assert eps == mwh.generate_episodes(h, 5)
        for ep in eps:
            assert h.nav.is_navigable(*ep.start[:2]) and h.objects_of(ep.goal_class)


def test_geodesic_distances_are_sane(suite):
    h = mwh.generate_house(0, "h0")
    nav = h.nav
    rng = np.random.default_rng(0)
    cells = np.argwhere(nav.grid)
    for cls in sorted({o.cls for o in h.objects}):
        f = nav.distance_field(cls)
        assert (f[nav.goal_region(cls)] == 0).all()
        for i, j in cells[rng.choice(len(cells), 50, replace=False)]:
            x, y = nav.to_world(int(i), int(j))
            # never shorter than the straight line to the success region
            assert f[i, j] >= nav.l2_to_class(x, y, cls) - 1.0 - 0.05
    # in an empty stretch of one room the geodesic is the straight line; through a wall it
    # is the way round by the door
    r = h.rooms[0]
    a, b = (r.x0 + 0.5, r.y0 + 0.5), (r.x0 + 0.5, r.y0 + 1.5)
    if all(nav.is_navigable(*p) for p in (a, b)):
        assert nav.geodesic_between(a, b) == pytest.approx(1.0, abs=0.08)
    d = h.doors[0]
    ra, rb = h.rooms[d.a], h.rooms[d.b]
    p = ((ra.x0 + ra.x1) / 2, (ra.y0 + ra.y1) / 2)
    q = ((rb.x0 + rb.x1) / 2, (rb.y0 + rb.y1) / 2)
    if nav.is_navigable(*p) and nav.is_navigable(*q):
        assert nav.geodesic_between(p, q) >= math.dist(p, q) - 0.05


def test_missing_miniworld_is_a_one_line_error(monkeypatch):
    monkeypatch.setattr(mwh.importlib.util, "find_spec", lambda name: None)
    with pytest.raises(KgnavError) as e:
        make_env("miniworld", EnvOptions(split="tiny"))
    assert "pip install 'kgnav[miniworld]'" in str(e.value) and "\n" not in str(e.value)


def test_unknown_split_and_scene_directories_are_refused(suite):
    with pytest.raises(KgnavError, match="unknown split 'nope' of environment 'miniworld'"):
        make_env("miniworld", EnvOptions(split="nope"))
    with pytest.raises(KgnavError, match="not --scenes-dir"):
        make_env("miniworld", EnvOptions(scenes_dir="/tmp"))


# ---------------------------------------------------------------------- the benchmark
@pytest.fixture(scope="module")
def evaluated(suite, env, tmp_path_factory):
    out = tmp_path_factory.mktemp("mw-eval")
    cfg = EvalConfig(env="miniworld", split="tiny", variants=("ans", "si", "oracle"),
                     segmenter="clean", extractor="opencv-gist", episodes=3, max_steps=150)
    records, summary = run_eval(cfg, out, progress=False)
    return cfg, out, records, summary


def test_benchmark_runs_ans_si_and_oracle(evaluated):
    _cfg, out, records, summary = evaluated
    assert len(records) == 3 * 2 * 3
    assert {r["scene"] for r in records} == {"mw0000", "mw0001"}
    oracle = [r for r in records if r["variant"] == "oracle"]
    assert all(r["success"] for r in oracle) and all(0 < r["spl"] <= 1 for r in oracle)
    for name in ("ans", "si"):
        s = summary[name]
        assert s["spl"] is not None and s["dts"] is not None and s["success"] >= 0.5
    for r in records:
        if r["variant"] != "oracle" and not r["success"]:
            assert r["failure"] is not None  # the ground truth for the failure classes
    fid = summary["si"]["memory"]
    assert fid["pooled"]["houses"] == 2 and fid["pooled"]["precision"] is not None
    for r in records:
        reloc = r.get("relocation")
        if reloc and reloc["same_house"]:
            assert "error_m" in reloc and "error_deg" in reloc  # ground-truth errors
    assert isinstance(summary["si"]["wrong_merges"], int)
    from kgnav import AbstractModel

    stored = sorted((out / "memory" / "si").glob("*.graphml"))
    assert stored
    for p in stored:  # built with opencv-gist at its calibrated threshold, and say so
        m = AbstractModel.load(p)
        assert m.classes == mwh.CLASSES and m.extractor == "opencv-gist"
        assert m.relocation_threshold == 0.1006


def test_benchmark_is_the_same_with_two_workers(evaluated, tmp_path):
    """A fresh process (no OpenGL context yet) with forked workers gives the same episodes."""
    _cfg, _out, records, _summary = evaluated
    out = tmp_path / "w2"
    code = ("from kgnav.benchmark.runner import EvalConfig, run_eval; "
            "run_eval(EvalConfig(env='miniworld', split='tiny', variants=('ans',), "
            "segmenter='clean', extractor='opencv-gist', episodes=2, max_steps=150, "
            f"workers=2), {str(out)!r}, progress=False)")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=600)
    assert res.returncode == 0, res.stderr[-2000:]
    two = [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines()]
    one = [r for r in records if r["variant"] == "ans" and r["episode"] < 2]
    keys = ("scene", "episode", "success", "spl", "steps", "path_length", "goal")
    assert [[r[k] for k in keys] for r in two] == [[r[k] for k in keys] for r in one]
