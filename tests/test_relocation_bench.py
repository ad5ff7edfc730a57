"""The relocation benchmark: pair definitions, calibration, metrics, and the command."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from kgnav.agent.features import make_extractor
from kgnav.nets.encoder.calibration import (
    KINDS,
    at_threshold,
    build_pairs,
    calibrate,
    evaluate,
    roc_points,
)
from kgnav.nets.encoder.views import (
    AMBIGUOUS,
    NEGATIVE,
    POSITIVE,
    ViewSampler,
    relation,
    relation_matrix,
    relations,
)
from kgnav.nets.encoder.weights import DEFAULT_WEIGHTS, load_weights
from kgnav.sim.episodes import load_scene_of


# ---------------------------------------------------------------------- definitions
@pytest.mark.parametrize("b, expect", [
    ((0, 0.4, 0.0, 0.0), POSITIVE),
    ((0, 0.0, 0.0, math.radians(29)), POSITIVE),
    ((0, 0.0, 0.0, math.radians(-29) + 2 * math.pi), POSITIVE),  # headings wrap
    ((0, 0.7, 0.0, 0.0), AMBIGUOUS),
    ((0, 0.0, 0.0, math.radians(60)), AMBIGUOUS),
    ((0, 1.2, 0.0, 0.0), NEGATIVE),
    ((0, 0.0, 0.0, math.radians(120)), NEGATIVE),
    ((1, 0.0, 0.0, 0.0), NEGATIVE),  # another house, same coordinates
])
def test_relation(b, expect):
    assert relation(0, (0.0, 0.0, 0.0), b[0], b[1:]) == expect


def test_relation_matrix_is_symmetric():
    rng = np.random.default_rng(0)
    houses = rng.integers(0, 2, 30)
    poses = np.c_[rng.uniform(0, 2, (30, 2)), rng.uniform(-math.pi, math.pi, 30)]
    r = relation_matrix(houses, poses)
    assert np.array_equal(r, r.T) and (np.diag(r) == POSITIVE).all()
    for i, j in [(0, 1), (3, 7), (10, 29)]:
        assert r[i, j] == relation(houses[i], poses[i], houses[j], poses[j])


# ---------------------------------------------------------------------- calibration, metrics
def test_calibrate_picks_the_largest_threshold_with_enough_precision():
    rng = np.random.default_rng(1)
    dist = np.r_[rng.uniform(0, 0.5, 300), rng.uniform(0.2, 1.5, 900)]
    labels = np.r_[np.ones(300, int), np.zeros(900, int)]
    for target in (0.9, 0.99):
        t = calibrate(dist, labels, target)
        assert at_threshold(dist, labels, t)["precision"] >= target
        # any larger cut through the data drops below the target
        bigger = np.sort(dist[dist >= t])
        for b in bigger[:50]:
            assert at_threshold(dist, labels, b + 1e-9)["precision"] < target or b > 0.5
    assert calibrate(np.array([0.1, 0.2]), np.array([0, 1]), 0.99) < 0.1  # nothing qualifies


def test_at_threshold_and_roc():
    dist = np.array([0.1, 0.2, 0.3, 0.4, 0.5])
    labels = np.array([1, 1, 0, 1, 0])
    r = at_threshold(dist, labels, 0.35)
    assert r == {"precision": 2 / 3, "recall": 2 / 3, "fpr": 0.5, "matches": 3}
    roc = np.array(roc_points(dist, labels))
    assert roc.shape[1] == 3
    assert roc[0, :2].tolist() == [0.0, 0.0] and roc[-1, :2].tolist() == [1.0, 1.0]
    assert (np.diff(roc[:, 0]) >= 0).all() and (np.diff(roc[:, 1]) >= 0).all()
    assert (np.diff(roc[:, 2]) > 0).all()
    for fpr, tpr, thr in roc:  # each point is "match = distance < threshold"
        assert at_threshold(dist, labels, thr)["recall"] == pytest.approx(tpr, abs=1e-6)
        assert at_threshold(dist, labels, thr)["fpr"] == pytest.approx(fpr, abs=1e-6)


# ---------------------------------------------------------------------- pairs
@pytest.fixture(scope="module")
def pairset():
    sampler = ViewSampler([load_scene_of("val", k) for k in range(4)])
    exts = [make_extractor("kgnav-encoder", device="cpu"), make_extractor("opencv-gist")]
    return build_pairs(sampler, exts, n_pos=16, seed=3)


def test_pairs_are_what_they_claim(pairset):
    ps = pairset
    a, b = ps.pairs[:, 0], ps.pairs[:, 1]
    rel = relations(ps.houses[a], ps.poses[a], ps.houses[b], ps.poses[b])
    assert (rel[ps.kinds == 0] == POSITIVE).all()
    assert (rel[ps.kinds > 0] == NEGATIVE).all()
    counts = ps.counts()
    assert set(counts) == set(KINDS) and counts["positive"] == 16
    assert counts["other-house"] == 32 and counts["other-house look-alike"] == 32
    same = ps.houses[a] == ps.houses[b]
    assert same[ps.kinds <= 2].all() and not same[ps.kinds >= 3].any()
    for name, f in ps.features.items():
        np.testing.assert_allclose(np.linalg.norm(f, axis=1), 1.0, atol=1e-5, err_msg=name)


def test_pairs_are_reproducible(pairset):
    sampler = ViewSampler([load_scene_of("val", k) for k in range(4)])
    again = build_pairs(sampler, [make_extractor("opencv-gist")], n_pos=16, seed=3)
    assert np.array_equal(again.pairs, pairset.pairs)
    assert np.array_equal(again.features["opencv-gist"], pairset.features["opencv-gist"])


def test_evaluate_reports_everything(pairset):
    r = evaluate(pairset, "kgnav-encoder", threshold=0.2, threshold_source="test")
    assert r["threshold"] == 0.2 and r["threshold_source"] == "test"
    for key in ("precision", "recall", "fpr", "auc", "calibrated_threshold"):
        assert 0 <= r[key] <= 2, key
    assert set(r["fpr_by_kind"]) == set(KINDS[1:])
    assert r["retrieval"]["queries"] == 16 and r["retrieval"]["store"] == 32
    assert r["auc"] > 0.5


# ---------------------------------------------------------------------- the command
def test_relocation_bench_writes_json_and_png(tmp_path, cli):
    out_dir = tmp_path / "bench"
    code, out, err = cli("relocation-bench", "--split", "val", "--out", out_dir, "--pairs", "11",
                         "--seed", "4", "--quiet", "--threshold", "opencv-gist=0.25")
    assert code == 0, err
    rep = json.loads((out_dir / "relocation.json").read_text())
    assert rep["split"] == "val" and rep["places"] == 11 and len(rep["houses"]) == 11
    assert rep["pairs"]["positive"] == 11
    assert set(rep["extractors"]) == {"kgnav-encoder", "opencv-gist"}
    enc = rep["extractors"]["kgnav-encoder"]
    assert enc["threshold"] == pytest.approx(load_weights().threshold, abs=1e-6)
    assert rep["extractors"]["opencv-gist"]["threshold"] == 0.25
    for r in rep["extractors"].values():
        for key in ("threshold", "precision", "recall", "roc", "auc", "calibrated_threshold",
                    "retrieval", "dim"):
            assert key in r
        assert all(len(p) == 3 for p in r["roc"])
    png = (out_dir / "relocation_roc.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000
    assert "kgnav-encoder" in out


def test_relocation_bench_write_threshold(tmp_path, cli):
    weights = tmp_path / "w.npz"
    weights.write_bytes(DEFAULT_WEIGHTS.read_bytes())
    code, _, err = cli("relocation-bench", "--out", tmp_path / "o", "--pairs", "11", "--quiet",
                       "--extractors", "kgnav-encoder", "--weights", weights,
                       "--write-threshold", "--seed", "5")
    assert code == 0, err
    rep = json.loads((tmp_path / "o" / "relocation.json").read_text())
    assert load_weights(weights).threshold == pytest.approx(
        rep["extractors"]["kgnav-encoder"]["calibrated_threshold"], abs=1e-6)
    assert "seed 5" in load_weights(weights).meta["threshold_source"]


def test_relocation_bench_write_loop_threshold(tmp_path, cli):
    """--write-loop-threshold stores the calibration as the threshold the agent relocates with
    and leaves the match threshold alone; LearnedEncoder relocates at it."""
    from kgnav.nets.encoder.extractor import LearnedEncoder

    weights = tmp_path / "w.npz"
    weights.write_bytes(DEFAULT_WEIGHTS.read_bytes())
    before = load_weights(weights).threshold
    code, _, err = cli("relocation-bench", "--out", tmp_path / "o", "--pairs", "11", "--quiet",
                       "--extractors", "kgnav-encoder", "--weights", weights,
                       "--target-precision", "0.5", "--write-loop-threshold", "--seed", "5")
    assert code == 0, err
    rep = json.loads((tmp_path / "o" / "relocation.json").read_text())
    cal = rep["extractors"]["kgnav-encoder"]["calibrated_threshold"]
    w = load_weights(weights)
    assert w.threshold == before
    assert w.meta["loop_threshold"] == pytest.approx(cal, abs=1e-6)
    assert "precision >= 0.5" in w.meta["loop_threshold_source"]
    assert LearnedEncoder(weights, device="cpu").loop_threshold == pytest.approx(cal, abs=1e-6)


@pytest.mark.parametrize("args", [
    ("--pairs", "0"),
    ("--pairs", "many"),
    ("--split", "test"),
    ("--extractors", "nope"),
    ("--extractors", ","),
    ("--extractors", "opencv-gist,opencv-gist"),
    ("--threshold", "opencv-gist"),
    ("--threshold", "opencv-gist=3"),
    ("--threshold", "kgnav-encoder=0.2", "--extractors", "opencv-gist"),
    ("--write-threshold",),
    ("--write-loop-threshold",),
    ("--target-precision", "0"),
    ("--device", "tpu"),
])
def test_relocation_bench_bad_arguments_exit_2_one_line(tmp_path, cli, args):
    code, _, err = cli("relocation-bench", "--out", tmp_path / "o", *args)
    assert code == 2, err
    assert err.count("\n") == 1 and err.startswith("kgnav: usage error")
    assert not (tmp_path / "o").exists()


def test_relocation_bench_out_is_a_file(tmp_path, cli):
    f = tmp_path / "file"
    f.write_text("x")
    code, _, err = cli("relocation-bench", "--out", f, "--pairs", "2")
    assert code == 2 and err.count("\n") == 1


def test_relocation_bench_corrupt_weights_exit_1_one_line(tmp_path, cli):
    bad = tmp_path / "bad.npz"
    bad.write_bytes(DEFAULT_WEIGHTS.read_bytes()[:1000])
    code, _, err = cli("relocation-bench", "--out", tmp_path / "o", "--weights", bad)
    assert code == 1 and err.count("\n") == 1 and str(bad) in err
    code, _, err = cli("relocation-bench", "--out", tmp_path / "o", "--weights",
                       tmp_path / "missing.npz")
    assert code == 1 and "no such file" in err
