"""Feature calibration on any environment: views walked through the protocol
(kgnav.nets.encoder.env_views), ``train-encoder --env`` and ``relocation-bench --env``.

The environment is the numpy grid room of tests/test_envs.py (not kgnav's simulator), so these
run without OpenGL; tests/test_miniworld.py runs the benchmark on MiniWorld frames.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from kgnav.envs import EnvOptions, make_env
from kgnav.errors import KgnavError
from kgnav.nets.encoder.calibration import build_pairs
from kgnav.nets.encoder.env_views import EnvViewSampler, walk_scene
from kgnav.nets.encoder.views import NEGATIVE, POSITIVE, relation
from kgnav.nets.encoder.weights import load_weights
from tests.test_envs import GridRoom

GRID = "tests.test_envs:GridSuite"


@pytest.fixture(scope="module")
def sampler():
    return EnvViewSampler.from_suite(make_env(GRID, EnvOptions(max_steps=400)), [0, 1],
                                     steps=60, seed=3)


def test_walks_are_seeded_and_follow_the_protocol(sampler):
    again = EnvViewSampler.from_suite(make_env(GRID, EnvOptions(max_steps=400)), [0, 1],
                                      steps=60, seed=3)
    other = EnvViewSampler.from_suite(make_env(GRID, EnvOptions(max_steps=400)), [0, 1],
                                      steps=60, seed=4)
    for a, b in zip(sampler.views, again.views, strict=True):
        assert a.name == b.name and np.array_equal(a.poses, b.poses)
        assert np.array_equal(a.rgb, b.rgb) and np.array_equal(a.depth, b.depth)
    assert not np.array_equal(sampler.views[0].poses, other.views[0].poses)
    v = sampler.views[0]
    assert v.rgb.shape == (60, 48, 64, 3) and v.depth.dtype == np.float16
    # no episode_start hook: one episode, poses in its start frame, turns of 45°
    assert tuple(v.poses[0]) == (0.0, 0.0, 0.0)
    steps = np.hypot(*np.diff(v.poses[:, :2], axis=0).T)
    assert set(np.round(steps, 6)) <= {0.0, 0.2}
    turns = np.round(np.degrees(np.remainder(np.diff(v.poses[:, 2]) + np.pi, 2 * np.pi)
                                - np.pi), 6)
    assert set(turns) <= {0.0, 45.0, -45.0} and (steps > 0).sum() > 20


def test_stored_views_are_the_frames_of_their_poses(sampler):
    """A view served for a pose is the frame the environment rendered there."""
    room = GridRoom(0)
    room.reset(options={"episode": 0})
    sx, sy, st = room.start
    assert np.array_equal(sampler.render(0, (0.0, 0.0, 0.0)), room.render()[0])  # the start
    rng = np.random.default_rng(0)
    for _ in range(5):
        p = sampler.random_pose(0, rng)
        c, s = math.cos(st), math.sin(st)
        room.pose = (sx + c * p[0] - s * p[1], sy + s * p[0] + c * p[1], st + p[2])
        _rgb, depth, _cls, _inst = room.render()
        # (the room's wall stripes flip with the last bit of a ray's hit point: no RGB check
        # on a pose that went back to the world through float arithmetic)
        got_rgb, got_depth = sampler.render_depth(0, p)
        assert got_rgb is sampler.render(0, p) or np.array_equal(got_rgb, sampler.render(0, p))
        assert np.median(np.abs(got_depth - np.clip(depth, 0.1, 4.0))) < 5e-3
    with pytest.raises(KgnavError, match="no stored view"):
        sampler.render(0, (9.0, 9.0, 0.0))


def test_pose_near_keeps_to_its_ranges(sampler):
    rng = np.random.default_rng(1)
    for _ in range(30):
        a = sampler.random_pose(1, rng)
        b = sampler.pose_near(1, a, rng)
        assert b is not None and relation(1, a, 1, b) == POSITIVE
        far = sampler.pose_near(1, a, rng, dist=(1.05, 4.0), turn=(0.0, math.pi))
        if far is not None:
            assert relation(1, a, 1, far) == NEGATIVE and math.dist(a[:2], far[:2]) >= 1.05
        turned = sampler.pose_near(1, a, rng, dist=(0.0, 0.0), turn=(math.radians(95), math.pi))
        if turned is not None:
            assert turned[:2] == a[:2] and relation(1, a, 1, turned) == NEGATIVE
    with pytest.raises(KgnavError, match="at least two scenes"):
        EnvViewSampler(sampler.views[:1])


def test_relocation_pairs_from_walked_views_are_labelled_right(sampler):
    from kgnav.agent.features import make_extractor

    ps = build_pairs(sampler, [make_extractor("opencv-gist")], n_pos=20, seed=0)
    assert ps.counts()["positive"] == 20 and len(ps.pairs) > 40
    for (i, j), k in zip(ps.pairs, ps.kinds, strict=True):
        r = relation(int(ps.houses[i]), tuple(ps.poses[i]), int(ps.houses[j]),
                     tuple(ps.poses[j]))
        assert r == (POSITIVE if k == 0 else NEGATIVE)
    assert ps.scene_names == ["grid-rooms-00", "grid-rooms-01"]  # the suite's name


def test_walk_uses_every_episode_with_episode_starts():
    room = GridRoom(0, hooks=True)
    views = walk_scene(room, "room", steps=30, episodes=3, seed=0)
    assert len(views.poses) == 30
    starts = {tuple(room.episode_start(i)) for i in range(3)}
    assert starts <= {tuple(p) for p in views.poses}  # world poses: each episode's start


# ---------------------------------------------------------------------- the commands
def test_relocation_bench_on_another_environment(tmp_path, cli):
    out = tmp_path / "rb"
    code, stdout, err = cli("relocation-bench", "--env", GRID, "--split", "any",
                            "--extractors", "opencv-gist", "--pairs", "20", "--walk-steps",
                            "50", "--out", out, "--quiet")
    assert code == 0, err
    rep = json.loads((out / "relocation.json").read_text())
    assert rep["env"] == GRID and rep["split"] == "any" and rep["pairs"]["positive"] == 20
    assert "environment tests.test_envs:GridSuite" in stdout


def test_train_encoder_on_another_environment(tmp_path, cli):
    w = tmp_path / "w.npz"
    code, _out, err = cli("train-encoder", "--env", GRID, "--out", w, "--steps", "2",
                          "--dim", "8", "--houses-per-batch", "2", "--places-per-house", "2",
                          "--calibrate-pairs", "11", "--walk-steps", "40", "--quiet")
    assert code == 0, err
    meta = load_weights(w).meta
    assert meta["domain"]["env"] == GRID and meta["domain"]["train_split"] == "train"
    assert meta["train"]["split"] == f"{GRID}:train"
    assert "environment tests.test_envs:GridSuite, split val" in meta["threshold_source"]


@pytest.mark.parametrize(("args", "expected"), [
    (("--env", "nope"), "unknown environment 'nope'"),
    (("--env", "kgnav", "--split", "nope"), "'nope' is not one of"),
    (("--env", GRID, "--scenes", "1"), "1 is not in the range x>=2"),
])
def test_bad_environment_arguments_are_one_line_usage_errors(tmp_path, cli, args, expected):
    code, _out, err = cli("relocation-bench", "--out", tmp_path / "o", *args, "--quiet")
    assert code == 2 and err.count("\n") == 1 and expected in err, err


# ---------------------------------------------------------------------- using such weights
@pytest.fixture(scope="module")
def grid_weights(sampler, tmp_path_factory):
    """A (barely) trained encoder on the grid room's frames, threshold 0.05."""
    from kgnav.nets.encoder.train import TrainConfig, Trainer

    cfg = TrainConfig(seed=0, steps=1, dim=8, houses_per_batch=2, places_per_house=2,
                      split=f"{GRID}:train", n_houses=len(sampler))
    path = tmp_path_factory.mktemp("w") / "grid.npz"
    weights = Trainer(cfg, sampler=sampler).fit().export(0.05, "test")
    weights.meta["domain"] = {"env": GRID, "train_split": "train"}  # as train-encoder --env
    weights.save(path)
    return path


def test_other_weights_are_another_extractor(grid_weights, tmp_path):
    from kgnav.nets.encoder.extractor import LOOP_THRESHOLD, LearnedEncoder
    from kgnav.nets.encoder.weights import DEFAULT_WEIGHTS, set_threshold

    shipped = LearnedEncoder(device="cpu")
    assert shipped.name == "kgnav-encoder" and shipped.loop_threshold == LOOP_THRESHOLD
    copy = tmp_path / "copy.npz"
    copy.write_bytes(DEFAULT_WEIGHTS.read_bytes())
    set_threshold(copy, 0.01, "recalibrated")  # same features: same extractor
    assert LearnedEncoder(copy, device="cpu").name == "kgnav-encoder"
    other = LearnedEncoder(grid_weights, device="cpu")
    fp = load_weights(grid_weights).fingerprint()
    assert other.name == f"kgnav-encoder:{fp}" and len(fp) == 12
    assert other.loop_threshold == other.threshold == 0.05  # its own, not the shipped one's


def test_eval_with_retrained_encoder_weights(grid_weights, tmp_path, cli):
    from kgnav import AbstractModel

    out = tmp_path / "ev"
    code, _out, err = cli("eval", "--env", GRID, "--segmenter", "clean", "--variants", "si",
                          "--episodes", "2", "--encoder-weights", grid_weights, "--out", out,
                          "--quiet")
    assert code == 0, err
    fp = load_weights(grid_weights).fingerprint()
    config = json.loads((out / "config.json").read_text())
    assert config["features"] == f"kgnav-encoder:{fp}"
    assert config["encoder_weights"] == str(grid_weights)
    stored = sorted((out / "memory" / "si").glob("*.graphml"))
    assert stored
    for p in stored:
        m = AbstractModel.load(p)
        assert m.extractor == f"kgnav-encoder:{fp}" and m.relocation_threshold == 0.05
    code, _out, err = cli("eval", "--env", GRID, "--extractor", "opencv-gist",
                          "--encoder-weights", grid_weights, "--out", out, "--quiet")
    assert code == 2 and err.count("\n") == 1 and "--encoder-weights" in err
    code, _out, err = cli("eval", "--env", GRID, "--encoder-weights", tmp_path / "none.npz",
                          "--out", out, "--quiet")
    assert code == 1 and err.count("\n") == 1 and "none.npz" in err
