"""Named noise models (kgnav.sim.noise): parsing, seeding, the LoCoBot preset's drift and
collisions, depth noise, and the one-line errors of `kgnav eval --noise`."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from kgnav.envs import EnvOptions, make_env
from kgnav.errors import KgnavError
from kgnav.sim.dynamics import (
    FORWARD_STEP,
    MOVE_FORWARD,
    TURN_ANGLE,
    TURN_LEFT,
    Dynamics,
    NoiseModel,
    Odometry,
    OdometryModel,
    compose,
)
from kgnav.sim.noise import (
    BENCHMARK_NOISE,
    DEFAULT_NOISE,
    NOISE_MODELS,
    NoiseSpec,
    locobot,
    parse_noise,
)
from tests.test_sim_env import corridor_env


# --------------------------------------------------------------------------- parsing
def test_presets_parse():
    # an environment is exact unless asked; the benchmark runs a real robot's noise
    assert DEFAULT_NOISE == "none" and BENCHMARK_NOISE == "locobot"
    assert {"none", "locobot"} <= set(NOISE_MODELS)
    none = parse_noise("none")
    assert none == NoiseSpec() and not none.active and parse_noise(None) == none
    loco = parse_noise("locobot")
    assert loco.name == "locobot" and loco.text == "locobot" and loco.depth == 0
    assert loco.actuation == locobot()[0] and loco.odometry == locobot()[1]
    # the habitat-sim LoCoBot numbers (Proportional controller, multiplier 0.5)
    a = loco.actuation
    assert a.forward_sigma == pytest.approx(0.5 * math.sqrt(0.007))
    assert a.lateral_sigma == pytest.approx(0.5 * math.sqrt(0.023))
    assert a.turn_sigma == pytest.approx(0.5 * math.sqrt(0.017)) and a.clip == 3
    two = parse_noise("locobot,scale=2,depth=0.01")
    assert two.text == "locobot,scale=2,depth=0.01" and two.depth == 0.01
    assert two.actuation.lateral_sigma == pytest.approx(2 * a.lateral_sigma)
    assert two.odometry.theta_per_rad == pytest.approx(2 * loco.odometry.theta_per_rad)
    assert not parse_noise("locobot,scale=0").actuation.active
    wet = parse_noise("locobot,slip=0.5")
    assert wet.odometry.slip == 0.5 and wet.odometry.theta_per_rad == loco.odometry.theta_per_rad
    assert wet.actuation == loco.actuation and loco.odometry.slip == 0  # off by default
    old = parse_noise("actuation=1,odometry=0.01")
    assert old.name == "custom" and old.actuation == NoiseModel.scaled(1.0)
    assert old.odometry == OdometryModel(0.01, math.radians(0.01))
    d = loco.to_dict()
    assert d["name"] == "locobot" and d["odometry"]["slip"] == 0 and d["depth_per_m"] == 0


@pytest.mark.parametrize("spec,message", [
    ("wobble", "unknown noise model 'wobble'"),
    ("locobot,foo=1", "unknown setting 'foo'"),
    ("locobot,actuation=1", "unknown setting 'actuation'"),
    ("actuation=1,scale=2", "unknown setting 'scale'"),
    ("locobot,scale=-1", "scale must be a number >= 0"),
    ("locobot,depth=nan", "depth must be a number >= 0"),
    ("locobot,depth=x", "depth needs a number"),
    ("locobot,depth=1,depth=2", "depth given twice"),
    ("odometry=-0.1", "odometry must be a number >= 0"),
    ("locobot,2", "expected KEY=VALUE"),
    ("locobot,slip=1.5", "slip is a share"),
])
def test_bad_specs_are_one_line_errors(spec, message):
    with pytest.raises(KgnavError, match=message.replace("(", r"\(")) as e:
        parse_noise(spec)
    assert "\n" not in str(e.value)


def test_cli_rejects_bad_specs_in_one_line(cli, tmp_path):
    for spec, message in (("wobble", "unknown noise model"), ("locobot,scale=-2", ">= 0"),
                          ("locobot,speed=3", "unknown setting 'speed'")):
        code, out, err = cli("eval", "--noise", spec, "--out", tmp_path / "x")
        assert code == 2 and message in err and "Traceback" not in err
    assert not (tmp_path / "x").exists()


def test_env_options_reject_a_bad_spec_and_levels_with_a_named_model():
    with pytest.raises(KgnavError, match="unknown noise model"):
        make_env("kgnav", EnvOptions(split="val-small", noise="wobble"))
    with pytest.raises(KgnavError, match="one or the other"):
        make_env("kgnav", EnvOptions(split="val-small", noise="locobot", actuation_noise=1))


def test_miniworld_takes_the_same_spec():
    mw = pytest.importorskip("kgnav.envs.miniworld")
    with pytest.raises(KgnavError, match="unknown setting 'foo'"):
        mw.MiniWorldHouses(EnvOptions(split="tiny", noise="locobot,foo=1"))
    house = mw.generate_house(0, "mw0000")
    env = mw.MiniWorldNav(house, mw.generate_episodes(house, 1), noise="locobot,depth=0.01")
    assert env.noise_spec == parse_noise("locobot,depth=0.01")
    assert env.noise == locobot()[0]

    def walk(noise, seed):
        e = mw.MiniWorldNav(house, mw.generate_episodes(house, 1), 64, 48, noise=noise)
        try:
            obs = e.reset(seed=seed)[0]
        except KgnavError as exc:
            pytest.skip(f"MiniWorld cannot render here ({exc})")
        depths, poses = [obs["depth"]], []
        for a in (2, 1, 1):
            obs = e.step(a)[0]
            depths.append(obs["depth"])
            poses.append(obs["pose"])
        return np.array(poses), np.array(depths), e.world_pose

    a, b, c = walk("locobot,depth=0.05", 1), walk("locobot,depth=0.05", 1), walk("none", 1)
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    assert not np.array_equal(a[0], c[0]) and not np.array_equal(a[1], c[1])


# --------------------------------------------------------------------------- in the simulator
def _walk(seed, noise=None, actions=(1, 1, 2, 1, 3, 1, 1), **kw):
    env = corridor_env(start_x=3.0, noise=noise, **kw)
    obs, _ = env.reset(seed=seed)
    poses, worlds, depths = [], [], [obs["depth"].copy()]
    for a in actions:
        obs, *_ = env.step(a)
        poses.append(obs["pose"].copy())
        worlds.append(env.world_pose)
        depths.append(obs["depth"].copy())
    return np.array(poses), np.array(worlds), np.array(depths)


def test_none_is_no_noise():
    base = _walk(3)
    for noise in ("none", NoiseSpec(), None):
        same = _walk(3, noise)
        assert all(np.array_equal(x, y) for x, y in zip(base, same, strict=True))
    poses, worlds, _ = base  # a perfect pose sensor: the truth in the start frame (theta 0)
    assert np.allclose(worlds[:, :2], poses[:, :2] + (3.0, 1.0))


def test_locobot_is_seeded():
    a, b, c = _walk(5, "locobot"), _walk(5, "locobot"), _walk(6, "locobot")
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    assert not np.array_equal(a[0], c[0]) and not np.array_equal(a[1], c[1])
    free = _walk(5)
    assert not np.allclose(a[1], free[1])  # the motion is noisy
    # the pose sensor is not the truth: its own error on top of the motion's
    start = (3.0, 1.0, 0.0)
    truth = np.array([_relative(start, w) for w in a[1]])
    assert not np.allclose(a[0], truth, atol=1e-6)


def _relative(origin, pose):
    from kgnav.sim.dynamics import relative_pose

    return relative_pose(origin, pose)


def test_depth_noise_is_relative_and_seeded():
    clean = _walk(2, actions=(2,))[2]
    noisy = _walk(2, "none,depth=0.05", actions=(2,))[2]
    again = _walk(2, "none,depth=0.05", actions=(2,))[2]
    assert np.array_equal(noisy, again) and noisy.dtype == np.float32
    inside = (clean > 0.5) & (clean < 4.0)
    rel = (noisy[inside] - clean[inside]) / clean[inside]
    assert 0.04 < rel.std() < 0.06 and abs(rel.mean()) < 0.01
    # and motion and pose untouched: depth noise has a stream of its own
    p0, w0, _ = _walk(2, "locobot")
    p1, w1, _ = _walk(2, "locobot,depth=0.05")
    assert np.array_equal(p0, p1) and np.array_equal(w0, w1)


# --------------------------------------------------------------------------- drift and bumps
def _odometry_error(n_moves: int, seed: int) -> float:
    """Position error of LoCoBot odometry after ``n_moves`` forward moves (a turn every fifth
    step) in open space."""
    _act, odo_model = locobot()
    odo = Odometry(model=odo_model, rng=np.random.default_rng(seed))
    true = (0.0, 0.0, 0.0)
    for i in range(n_moves):
        after = compose(true, (FORWARD_STEP, 0.0, 0.0))
        est = odo.update(true, after)
        true = after
        if i % 5 == 4:
            after = compose(true, (0.0, 0.0, TURN_ANGLE))
            est = odo.update(true, after)
            true = after
    return math.hypot(est[0] - true[0], est[1] - true[1])


def test_odometry_drift_grows_with_distance():
    short = np.array([_odometry_error(20, s) for s in range(150)])
    long = np.array([_odometry_error(200, s) for s in range(150)])
    assert np.median(long) > 3 * np.median(short)
    assert np.median(short) > 0.002  # a few mm after 5 m: there is noise at all


def test_perfect_odometry_has_no_drift():
    odo = Odometry(model=OdometryModel(), rng=np.random.default_rng(0))
    est = odo.update((1.0, 2.0, 0.3), (1.2, 2.1, 0.5))
    assert np.allclose(est, _relative((1.0, 2.0, 0.3), (1.2, 2.1, 0.5)))


def test_wheel_slip_reports_motion_that_did_not_happen():
    _act, model = locobot(slip=0.5)
    got = []
    for seed in range(200):
        odo = Odometry(model=model, rng=np.random.default_rng(seed))
        got.append(odo.update((0.0, 0.0, 0.0), (0.05, 0.0, 0.0), blocked=0.2)[0])
    got = np.array(got)
    # half of the 0.2 m blocked on average (clipped share), on top of the 0.05 m travelled
    assert 0.13 < got.mean() < 0.17 and got.min() >= 0.04 and got.max() <= 0.26
    free = Odometry(model=model, rng=np.random.default_rng(0)).update(
        (0.0, 0.0, 0.0), (0.05, 0.0, 0.0))
    assert abs(free[0] - 0.05) < 0.01


def test_a_bump_twists_the_base_more_than_a_free_move():
    act, _odo = locobot()
    env = corridor_env(start_x=3.0)
    nav = env.nav
    free, bumped = [], []
    for seed in range(150):
        d = Dynamics(nav, act, np.random.default_rng(seed))
        r = d.step((3.0, 1.0, 0.0), MOVE_FORWARD)  # along the corridor: free
        assert not r.collided
        free.append(r.pose[2])
        d2 = Dynamics(nav, act, np.random.default_rng(10_000 + seed))
        r = d2.step((9.4, 1.7, math.pi / 2), MOVE_FORWARD)  # into the side wall
        if r.collided:
            bumped.append(r.pose[2] - math.pi / 2)
            assert r.blocked > 0 and r.travelled < FORWARD_STEP
    assert len(bumped) > 100
    assert np.std(bumped) > 1.25 * np.std(free)


def test_turns_overshoot_and_move_the_base():
    act, _odo = locobot()
    nav = corridor_env(start_x=3.0).nav
    d = Dynamics(nav, act, np.random.default_rng(0))
    turns = np.array([d.step((3.0, 1.0, 0.0), TURN_LEFT).pose for _ in range(300)])
    assert turns[:, 2].mean() == pytest.approx(TURN_ANGLE + act.turn_mean, abs=0.01)
    assert turns[:, 2].std() == pytest.approx(act.turn_sigma, rel=0.2)
    assert np.hypot(turns[:, 0] - 3.0, turns[:, 1] - 1.0).mean() > 0.01


# --------------------------------------------------------------------------- the benchmark
def test_eval_records_the_noise_by_name_and_parameters(cli, tmp_path):
    code, out, err = cli("eval", "--split", "val-small", "--variants", "oracle", "--scenes", "1",
                         "--episodes", "1", "--noise", "locobot,depth=0.01",
                         "--out", tmp_path / "n", "--quiet")
    assert code == 0, err
    cfg = json.loads((tmp_path / "n" / "config.json").read_text())
    assert cfg["noise"] == "locobot,depth=0.01"
    assert cfg["noise_model"]["name"] == "locobot"
    assert cfg["noise_model"]["actuation"]["lateral_sigma"] == pytest.approx(
        0.5 * math.sqrt(0.023))
    assert cfg["noise_model"]["depth_per_m"] == 0.01


def test_the_benchmark_runs_locobot_noise_unless_told_otherwise():
    from kgnav.benchmark.runner import EvalConfig

    assert EvalConfig(split="val-small").noise == "locobot"
    assert EvalConfig(split="val-small").noise_spec.odometry.active
    assert EvalConfig(split="val-small", noise="none").noise == "none"
    # the older levels name the whole noise: no LoCoBot noise beside them
    old = EvalConfig(split="val-small", actuation_noise=1.0)
    assert old.noise == "none" and old.noise_spec.name == "custom"
    # an environment asked for nothing stays exact
    assert EnvOptions().noise is None and parse_noise(EnvOptions().noise) == NoiseSpec()


@pytest.mark.parametrize("args,noise", [((), "locobot"), (("--preset", "paper"), "none"),
                                        (("--preset", "paper", "--noise", "locobot"), "locobot"),
                                        (("--noise", "none"), "none")])
def test_eval_cli_noise_default_and_the_papers_noise_free_task(cli, tmp_path, args, noise):
    code, out, err = cli("eval", "--split", "val-small", "--variants", "oracle", "--scenes", "1",
                         "--episodes", "1", *args, "--out", tmp_path / "n", "--quiet")
    assert code == 0, err
    assert json.loads((tmp_path / "n" / "config.json").read_text())["noise"] == noise
