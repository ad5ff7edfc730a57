"""The segmenter trained and measured on any environment: labelled frames walked through the
protocol (kgnav.nets.segnet.env_data), ``train-segmenter --env`` and ``segmenter-bench --env``.

The environment is the numpy grid room of tests/test_envs.py (three classes: crate, barrel,
cone; 64 × 48 frames), so these run in seconds without OpenGL.
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from kgnav.envs import ENVS, EnvOptions, make_env, register_env
from kgnav.errors import KgnavError
from kgnav.nets.encoder.env_views import walk_scene
from kgnav.nets.segnet.bench import Scorer, walked_frames
from kgnav.nets.segnet.env_data import SHOWS_PIXELS, EnvLabelledViews
from kgnav.nets.segnet.train import SegTrainConfig, SegTrainer
from kgnav.nets.segnet.weights import SegmenterWeightsError, load_weights
from tests.test_envs import CLASSES, GridRoom, GridSuite

GRID = "tests.test_envs:GridSuite"
TINY = dict(batch=3, warmup=1, input_size=(40, 30), stem=4, channels=(4, 8, 8),
            depth_channels=(4, 8, 8))
WALK = 30


def _config(**kw) -> SegTrainConfig:
    return SegTrainConfig(**{**dict(seed=1, steps=3, split="any", n_houses=2, env=GRID,
                                    classes=CLASSES, walk_steps=WALK), **TINY, **kw})


@pytest.fixture(scope="module")
def views() -> EnvLabelledViews:
    return EnvLabelledViews.from_suite(make_env(GRID, EnvOptions()), [0, 1], WALK, seed=1)


def _params(t: SegTrainer) -> dict:
    return t.export().params


def _same(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)


# ---------------------------------------------------------------------- the walked frames
def test_walks_keep_the_environments_labels(views):
    assert views.classes == CLASSES and len(views) == 2
    v = views.views[0]
    assert v.semantic.shape == (WALK, 48, 64, 2) and v.semantic.dtype == np.uint16
    room = GridRoom(0)
    obs, _ = room.reset(options={"episode": 0})
    assert np.array_equal(v.semantic[0], obs["semantic"])  # the start's frame, its labels
    assert np.array_equal(v.rgb[0], obs["rgb"])
    plain = walk_scene(GridRoom(0), "r", WALK, 1, 1, 0)  # without labels: the same walk
    assert plain.semantic is None
    assert np.array_equal(plain.rgb, v.rgb) and np.array_equal(plain.poses, v.poses)


def test_frames_are_seeded_and_class_balanced(views):
    a = views.frames(np.random.default_rng(5), 24, object_share=1.0)
    b = views.frames(np.random.default_rng(5), 24, object_share=1.0)
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    rgb, depth, sem, houses, poses = a
    assert rgb.shape == (24, 48, 64, 3) and depth.dtype == np.float32
    assert sem.dtype == np.int32 and set(houses.tolist()) == {0, 1} and poses.shape == (24, 3)
    shown = [np.bincount(s[..., 0].ravel(), minlength=4)[1:] >= SHOWS_PIXELS for s in sem]
    assert all(s.any() for s in shown)  # every frame shows an object
    assert sum(s.any() for s in shown) == 24 and len({int(np.argmax(s)) for s in shown}) >= 2


def test_an_environment_without_labels_is_a_one_line_error():
    room = GridRoom(0)
    room.env_spec = replace(room.env_spec, semantic=False)
    with pytest.raises(KgnavError, match="no semantic channel") as e:
        walk_scene(room, "r", 5, 1, 0, semantic=True)
    assert "\n" not in str(e.value)


# ---------------------------------------------------------------------- training
def test_training_on_another_environment_is_reproducible_and_resumes(tmp_path, views):
    cfg = _config(steps=4)
    full = SegTrainer(cfg, sampler=views).fit()
    again = SegTrainer(cfg).fit()  # walks the rooms itself, from the config's seed
    assert _same(_params(full), _params(again)) and full.losses == again.losses
    other = SegTrainer(replace(cfg, seed=2)).fit()
    assert not _same(_params(full), _params(other))
    part = SegTrainer(cfg, sampler=views)
    part.train_step()
    part.train_step()
    ckpt = part.save_checkpoint(tmp_path / "run.ckpt")
    resumed = SegTrainer(cfg).load_checkpoint(ckpt)  # a new process: walks again
    resumed.fit()
    assert resumed.done and resumed.losses == full.losses
    assert _same(_params(full), _params(resumed))
    with pytest.raises(SegmenterWeightsError, match="another run: walk_steps"):
        SegTrainer(replace(cfg, walk_steps=WALK + 1)).load_checkpoint(ckpt)


def test_the_network_labels_the_environments_classes(views):
    t = SegTrainer(_config(), sampler=views)
    x, d, y = t.batch(0)
    assert x.shape == (3, 3, 30, 40) and y.shape == (3, 30, 40) and int(y.max()) <= 3
    assert t.config.arch.n_classes == 4 and np.allclose(t.config.class_weights(), [0.7, 1, 1, 1])
    w = t.fit().export()
    assert w.classes == CLASSES and w.meta["domain"]["env"] == GRID
    with pytest.raises(ValueError, match="walk_steps"):
        _config(walk_steps=0)
    with pytest.raises(KgnavError, match="labels"):
        SegTrainer(_config(classes=("crate", "barrel"))).batch(0)


# ---------------------------------------------------------------------- the commands
@pytest.fixture(scope="module", autouse=True)
def no_labels_env():
    """The grid rooms declaring no semantic channel."""

    class Unlabelled(GridSuite):
        def make(self, k, n=None):
            room = super().make(k, n)
            room.env_spec = replace(room.env_spec, semantic=False)
            return room

    register_env("grid-unlabelled")(Unlabelled)
    yield
    ENVS.pop("grid-unlabelled", None)


def test_train_segmenter_env_cli_budget_resume_and_calibration(tmp_path, cli):
    small = ("--env", GRID, "--split", "any", "--scenes", "2", "--walk-steps", str(WALK),
             "--steps", "2", "--batch", "2", "--seed", "2", "--quiet")
    full = tmp_path / "full.npz"
    code, out, err = cli("train-segmenter", "--out", full, *small, "--calibrate-frames", "6")
    assert code == 0, err
    assert "done at step 2/2" in out
    w = load_weights(full)
    assert w.classes == CLASSES and w.meta["domain"] == {
        "env": GRID, "train_split": "any", "scenes": 2, "walk_steps": WALK}
    assert len(w.meta["score_threshold_curve"]) == 19
    assert f"environment {GRID}'s any scenes (walked)" in w.meta["score_threshold_source"]
    part = tmp_path / "part.npz"
    code, out, err = cli("train-segmenter", "--out", part, "--time-budget", "0.00001", *small,
                         "--calibrate-frames", "0")
    assert code == 0 and "stopped by --time-budget at step 1/2" in out, err
    assert f"--env {GRID} --walk-steps {WALK} --scenes 2" in err  # how to continue
    code, out, err = cli("train-segmenter", "--out", part, "--resume", *small,
                         "--calibrate-frames", "0")
    assert code == 0 and "done at step 2/2" in out, err
    assert all(np.array_equal(w.params[k], load_weights(part).params[k]) for k in w.params)


@pytest.mark.parametrize(("args", "code", "expected"), [
    (("--env", "nope"), 2, "unknown environment 'nope'"),
    (("--env", "grid-unlabelled", "--split", "any"), 1, "no semantic channel"),
    (("--split", "val"), 2, "'val' is not one of train"),
])
def test_train_segmenter_env_bad_input_one_line(tmp_path, cli, args, code, expected):
    got, _out, err = cli("train-segmenter", "--out", tmp_path / "w.npz", "--steps", "1",
                         "--quiet", *args)
    assert got == code and expected in err and err.count("\n") == 1, err


def test_segmenter_bench_env_scores_in_the_environments_vocabulary(tmp_path, cli):
    trained = tmp_path / "grid.npz"
    SegTrainer(_config(steps=2)).fit().export().save(trained)
    out = tmp_path / "b"
    code, stdout, err = cli("segmenter-bench", "--env", GRID, "--split", "any", "--scenes", "2",
                            "--walk-steps", str(WALK), "--frames", "8", "--weights", trained,
                            "--segmenters", "learned,clean,default", "--out", out, "--quiet")
    assert code == 0, err
    report = json.loads((out / "segmenter_bench.json").read_text())
    assert report["env"] == GRID and report["classes"] == list(CLASSES)
    clean = report["segmenters"]["clean"]
    assert clean["mean_iou"] == 1.0 and clean["recall"] == 1.0 and clean["recall_goal"] == 1.0
    assert set(clean["iou"]) <= set(CLASSES) and clean["instances"] > 0
    assert f"environment {GRID}, split any" in stdout
    # the shipped weights know none of the rooms' classes: one line, exit 1
    code, _out, err = cli("segmenter-bench", "--env", GRID, "--split", "any", "--scenes", "2",
                          "--walk-steps", "10", "--frames", "2", "--segmenters", "learned",
                          "--out", tmp_path / "c", "--quiet")
    assert code == 1 and "labels none of the environment's 3 classes" in err
    assert err.count("\n") == 1


def test_walked_frames_and_a_vocabulary_scorer(views):
    frames = walked_frames(views, 6, seed=1)
    assert len(frames) == 6 and frames.scenes[0].startswith("grid-rooms")
    again = walked_frames(views, 6, seed=1)
    assert np.array_equal(frames.rgb, again.rgb)
    sc = Scorer(classes=CLASSES)
    assert sc.n_cls == 4 and sc.goal == {1, 2, 3}  # another environment: every class a goal
