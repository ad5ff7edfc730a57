"""The agent's segmenter: clean ground truth, the noise model's effects, determinism, errors."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from kgnav.agent.noise_segmenters import (
    CONFUSIONS,
    SEGMENTER_PRESETS,
    NoisySegmenter,
    SegmenterNoise,
)
from kgnav.agent.segmentation import Segmentation, Segmenter, make_segmenter
from kgnav.common.classes import OBJECT_CLASSES, OBJECTNAV_CLASSES
from kgnav.errors import KgnavError

H, W = 120, 160
RGB = np.zeros((H, W, 3), np.uint8)
CLEAN = SEGMENTER_PRESETS["clean"]


def noise(**kw) -> SegmenterNoise:
    """The clean preset with some effects switched on."""
    return dataclasses.replace(CLEAN, **kw)


@pytest.fixture(scope="module")
def frames():
    """A dozen rendered frames of a validation house (scene name, rgb, depth, semantic)."""
    from kgnav.sim import ObjectNavEnv

    env = ObjectNavEnv(split="val-small", scene=0)
    obs, info = env.reset(seed=0)
    out = []
    for a in (1, 1, 2, 1, 3, 3, 1, 1, 2, 2, 1, 3):
        out.append((info["scene"], obs["rgb"], obs["depth"], obs["semantic"]))
        obs, _, _, _, info = env.step(a)
    assert sum(len(np.unique(f[3][..., 1])) > 1 for f in out) >= 6  # frames show objects
    return out


def grid_frame(classes, depth=2.0, size=16, gap=4, id0=1):
    """Synthetic frame: square instances (ids id0, id0+1, ...) of ``classes`` on a grid, in
    front of a flat wall; ``depth`` is the objects' depth (scalar or one per object)."""
    sem = np.zeros((H, W, 2), np.int32)
    dep = np.full((H, W), 4.9, np.float32)
    per_row = (W - gap) // (size + gap)
    d = np.broadcast_to(np.asarray(depth, np.float32), (len(classes),))
    for k, c in enumerate(classes):
        r, q = divmod(k, per_row)
        v0, u0 = gap + r * (size + gap), gap + q * (size + gap)
        assert v0 + size <= H, "too many objects for the frame"
        sem[v0 : v0 + size, u0 : u0 + size] = (OBJECT_CLASSES.index(c) + 1, id0 + k)
        dep[v0 : v0 + size, u0 : u0 + size] = d[k]
    return RGB, dep, sem


def check_consistent(out: Segmentation) -> None:
    """Segments agree with the maps: ids, classes, exact pixel counts and tight boxes."""
    assert out.classes.dtype == np.int32 and out.instances.dtype == np.int32
    ids = np.unique(out.instances)
    ids = ids[ids > 0].tolist()
    assert [s.id for s in out.segments] == ids
    assert not out.classes[out.instances == 0].any()
    for s in out.segments:
        m = out.instances == s.id
        assert s.pixels == int(m.sum())
        assert (out.classes[m] == OBJECT_CLASSES.index(s.cls) + 1).all()
        rows, cols = np.flatnonzero(m.any(1)), np.flatnonzero(m.any(0))
        assert s.bbox == (cols[0], rows[0], cols[-1] + 1, rows[-1] + 1)
        assert 0.0 <= s.score <= 1.0


def seg_class_of(out: Segmentation, sem: np.ndarray) -> dict[int, str]:
    """Output class of each ground-truth instance that has a segment mostly on it."""
    res = {}
    for s in out.segments:
        g = np.bincount(sem[..., 1][out.instances == s.id])
        res[int(np.argmax(g))] = s.cls
    res.pop(0, None)
    return res


# ---------------------------------------------------------------------------------- clean
def test_clean_reproduces_ground_truth(frames):
    seg = make_segmenter("clean")
    assert seg.name == "gt-clean" and isinstance(seg, Segmenter)
    seg.reset(0, frames[0][0])
    for _, rgb, depth, sem in frames:
        out = seg(rgb, depth, sem)
        np.testing.assert_array_equal(out.classes, sem[..., 0])
        # the instance partition is the ground truth's, up to renaming the ids
        pairs = np.unique(np.stack([sem[..., 1].ravel(), out.instances.ravel()]), axis=1)
        assert len(np.unique(pairs[0])) == len(np.unique(pairs[1])) == pairs.shape[1]
        assert ((pairs[0] == 0) == (pairs[1] == 0)).all()
        check_consistent(out)
        assert all(s.score == 1.0 for s in out.segments)
        for s in out.segments:  # segment ids follow ground-truth ids in order
            g = int(sem[..., 1][out.instances == s.id][0])
            assert s.pixels == int((sem[..., 1] == g).sum())


@pytest.mark.parametrize("offset", [0, 300, 70_000, 2**30])
def test_clean_handles_any_instance_ids(offset):
    rgb, depth, sem = grid_frame(["chair", "bed", "sofa"], id0=1 + offset)
    out = make_segmenter("clean")(rgb, depth, sem)
    assert [(s.id, s.cls, s.pixels) for s in out.segments] == [
        (1, "chair", 256), (2, "bed", 256), (3, "sofa", 256)]
    np.testing.assert_array_equal(out.classes, sem[..., 0])


def test_presets_and_names():
    assert set(SEGMENTER_PRESETS) >= {"clean", "default", "heavy"}
    assert CLEAN.is_clean and not SEGMENTER_PRESETS["default"].is_clean
    for key in SEGMENTER_PRESETS:
        seg = make_segmenter(key, seed=4)
        again = make_segmenter(seg.name, seed=4)  # the reported name round-trips
        assert again.name == seg.name and again.noise == seg.noise
    assert make_segmenter("default").name == "gt-noisy"
    assert NoisySegmenter(noise(miss=0.1)).name == "gt-noisy-custom"


# ---------------------------------------------------------------------------------- invariants
@pytest.mark.parametrize("preset", ["default", "heavy"])
def test_noisy_output_is_consistent(frames, preset):
    seg = make_segmenter(preset, seed=2)
    for ep in range(3):
        seg.reset(ep, frames[0][0])
        for _, rgb, depth, sem in frames:
            check_consistent(seg(rgb, depth, sem))


@given(st.integers(0, 2**32 - 1), st.integers(1, 12), st.sampled_from([1, 3, 40, 300]))
def test_from_maps_matches_the_maps(seed, n, scale):
    rng = np.random.default_rng(seed)
    h, w = int(rng.integers(1, 30)), int(rng.integers(1, 30))
    # blocky random instances (runs and holes), each with one class
    inst = rng.integers(0, n + 1, (h // 2 + 1, w // 3 + 1)).repeat(2, 0).repeat(3, 1)[:h, :w]
    inst = inst * scale
    cls_of = rng.integers(1, len(OBJECT_CLASSES) + 1, inst.max() + 1)
    classes = np.where(inst > 0, cls_of[inst], 0)
    scores = {i: 0.5 for i in range(0, inst.max() + 1, 2)}
    out = Segmentation.from_maps(classes, inst, scores)
    check_consistent(out)
    for s in out.segments:
        assert s.score == (0.5 if s.id % 2 == 0 else 1.0)


def test_from_maps_rejects_bad_maps():
    inst = np.zeros((4, 5), np.int32)
    inst[1:3, 1:3] = 1
    classes = np.where(inst > 0, 2, 0)
    assert [s.bbox for s in Segmentation.from_maps(classes, inst).segments] == [(1, 1, 3, 3)]
    mixed = classes.copy()
    mixed[1, 1] = 3
    with pytest.raises(ValueError, match="several classes"):
        Segmentation.from_maps(mixed, inst)
    with pytest.raises(ValueError, match="background"):
        Segmentation.from_maps(np.zeros_like(inst), inst)
    with pytest.raises(ValueError, match="shape"):
        Segmentation.from_maps(classes[:3], inst)
    with pytest.raises(ValueError, match="integer"):
        Segmentation.from_maps(classes.astype(float), inst)


# ---------------------------------------------------------------------------------- determinism
def run(seg, frames, seed):
    seg.reset(seed, frames[0][0])
    return [seg(rgb, depth, sem) for _, rgb, depth, sem in frames]


def same(a: list[Segmentation], b: list[Segmentation]) -> bool:
    return all(
        x.segments == y.segments and np.array_equal(x.instances, y.instances)
        and np.array_equal(x.classes, y.classes) for x, y in zip(a, b, strict=True))


def test_deterministic(frames):
    a = run(make_segmenter("heavy", seed=5), frames, 1)
    seg = make_segmenter("heavy", seed=5)
    assert same(a, run(seg, frames, 1))
    assert same(a, run(seg, frames, 1))  # reset restarts the frame counter
    assert not same(a, run(seg, frames, 2))  # another episode seed: other per-frame noise
    assert not same(a, run(make_segmenter("heavy", seed=6), frames, 1))


# ---------------------------------------------------------------------------------- misses
def miss_rate(nz, depth, size, n_frames=150, seed=0):
    classes = [OBJECTNAV_CLASSES[k % 6] for k in range(12)]
    rgb, dep, sem = grid_frame(classes, depth=depth, size=size)
    seg = NoisySegmenter(nz, seed)
    seg.reset(seed, "synthetic")
    missed = 0
    for _ in range(n_frames):
        out = seg(rgb, dep, sem)
        seen = np.unique(sem[..., 1][out.instances > 0])
        missed += 12 - np.count_nonzero(seen)
    return missed / (12 * n_frames)


def test_miss_rate_grows_with_distance_and_smallness():
    nz = dataclasses.replace(SEGMENTER_PRESETS["default"], fp_rate=0.0, phantom_fraction=0.0,
                             degrade=0.0, degrade_far=0.0)
    near, far = miss_rate(nz, 1.0, 16), miss_rate(nz, 4.8, 16)
    assert near < 0.15 and far > near + 0.15, (near, far)
    tiny = miss_rate(nz, 1.0, 4)
    assert tiny > near + 0.2, (near, tiny)
    # without hard instances, misses follow the configured rates
    nz2 = noise(miss=0.1, miss_far=0.5)
    assert abs(miss_rate(nz2, 1.0, 16) - 0.1) < 0.04
    assert abs(miss_rate(nz2, 5.0, 16) - 0.6) < 0.06
    assert miss_rate(CLEAN, 5.0, 4) == 0.0


def test_hard_instances_are_missed_persistently():
    nz = noise(hard_fraction=0.3, hard_miss=0.95)
    rates = []
    for sd in (0, 1):  # two episodes in the same scene
        classes = ["chair"] * 40
        rgb, dep, sem = grid_frame(classes, size=8, gap=6)
        seg = NoisySegmenter(nz, seed=9)
        seg.reset(sd, "house-a")
        seen = np.zeros(41)
        for _ in range(40):
            out = seg(rgb, dep, sem)
            seen[np.unique(sem[..., 1][out.instances > 0])] += 1
        rates.append(seen[1:] / 40)
    hard = [r < 0.5 for r in rates]
    np.testing.assert_array_equal(hard[0], hard[1])  # the same instances, every episode
    assert 0.1 < hard[0].mean() < 0.55


# ---------------------------------------------------------------------------------- confusion
def test_confusion_table_is_well_formed():
    assert set(CONFUSIONS) == set(OBJECT_CLASSES)
    for c, row in CONFUSIONS.items():
        assert row and all(t in OBJECT_CLASSES and t != c and w > 0 for t, w in row)
        assert len({t for t, _ in row}) == len(row)


def test_confused_labels_come_from_the_table():
    nz = noise(confusion=1.0)
    rgb, dep, sem = grid_frame(list(OBJECT_CLASSES))
    seg = NoisySegmenter(nz, seed=1)
    seg.reset(0, "s")
    targets = {c: set() for c in OBJECT_CLASSES}
    for _ in range(60):
        out = seg(rgb, dep, sem)
        got = seg_class_of(out, sem)
        assert len(got) == len(OBJECT_CLASSES)
        for g, cls in got.items():
            true = OBJECT_CLASSES[g - 1]
            assert cls != true and cls in dict(CONFUSIONS[true])
            targets[true].add(cls)
    # the flips spread over the table's entries
    assert sum(len(v) for v in targets.values()) > 1.5 * len(OBJECT_CLASSES)


def test_confusion_grows_with_distance():
    nz = noise(confusion=0.05, confusion_far=0.5)
    classes = list(OBJECTNAV_CLASSES) * 2

    def wrong(depth):
        rgb, dep, sem = grid_frame(classes, depth=depth)
        seg = NoisySegmenter(nz, seed=3)
        seg.reset(0, "s")
        n = 0
        for _ in range(100):
            got = seg_class_of(seg(rgb, dep, sem), sem)
            n += sum(cls != classes[g - 1] for g, cls in got.items())
        return n / (100 * len(classes))

    near, far = wrong(1.0), wrong(5.0)
    assert abs(near - 0.05) < 0.04 and abs(far - 0.55) < 0.08, (near, far)


def test_persistent_confusions_are_stable():
    nz = noise(persistent_confusion=0.4, persistent_consistency=1.0)
    classes = [OBJECT_CLASSES[k % len(OBJECT_CLASSES)] for k in range(30)]
    rgb, dep, sem = grid_frame(classes, size=12)
    seg = NoisySegmenter(nz, seed=11)
    labels = []
    for ep in range(3):
        seg.reset(ep, "house-b")
        for _ in range(5):
            labels.append(seg_class_of(seg(rgb, dep, sem), sem))
    assert all(lab == labels[0] for lab in labels)  # every frame of every episode
    wrong = {g: c for g, c in labels[0].items() if c != classes[g - 1]}
    assert 4 <= len(wrong) <= 22
    assert all(c in dict(CONFUSIONS[classes[g - 1]]) for g, c in wrong.items())
    seg.reset(0, "house-c")  # another house: other objects are affected
    assert seg_class_of(seg(rgb, dep, sem), sem) != labels[0]


def test_phantoms_are_persistent_wrong_class_segments():
    nz = noise(phantom_fraction=1.0, phantom_rate=1.0)
    classes = ["sofa", "bed", "table", "cabinet"]
    rgb, dep, sem = grid_frame(classes, size=30, gap=8)
    seg = NoisySegmenter(nz, seed=2)
    seen = []
    for ep in range(3):
        seg.reset(ep, "house-d")
        for _ in range(3):
            out = seg(rgb, dep, sem)
            check_consistent(out)
            assert len(out.segments) == 8  # each object and its phantom
            ph = []
            for s in out.segments:
                g = np.bincount(sem[..., 1][out.instances == s.id]).argmax()
                if s.cls != classes[g - 1]:
                    ph.append((int(g), s.cls, s.bbox))
            assert len(ph) == 4
            seen.append(ph)
    assert all(p == seen[0] for p in seen)  # same class, same place, every time


# ---------------------------------------------------------------------------------- false positives
def test_false_positive_count_follows_the_poisson_rate():
    nz = noise(fp_rate=2.0, fp_goal_share=0.75)
    dep = np.full((H, W), 2.5, np.float32)  # a flat wall facing the camera
    sem = np.zeros((H, W, 2), np.int32)
    seg = NoisySegmenter(nz, seed=0)
    seg.reset(7, "s")
    counts, goal = [], 0
    for _ in range(300):
        out = seg(RGB, dep, sem)
        counts.append(len(out.segments))
        goal += sum(s.cls in OBJECTNAV_CLASSES for s in out.segments)
        assert all(0.3 <= s.score <= 0.8 for s in out.segments)
    c = np.array(counts)
    # overlapping blobs may hide one another: allow a little below the rate
    assert 1.7 < c.mean() < 2.25, c.mean()
    assert 0.6 < c.var() / c.mean() < 1.4
    assert 0.65 < goal / c.sum() < 0.85


def test_false_positives_sit_on_vertical_surfaces():
    # ceiling (rows 0-39) and floor (80-119) change depth down a column; the wall does not
    dep = np.full((H, W), 3.0, np.float32)
    dep[:40] = (1.0 + 0.03 * np.arange(40, dtype=np.float32))[:, None]
    dep[80:] = (2.0 - 0.015 * np.arange(40, dtype=np.float32))[:, None]
    seg = NoisySegmenter(noise(fp_rate=3.0), seed=1)
    seg.reset(0, "s")
    n = 0
    for _ in range(40):
        out = seg(RGB, dep, np.zeros((H, W, 2), np.int32))
        assert not out.instances[:40].any() and not out.instances[80:].any()
        n += len(out.segments)
    assert n > 60


def test_blobs_are_never_the_true_class_under_them():
    classes = ["chair"] * 24
    rgb, dep, sem = grid_frame(classes, size=24, gap=2)  # chairs nearly everywhere
    seg = NoisySegmenter(noise(fp_rate=3.0, fp_goal_share=1.0), seed=4)
    seg.reset(0, "s")
    on_chairs = 0
    for _ in range(40):
        out = seg(rgb, dep, sem)
        for s in out.segments[24:]:  # the blobs, painted after the 24 chairs
            if sem[..., 1][out.instances == s.id].any():
                on_chairs += 1
                assert s.cls != "chair"
    assert on_chairs > 20


# ---------------------------------------------------------------------------------- errors
@pytest.mark.parametrize(
    "rgb, depth, semantic, match",
    [
        (RGB.astype(np.float32), None, None, "rgb must be uint8"),
        (RGB[..., 0], None, None, r"rgb must be an \(H, W, 3\)"),
        (RGB, np.zeros((H, W), np.int32), None, "depth must be a float"),
        (RGB, np.zeros((H, W + 1), np.float32), None, r"depth must be an \(120, 160\)"),
        (RGB, None, "none", "needs the semantic frame"),
        (RGB, None, np.zeros((H, W), np.int32), r"semantic must be an \(120, 160, 2\)"),
        (RGB, None, np.zeros((H, W, 2), np.float32), "semantic must be an integer"),
        (RGB, None, np.full((H, W, 2), -1, np.int32), ">= 0"),
        (RGB, None, np.full((H, W, 2), 99, np.int32), "out of range"),
    ],
)
def test_bad_input_raises_one_line_value_error(rgb, depth, semantic, match):
    depth = np.full((H, W), 2.0, np.float32) if depth is None else depth
    semantic = None if isinstance(semantic, str) else (
        np.zeros((H, W, 2), np.int32) if semantic is None else semantic)
    for preset in ("clean", "default"):
        with pytest.raises(ValueError, match=match) as e:
            make_segmenter(preset)(rgb, depth, semantic)
        assert "\n" not in str(e.value)


def test_unknown_segmenter_and_bad_noise():
    with pytest.raises(KgnavError, match=r"unknown segmenter 'rednet' \(known: clean, default"):
        make_segmenter("rednet")
    with pytest.raises(ValueError, match="miss"):
        SegmenterNoise(miss=-0.1)
    with pytest.raises(ValueError, match="probability"):
        SegmenterNoise(confusion=1.5)
    with pytest.raises(ValueError, match="far"):
        SegmenterNoise(near=3.0, far=2.0)
