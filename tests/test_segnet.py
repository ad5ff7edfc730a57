"""The learned RGB-D segmenter: output contract on rendered frames, RGB-D only (no semantic),
shipped weights, weight-file errors, reproducible and resumable training, the bench's scoring,
and the train-segmenter / segmenter-bench commands."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from kgnav.agent.segmentation import Segmentation, make_segmenter
from kgnav.common.classes import OBJECT_CLASSES
from kgnav.errors import KgnavError
from kgnav.nets.segnet.bench import Scorer, render_frames, score
from kgnav.nets.segnet.data import LabelledViews
from kgnav.nets.segnet.segmenter import LearnedSegmenter
from kgnav.nets.segnet.train import SegTrainConfig, SegTrainer
from kgnav.nets.segnet.weights import (
    DEFAULT_WEIGHTS,
    VERSION,
    SegmenterWeightsError,
    load_weights,
)
from kgnav.nets.weights import META_KEY
from kgnav.sim.house import generate_house

# a tiny network and batch: training tests check mechanics, not quality
TINY = dict(batch=3, n_houses=2, warmup=1, input_size=(40, 30), stem=4, channels=(4, 8, 8),
            depth_channels=(4, 8, 8))


@pytest.fixture(scope="module")
def seg() -> LearnedSegmenter:
    return make_segmenter("learned")


@pytest.fixture(scope="module")
def frames():
    return render_frames("val", 20, seed=5)


@pytest.fixture(scope="module")
def tiny_views() -> LabelledViews:
    return LabelledViews([generate_house(1000), generate_house(1001)], 80, 60)


# ---------------------------------------------------------------------- the segmenter
def test_output_contract_on_rendered_frames(seg, frames):
    for k in range(len(frames)):
        rgb, depth, sem = frames.rgb[k], frames.depth[k], frames.semantic[k]
        out = seg(rgb, depth)  # RGB-D only: no semantic channel
        assert isinstance(out, Segmentation)
        assert out.classes.shape == out.instances.shape == depth.shape
        assert out.classes.dtype == out.instances.dtype == np.int32
        assert ((out.instances > 0) == (out.classes > 0)).all()
        ids = [s.id for s in out.segments]
        assert ids == sorted(ids) and set(ids) == set(np.unique(out.instances)) - {0}
        for s in out.segments:
            m = out.instances == s.id
            assert s.pixels == m.sum() >= 20  # the state creator's minimum
            assert set(np.unique(out.classes[m])) == {OBJECT_CLASSES.index(s.cls) + 1}
            v, u = np.nonzero(m)
            assert s.bbox == (u.min(), v.min(), u.max() + 1, v.max() + 1)
            assert seg.min_score <= s.score <= 1
        # the ground truth is ignored when given; the output is deterministic
        again = seg(rgb, depth, sem)
        assert np.array_equal(again.instances, out.instances) and again.segments == out.segments


def test_shipped_network_segments_val_frames(seg, frames):
    """Unseen val houses: most object pixels are found, and labelled right (random weights
    score near zero)."""
    sc = score(seg, frames)
    r = sc.report()
    assert r["mean_iou"] > 0.4, r["iou"]
    assert r["recall"] > 0.4 and r["precision"] > 0.5, r


def test_agent_runs_without_a_semantic_channel(seg):
    from kgnav.agent.camera import Camera
    from kgnav.agent.features import make_extractor
    from kgnav.agent.loop import ObjectNavAgent
    from kgnav.sim import ObjectNavEnv

    env = ObjectNavEnv("val", 0)
    agent = ObjectNavAgent(Camera.from_env(env), seg, make_extractor("opencv-gist"))
    obs, _ = env.reset(seed=0, options={"episode": 0})
    agent.reset(env.goal_class, seed=0, scene=env.scene.name, episode=0)
    for _ in range(5):
        obs = {k: v for k, v in obs.items() if k != "semantic"}
        obs, _, terminated, truncated, _ = env.step(agent.act(obs))
        if terminated or truncated:
            break
    assert agent.model_.n_states >= 1


def test_registry_names_and_errors(seg):
    assert seg.name == "kgnav-segnet"
    assert isinstance(make_segmenter(seg.name), LearnedSegmenter)  # the reported name too
    with pytest.raises(KgnavError, match="known: .*learned"):
        make_segmenter("nonesuch")
    rgb = np.zeros((60, 80, 3), np.uint8)
    for bad_rgb, bad_depth, msg in [
        (rgb.astype(np.float32), np.ones((60, 80), np.float32), "rgb must"),
        (rgb, np.ones((60, 81), np.float32), "depth must"),
        (rgb, np.ones((60, 80), np.int32), "depth must"),
        (np.zeros((0, 0, 3), np.uint8), np.ones((0, 0), np.float32), "non-empty"),
    ]:
        with pytest.raises(ValueError, match=msg) as exc:
            seg(bad_rgb, bad_depth)
        assert "\n" not in str(exc.value)


def test_other_resolutions(seg, frames):
    rgb = np.repeat(np.repeat(frames.rgb[0], 2, 0), 2, 1)
    depth = np.repeat(np.repeat(frames.depth[0], 2, 0), 2, 1)
    out = seg(rgb, depth)
    assert out.classes.shape == (240, 320)
    small = seg(frames.rgb[0], frames.depth[0])
    assert {s.cls for s in out.segments} >= {s.cls for s in small.segments if s.pixels > 200}


def test_class_maps_become_components_with_scores():
    from kgnav.nets.segnet.segmenter import ClassMapSegmenter, segmentation_from_classes

    cls = np.zeros((30, 40), np.int64)
    cls[2:8, 2:8] = 1  # two separate chairs ...
    cls[2:8, 20:26] = 1
    cls[10:20, 2:10] = 6  # ... a sofa touching nothing
    cls[25:27, 30:32] = 2  # 4 px: 16 at frame scale, under the 20-px minimum
    conf = np.full((30, 40), 0.5)
    conf[2:8, 20:26] = 0.9
    out = segmentation_from_classes(cls, conf, frame_size=(80, 60))
    assert out.classes.shape == (60, 80)
    assert [(s.cls, s.pixels, s.score) for s in out.segments] == [
        ("chair", 144, 0.5), ("chair", 144, 0.9), ("sofa", 320, 0.5)]
    assert not (out.classes == 2).any()  # the tiny bed is gone
    with pytest.raises(ValueError, match="0..24"):
        segmentation_from_classes(np.full((4, 4), 25))
    high = segmentation_from_classes(cls, conf, frame_size=(80, 60), min_score=0.6)
    assert [(s.id, s.cls, s.score) for s in high.segments] == [(1, "chair", 0.9)]
    assert (high.classes > 0).sum() == 144
    seg = ClassMapSegmenter(lambda rgb, depth: (cls, conf), name="mine")
    got = seg(np.zeros((60, 80, 3), np.uint8), np.ones((60, 80), np.float32))
    assert got.segments == out.segments and seg.name == "mine"


# ---------------------------------------------------------------------- shipped weights
def test_shipped_weights_are_small_and_described():
    assert DEFAULT_WEIGHTS.stat().st_size <= 10 * 2**20
    w = load_weights()
    assert w.classes == OBJECT_CLASSES
    t = w.meta["train"]
    assert t["complete"] and t["train_steps"] == t["steps"]
    # trained and calibrated on training houses (the split's or generated ones), never val's
    assert t.get("scenes_dir") or t["split"] == "train"
    assert t["loss_curve"][-1] < 0.5 * t["loss_curve"][0]
    source = w.meta["score_threshold_source"]
    assert 0 < w.score_threshold < 1 and "houses" in source and "val" not in source


def _rewrite(src, dst, meta=None, drop=(), change=None):
    with np.load(src) as z:
        arrays = {k: z[k] for k in z.files if k not in drop}
    if meta is not None:
        arrays[META_KEY] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    arrays.update(change or {})
    with open(dst, "wb") as fh:
        np.savez(fh, **arrays)


@pytest.mark.parametrize("case", ["truncated", "garbage", "missing-file", "encoder-file",
                                  "version", "shape", "missing", "nan", "classes", "arch",
                                  "threshold"])
def test_bad_weight_files_raise_one_line_errors(tmp_path, case, cli):
    from kgnav.nets.encoder.weights import DEFAULT_WEIGHTS as ENCODER_WEIGHTS

    good = DEFAULT_WEIGHTS
    bad = tmp_path / f"{case}.npz"
    meta = dict(load_weights().meta)
    name = next(iter(load_weights().params))
    if case == "truncated":
        bad.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    elif case == "garbage":
        bad.write_bytes(b"\x00not weights" * 50)
    elif case == "missing-file":
        bad = tmp_path / "nowhere.npz"
    elif case == "encoder-file":  # another kgnav network's weights
        bad.write_bytes(ENCODER_WEIGHTS.read_bytes())
    elif case == "version":
        _rewrite(good, bad, meta={**meta, "version": VERSION + 1})
    elif case == "shape":
        _rewrite(good, bad, change={name: np.zeros((1, 2), np.float32)})
    elif case == "missing":
        _rewrite(good, bad, drop=(name,))
    elif case == "nan":
        _rewrite(good, bad, change={name: np.full_like(load_weights().params[name], np.nan)})
    elif case == "classes":
        _rewrite(good, bad, meta={**meta, "classes": ["chair"]})
    elif case == "arch":
        _rewrite(good, bad, meta={**meta, "arch": {"stem": "wide"}})
    elif case == "threshold":
        _rewrite(good, bad, meta={**meta, "score_threshold": 1.5})
    with pytest.raises(SegmenterWeightsError) as exc:
        LearnedSegmenter(bad)
    assert str(exc.value).startswith(f"{bad}: ") and "\n" not in str(exc.value)
    code, _, err = cli("segmenter-bench", "--out", tmp_path / "b", "--frames", "1",
                       "--segmenters", "learned", "--weights", bad, "--quiet")
    assert code == 1 and err.count("\n") == 1 and str(bad) in err


def test_weights_roundtrip(tmp_path):
    w = load_weights()
    w2 = load_weights(w.save(tmp_path / "copy.npz"))
    assert w2.arch == w.arch and w2.meta == w.meta
    assert all(np.array_equal(v, w2.params[k]) for k, v in w.params.items())


# ---------------------------------------------------------------------- training
def _params(t: SegTrainer) -> dict[str, np.ndarray]:
    return t.export().params


def _same(a: dict, b: dict) -> bool:
    return all(np.array_equal(a[k], b[k]) for k in a)


def test_training_is_reproducible_from_a_seed(tiny_views):
    a = SegTrainer(SegTrainConfig(seed=3, steps=2, **TINY), sampler=tiny_views).fit()
    b = SegTrainer(SegTrainConfig(seed=3, steps=2, **TINY), sampler=tiny_views).fit()
    c = SegTrainer(SegTrainConfig(seed=4, steps=2, **TINY), sampler=tiny_views).fit()
    assert _same(_params(a), _params(b)) and a.losses == b.losses
    assert not _same(_params(a), _params(c))


def test_resume_equals_an_uninterrupted_run(tmp_path, tiny_views):
    cfg = SegTrainConfig(seed=1, steps=4, **TINY)
    full = SegTrainer(cfg, sampler=tiny_views).fit()
    part = SegTrainer(cfg, sampler=tiny_views)
    part.fit(time_budget_s=0.0)  # stops before the first step
    assert part.step == 0
    part.train_step()
    part.train_step()
    ckpt = part.save_checkpoint(tmp_path / "run.ckpt")
    resumed = SegTrainer(cfg, sampler=tiny_views).load_checkpoint(ckpt)
    assert resumed.step == 2
    resumed.fit(checkpoint=ckpt)
    assert resumed.done and resumed.losses == full.losses
    assert _same(_params(full), _params(resumed))
    with pytest.raises(SegmenterWeightsError, match="another run"):
        SegTrainer(SegTrainConfig(seed=2, steps=4, **TINY)).load_checkpoint(ckpt)
    (tmp_path / "junk.ckpt").write_bytes(b"junk")
    with pytest.raises(SegmenterWeightsError, match="junk.ckpt"):
        SegTrainer(cfg).load_checkpoint(tmp_path / "junk.ckpt")


def test_exported_weights_match_the_training_network(tiny_views):
    t = SegTrainer(SegTrainConfig(seed=0, steps=3, **TINY), sampler=tiny_views).fit()
    x, d, _ = t.batch(7)
    t.net.eval()
    with torch.no_grad():
        ref = t.net(x, d)
    seg = LearnedSegmenter(t.export())
    with torch.no_grad():
        got = seg.net(x, d)
    np.testing.assert_allclose(got.numpy(), ref.numpy(), atol=1e-4)


def test_batches_are_labelled_and_class_balanced(tiny_views):
    t = SegTrainer(SegTrainConfig(seed=0, steps=1, **{**TINY, "batch": 40}), sampler=tiny_views)
    x, d, y = t.batch(0)
    assert x.shape == (40, 3, 30, 40) and d.shape == (40, 1, 30, 40) and y.shape == (40, 30, 40)
    assert y.dtype == torch.int64 and int(y.max()) <= len(OBJECT_CLASSES)
    # aimed views: most frames show an object, and many classes appear
    assert (y.flatten(1) > 0).any(1).float().mean() > 0.7
    assert len(torch.unique(y)) > 8


# ---------------------------------------------------------------------- the bench's scoring
def test_scorer_counts_hits_confusions_and_false_positives(frames):
    clean = score(make_segmenter("clean"), frames).report()
    assert clean["mean_iou"] == 1.0 and clean["recall"] == 1.0
    assert clean["fp_per_frame"] == 0 and clean["confusion_pairs"] == []
    # a hand-made frame: one right segment, one mislabelled, one on background
    sem = np.zeros((60, 80, 2), np.int32)
    sem[10:30, 10:30] = (1, 1)  # chair, instance 1
    sem[10:30, 40:60] = (6, 2)  # sofa, instance 2
    cls = sem[..., 0].copy()
    cls[10:30, 40:60] = 2  # the sofa read as a bed
    cls[40:50, 5:15] = 3  # a plant on the floor
    inst = np.zeros_like(cls)
    inst[10:30, 10:30], inst[10:30, 40:60], inst[40:50, 5:15] = 1, 2, 3
    sc = Scorer()
    for _ in range(3):  # the same view three times: the sofa is wrong in every one
        sc.add(Segmentation.from_maps(cls, inst), np.full((60, 80), 1.5, np.float32), sem, 0.001,
               "house")
    r = sc.report()
    assert r["recall"] == 0.5 and r["fp_per_frame"] == 2 and r["fp_background_per_frame"] == 1
    assert r["confusion_pairs"] == [["sofa", "bed", 3]]
    assert r["persistence"] == {"objects": 2, "views": 6, "mislabelled_views": 0.5,
                                "mislabelled_in_most_views": 0.5,
                                "mislabelled_in_all_views": 0.5}
    assert r["recall_by_distance"]["0-2 m"] == {"value": 0.5, "n": 6}
    assert r["iou"]["chair"] == 1.0 and r["iou"]["sofa"] == 0.0


# ---------------------------------------------------------------------- the commands
def test_train_segmenter_cli_budget_resume_and_reproducibility(tmp_path, cli):
    small = ("--steps", "2", "--batch", "2", "--seed", "2", "--quiet", "--calibrate-frames", "0")
    full = tmp_path / "full.npz"
    code, out, err = cli("train-segmenter", "--out", full, *small)
    assert code == 0, err
    assert "done at step 2/2" in out and "1 thread(s)" in out
    part = tmp_path / "part.npz"
    code, out, err = cli("train-segmenter", "--out", part, "--time-budget", "0.00001", *small)
    assert code == 0, err
    assert "stopped by --time-budget at step 1/2" in out and "--resume" in err
    assert not load_weights(part).meta["train"]["complete"]
    code, out, err = cli("train-segmenter", "--out", part, "--resume", *small)
    assert code == 0 and "resuming" in err and "done at step 2/2" in out
    a, b = load_weights(full), load_weights(part)
    assert _same(a.params, b.params) and a.score_threshold == 0.0
    # resuming a finished run only exports; here with the score threshold calibrated
    code, out, err = cli("train-segmenter", "--out", part, "--resume", *small[:-1], "3")
    c = load_weights(part)
    assert code == 0 and _same(a.params, c.params), err
    assert len(c.meta["score_threshold_curve"]) == 19
    assert c.score_threshold == max(c.meta["score_threshold_curve"], key=lambda r: r["f1"])[
        "threshold"]
    code, _, err = cli("train-segmenter", "--out", part, "--resume", "--steps", "2", "--batch",
                       "3", "--quiet")
    assert code == 1 and err.count("\n") == 1 and "another run" in err


def test_train_segmenter_on_houses_of_your_own(tmp_path, cli):
    """--scenes-dir trains and calibrates on a generated directory's houses: the weights
    record it as their domain, a resumed run is the same run only with the same directory,
    and a missing directory is one line, exit 1."""
    from kgnav.nets.segnet.train import SegTrainConfig, training_houses
    from kgnav.sim.scene_dir import generate_split

    names = generate_split(tmp_path / "mine", count=3, seed=9101, rooms=(8, 8), episodes=1)
    cfg = SegTrainConfig(n_houses=2, scenes_dir=str(tmp_path / "mine"))
    assert [h.name for h in training_houses(cfg)] == sorted(names)[:2]
    with pytest.raises(KgnavError, match="holds 3 houses, not the 4"):
        training_houses(SegTrainConfig(n_houses=4, scenes_dir=str(tmp_path / "mine")))
    small = ("--steps", "2", "--batch", "2", "--seed", "2", "--quiet")
    w = tmp_path / "w.npz"
    code, out, err = cli("train-segmenter", "--out", w, "--scenes-dir", tmp_path / "mine",
                         "--scenes", "2", "--calibrate-frames", "3",
                         "--checkpoint", tmp_path / "w.ckpt", *small)
    assert code == 0, err
    meta = load_weights(w).meta
    assert meta["domain"]["scenes_dir"] == str(tmp_path / "mine")
    assert meta["domain"]["scenes"] == 2 and "train_split" not in meta["domain"]
    assert f"the houses of {tmp_path / 'mine'}" in meta["score_threshold_source"]
    code, _, err = cli("train-segmenter", "--out", w, "--resume", "--checkpoint",
                       tmp_path / "w.ckpt", "--calibrate-frames", "0", *small)
    assert code == 1 and err.count("\n") == 1 and "scenes_dir=" in err  # the split's: another run
    code, _, err = cli("train-segmenter", "--out", tmp_path / "x.npz", "--scenes-dir",
                       tmp_path / "none", *small)
    assert code == 1 and err.count("\n") == 1 and "not a directory" in err


@pytest.mark.parametrize("args", [("--steps", "0"), ("--batch", "1"), ("--threads", "0"),
                                  ("--resume",), ("--device", "tpu")])
def test_train_segmenter_bad_arguments_exit_2_one_line(tmp_path, cli, args):
    code, _, err = cli("train-segmenter", "--out", tmp_path / "w.npz", *args)
    assert code == 2 and err.count("\n") == 1


def test_segmenter_bench_cli(tmp_path, cli):
    code, out, err = cli("segmenter-bench", "--out", tmp_path / "b", "--frames", "4",
                         "--segmenters", "learned,default", "--quiet")
    assert code == 0, err
    report = json.loads((tmp_path / "b" / "segmenter_bench.json").read_text())
    assert report["split"] == "val" and report["frames"] == 4
    assert set(report["segmenters"]) == {"learned", "default"}
    r = report["segmenters"]["learned"]
    assert set(r["recall_by_distance"]) <= {"0-2 m", "2-3.5 m", "3.5-5 m"}
    assert r["ms_per_frame"]["median"] > 0
    assert (tmp_path / "b" / "confusion.png").stat().st_size > 1000
    assert "mean IoU" in out
    code, _, err = cli("segmenter-bench", "--out", tmp_path / "c", "--segmenters", "learned,x")
    assert code == 2 and "unknown segmenter 'x'" in err and err.count("\n") == 1


def test_segmenter_bench_on_houses_of_your_own(tmp_path, cli):
    """--scenes-dir renders a generated directory's houses (none of a split's): the frames
    are those houses' and the report names the directory; a missing directory is one line,
    exit 1; another environment with it, a usage error."""
    from kgnav.sim.scene_dir import generate_split

    names = generate_split(tmp_path / "mine", count=2, seed=9100, rooms=(8, 8), episodes=2)
    code, out, err = cli("segmenter-bench", "--scenes-dir", tmp_path / "mine", "--out",
                         tmp_path / "b", "--frames", "4", "--segmenters", "learned,clean",
                         "--quiet")
    assert code == 0, err
    report = json.loads((tmp_path / "b" / "segmenter_bench.json").read_text())
    assert report["split"] is None and report["scenes_dir"] == str(tmp_path / "mine")
    assert report["houses"] == sorted(names) and report["frames"] == 4
    assert report["segmenters"]["clean"]["precision"] == 1.0
    assert f"the houses of {tmp_path / 'mine'}" in out
    code, _, err = cli("segmenter-bench", "--scenes-dir", tmp_path / "none", "--out",
                       tmp_path / "c")
    assert code == 1 and err.count("\n") == 1 and "not a directory" in err
    code, _, err = cli("segmenter-bench", "--scenes-dir", tmp_path / "mine", "--env", "miniworld",
                       "--out", tmp_path / "c")
    assert code == 2 and err.count("\n") == 1 and "--scenes-dir" in err


def test_segments_under_the_threshold_come_back_apart_when_asked():
    from kgnav.nets.segnet.segmenter import segmentation_from_classes

    cls = np.zeros((30, 40), np.int32)
    conf = np.zeros((30, 40), np.float32)
    for k, (c, mean) in enumerate([(1, 0.9), (2, 0.5), (3, 0.2)]):  # strong, weak, neither
        cls[5:15, 2 + 12 * k:10 + 12 * k] = c
        conf[5:15, 2 + 12 * k:10 + 12 * k] = mean
    plain = segmentation_from_classes(cls, conf, (80, 60), 10, min_score=0.6)
    out = segmentation_from_classes(cls, conf, (80, 60), 10, min_score=0.6, weak_score=0.4)
    assert plain.weak is None
    assert out.segments == plain.segments and [s.score for s in out.segments] == [0.9]
    assert np.array_equal(out.classes, plain.classes)
    assert np.array_equal(out.instances, plain.instances)
    weak = out.weak
    assert [(s.cls, s.score) for s in weak.segments] == [(OBJECT_CLASSES[1], 0.5)]
    assert weak.classes.shape == (60, 80) and set(np.unique(weak.classes)) == {0, 2}
    assert not (weak.instances.astype(bool) & out.instances.astype(bool)).any()
    none = segmentation_from_classes(cls, conf, (80, 60), 10, min_score=0.1, weak_score=0.05)
    assert none.weak.segments == [] and len(none.segments) == 3
