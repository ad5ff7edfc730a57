"""The learned encoder: shipped weights, features, weight-file errors, reproducible training,
resume, and the train-encoder command."""

from __future__ import annotations

import json
import subprocess
import sys
import zipfile

import numpy as np
import pytest
import torch

from kgnav.agent.features import make_extractor
from kgnav.nets.encoder import EncoderWeightsError, LearnedEncoder, load_weights
from kgnav.nets.encoder.train import TrainConfig, Trainer
from kgnav.nets.encoder.views import ViewSampler
from kgnav.nets.encoder.weights import DEFAULT_WEIGHTS, FORMAT, META_KEY, VERSION
from kgnav.sim.episodes import load_scene_of

# a tiny network and batch: training tests check mechanics, not quality
TINY = dict(dim=8, channels=(4, 8), input_size=(40, 30), houses_per_batch=2, places_per_house=2,
            n_houses=2, warmup=1)


@pytest.fixture(scope="module")
def encoder() -> LearnedEncoder:
    return make_extractor("kgnav-encoder", device="cpu")


@pytest.fixture(scope="module")
def val_views():
    return ViewSampler([load_scene_of("val", k) for k in range(3)])


# ---------------------------------------------------------------------- shipped weights
def test_shipped_weights_are_small_and_described():
    assert DEFAULT_WEIGHTS.is_file()
    assert DEFAULT_WEIGHTS.stat().st_size < 4 << 20
    w = load_weights()
    m = w.meta
    assert m["format"] == FORMAT and m["version"] == VERSION
    assert m["arch"]["dim"] == w.arch.dim and len(m["arch"]["input_size"]) == 2
    assert 0 < m["threshold"] < 1 and "calibrated" in m["threshold_source"]
    train = m["train"]
    assert train["complete"] and train["train_steps"] == train["steps"]
    assert isinstance(train["seed"], int) and train["objective"] == "contrastive"


def test_make_extractor_imports_the_plugin_lazily():
    code = ("import sys; from kgnav.agent.features import make_extractor; "
            "assert 'kgnav.nets.encoder' not in sys.modules; "
            "e = make_extractor('kgnav-encoder', device='cpu'); print(e.name, e.dim, e.threshold)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    name, dim, thr = out.stdout.split()
    assert name == "kgnav-encoder" and int(dim) == load_weights().arch.dim
    assert float(thr) == pytest.approx(load_weights().threshold)


def test_features_unit_norm_deterministic(encoder, val_views):
    rng = np.random.default_rng(0)
    frames = np.stack([val_views.render(0, val_views.random_pose(0, rng)) for _ in range(5)])
    f = encoder(frames[0])
    assert f.shape == (encoder.dim,) and f.dtype == np.float32
    assert np.linalg.norm(f) == pytest.approx(1.0, abs=1e-5)
    assert np.array_equal(f, encoder(frames[0].copy()))
    again = make_extractor("kgnav-encoder", device="cpu")
    assert np.array_equal(f, again(frames[0]))
    b = encoder.batch(frames)
    assert b.shape == (5, encoder.dim) and b.dtype == np.float32
    np.testing.assert_allclose(b, np.stack([encoder(x) for x in frames]), atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(b, axis=1), 1.0, atol=1e-5)
    blank = encoder(np.zeros((120, 160, 3), np.uint8))
    assert np.linalg.norm(blank) == pytest.approx(1.0, abs=1e-5)
    assert encoder(np.zeros((60, 80, 3), np.uint8)).shape == (encoder.dim,)  # any frame size
    with pytest.raises(ValueError, match="RGB uint8"):
        encoder(np.zeros((120, 160), np.uint8))
    with pytest.raises(ValueError, match="RGB uint8"):
        encoder.batch(np.zeros((2, 120, 160, 3), np.float32))


def test_same_place_is_closer_than_other_houses(encoder, val_views):
    """Each anchor's view from (nearly) the same place beats every view of the other houses."""
    rng = np.random.default_rng(5)
    anchors, positives, others = [], [], []
    for h in range(3):
        for _ in range(4):
            a = val_views.random_pose(h, rng)
            b = val_views.pose_near(h, a, rng, dist=(0.0, 0.25), turn=(0.0, np.radians(10)))
            anchors.append((h, encoder(val_views.render(h, a))))
            positives.append(encoder(val_views.render(h, b or a)))
            others.append((h, encoder(val_views.render(h, val_views.random_pose(h, rng)))))
    wins = 0
    for (h, fa), fp in zip(anchors, positives, strict=True):
        d_pos = 1 - float(fa @ fp)
        d_other = min(1 - float(fa @ fo) for ho, fo in others if ho != h)
        wins += d_pos < d_other
    assert wins >= 11, wins
    d_pos = np.mean([1 - float(a @ p) for (_, a), p in zip(anchors, positives, strict=True)])
    d_other = [1 - float(fa @ fo) for h, fa in anchors for ho, fo in others if ho != h]
    assert d_pos < 0.2 * np.mean(d_other)
    assert min(d_other) > encoder.threshold  # no view of another house matches


# ---------------------------------------------------------------------- weight-file errors
def _copy(tmp_path, name="w.npz"):
    p = tmp_path / name
    p.write_bytes(DEFAULT_WEIGHTS.read_bytes())
    return p


def _rewrite(src, dst, meta=None, drop=(), change=None):
    with np.load(src) as z:
        arrays = {k: z[k] for k in z.files if k not in drop}
    if meta is not None:
        arrays[META_KEY] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    if change:
        arrays.update(change)
    with open(dst, "wb") as fh:
        np.savez(fh, **arrays)
    return dst


def _meta():
    return dict(load_weights().meta)


@pytest.mark.parametrize("case", ["truncated", "garbage", "empty", "npy", "no-meta", "bad-json",
                                  "format", "version", "shape", "missing", "nan", "threshold",
                                  "missing-file", "bad-member"])
def test_bad_weight_files_raise_weights_error(tmp_path, case):
    good = _copy(tmp_path, "good.npz")
    bad = tmp_path / f"{case}.npz"
    first = load_weights(good).params
    name = next(iter(first))
    if case == "truncated":
        bad.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    elif case == "garbage":
        bad.write_bytes(b"\x00not a weight file" * 100)
    elif case == "empty":
        bad.write_bytes(b"")
    elif case == "npy":
        with open(bad, "wb") as fh:
            np.save(fh, np.zeros(3))
    elif case == "no-meta":
        _rewrite(good, bad, drop=(META_KEY,))
    elif case == "bad-json":
        _rewrite(good, bad, change={META_KEY: np.frombuffer(b"{not json", np.uint8)})
    elif case == "format":
        _rewrite(good, bad, meta={**_meta(), "format": "something-else"})
    elif case == "version":
        _rewrite(good, bad, meta={**_meta(), "version": VERSION + 1})
    elif case == "shape":
        _rewrite(good, bad, change={name: np.zeros((1, 2), np.float32)})
    elif case == "missing":
        _rewrite(good, bad, drop=(name,))
    elif case == "nan":
        _rewrite(good, bad, change={name: np.full_like(first[name], np.nan)})
    elif case == "threshold":
        _rewrite(good, bad, meta={**_meta(), "threshold": "0.2"})
    elif case == "missing-file":
        bad = tmp_path / "nowhere.npz"
    elif case == "bad-member":  # a zip whose member is not an array
        with zipfile.ZipFile(bad, "w") as zf:
            zf.writestr(f"{META_KEY}.npy", b"garbage")
    with pytest.raises(EncoderWeightsError) as exc:
        load_weights(bad)
    assert str(bad) in str(exc.value) and exc.value.path == str(bad)
    assert "\n" not in str(exc.value)
    with pytest.raises(EncoderWeightsError):
        make_extractor("kgnav-encoder", weights=bad, device="cpu")


def test_weights_roundtrip(tmp_path):
    w = load_weights()
    p = w.save(tmp_path / "sub" / "copy.npz")
    w2 = load_weights(p)
    assert w2.arch == w.arch and w2.meta == w.meta
    for k, v in w.params.items():
        assert np.array_equal(v, w2.params[k])


# ---------------------------------------------------------------------- training
def _params(trainer: Trainer) -> dict[str, np.ndarray]:
    return trainer.export().params


def test_training_is_reproducible_from_a_seed():
    a = _params(Trainer(TrainConfig(seed=3, steps=2, **TINY)).fit())
    b = _params(Trainer(TrainConfig(seed=3, steps=2, **TINY)).fit())
    c = _params(Trainer(TrainConfig(seed=4, steps=2, **TINY)).fit())
    assert all(np.array_equal(a[k], b[k]) for k in a)
    assert not all(np.array_equal(a[k], c[k]) for k in a)


def test_autoencoder_objective_trains():
    t = Trainer(TrainConfig(seed=0, steps=1, objective="autoencoder", **TINY)).fit()
    assert t.step == 1 and np.isfinite(t.last_loss)


def test_resume_equals_an_uninterrupted_run(tmp_path):
    cfg = TrainConfig(seed=1, steps=4, **TINY)
    full = Trainer(cfg).fit()
    part = Trainer(cfg)
    part.train_step()
    part.train_step()
    ckpt = part.save_checkpoint(tmp_path / "run.ckpt")
    resumed = Trainer(cfg).load_checkpoint(ckpt)
    assert resumed.step == 2
    resumed.fit(checkpoint=ckpt)
    assert resumed.step == 4 and resumed.done
    a, b = _params(full), _params(resumed)
    assert all(np.array_equal(a[k], b[k]) for k in a)
    with pytest.raises(EncoderWeightsError, match="another run"):
        Trainer(TrainConfig(seed=2, steps=4, **TINY)).load_checkpoint(ckpt)
    (tmp_path / "junk.ckpt").write_bytes(b"junk")
    with pytest.raises(EncoderWeightsError, match="junk.ckpt"):
        Trainer(cfg).load_checkpoint(tmp_path / "junk.ckpt")


def test_exported_weights_match_the_training_network():
    t = Trainer(TrainConfig(seed=0, steps=2, **TINY)).fit()
    frames, _, _ = t.batch(0)
    from kgnav.nets.encoder.net import to_tensor

    t.net.eval()
    with torch.no_grad():
        ref = torch.nn.functional.normalize(t.net(to_tensor(frames)), dim=1).numpy()
    enc = LearnedEncoder(t.export(), device="cpu")
    np.testing.assert_allclose(enc.batch(frames), ref, atol=1e-5)


# ---------------------------------------------------------------------- the command
SMALL = ("--dim", "8", "--houses-per-batch", "2", "--places-per-house", "2", "--quiet",
         "--calibrate-pairs", "0")


def test_train_encoder_cli_resume_and_reproducibility(tmp_path, cli):
    full = tmp_path / "full.npz"
    code, out, err = cli("train-encoder", "--out", full, "--steps", "3", "--seed", "2", *SMALL)
    assert code == 0, err
    assert "done at step 3/3" in out
    assert (tmp_path / "full.ckpt").is_file()
    # interrupted by a time budget shorter than one step, then resumed
    part = tmp_path / "part.npz"
    code, out, err = cli("train-encoder", "--out", part, "--steps", "3", "--seed", "2",
                         "--time-budget", "0.00001", *SMALL)
    assert code == 0, err
    assert "stopped by --time-budget at step 1/3" in out and "--resume" in err
    w = load_weights(part)
    assert w.meta["train"]["train_steps"] == 1 and not w.meta["train"]["complete"]
    code, out, err = cli("train-encoder", "--out", part, "--steps", "3", "--seed", "2",
                         "--resume", *SMALL)
    assert code == 0, err
    assert "resuming" in err and "done at step 3/3" in out
    a, b = load_weights(full), load_weights(part)
    assert all(np.array_equal(a.params[k], b.params[k]) for k in a.params)
    assert b.meta["train"]["seed"] == 2 and b.meta["train"]["train_steps"] == 3
    assert b.threshold == 0.3  # not calibrated: the paper's default
    # resuming with another seed is a data error (exit 1), one line
    code, _, err = cli("train-encoder", "--out", part, "--steps", "3", "--seed", "9",
                       "--resume", *SMALL)
    assert code == 1 and err.count("\n") == 1 and "another run" in err


def test_train_encoder_calibrates_the_threshold(tmp_path, cli):
    out_path = tmp_path / "w.npz"
    args = [a for a in SMALL if a not in ("--calibrate-pairs", "0")]
    code, out, err = cli("train-encoder", "--out", out_path, "--steps", "1",
                         "--calibrate-pairs", "11", *args)
    assert code == 0, err
    w = load_weights(out_path)
    assert "calibrated" in w.meta["threshold_source"] and 0 < w.threshold <= 2


@pytest.mark.parametrize("args", [
    ("--steps", "0"),
    ("--dim", "0"),
    ("--dim", "x"),
    ("--time-budget", "-1"),
    ("--time-budget", "0"),
    ("--device", "tpu"),
    ("--objective", "magic"),
    ("--resume",),
    ("--seed", "-1"),
])
def test_train_encoder_bad_arguments_exit_2_one_line(tmp_path, cli, args):
    code, _, err = cli("train-encoder", "--out", tmp_path / "w.npz", *args)
    assert code == 2, err
    assert err.count("\n") == 1 and err.startswith("kgnav: usage error")
    assert not (tmp_path / "w.npz").exists()


@pytest.mark.parametrize("args", [(), ("--out",)])
def test_train_encoder_needs_out(cli, args):
    code, _, err = cli("train-encoder", *args)
    assert code == 2 and err.count("\n") == 1 and "--out" in err


def test_train_encoder_out_is_a_directory(tmp_path, cli):
    code, _, err = cli("train-encoder", "--out", tmp_path, "--steps", "1")
    assert code == 2 and err.count("\n") == 1 and "directory" in err


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the no-GPU message")
def test_cuda_without_gpu_is_a_usage_error(tmp_path, cli):
    code, _, err = cli("train-encoder", "--out", tmp_path / "w.npz", "--device", "cuda")
    assert code == 2 and "CUDA" in err and err.count("\n") == 1
