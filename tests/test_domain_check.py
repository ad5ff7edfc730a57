"""The domain check (kgnav.nets.domain): learned weights record the environment they were
trained on, and ``kgnav eval --env X`` refuses segmenter or encoder weights made for another
one, in one line that says how to get weights for X, unless ``--allow-domain-mismatch``.

The other environment is the numpy grid room of tests/test_envs.py (no OpenGL needed).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from kgnav.benchmark.runner import EvalConfig, run_eval
from kgnav.envs import ENVS, register_env
from kgnav.nets.domain import DomainMismatchError, check_domain, same_env, weights_env
from kgnav.nets.encoder import weights as encoder_weights
from kgnav.nets.segnet import weights as segmenter_weights
from kgnav.nets.segnet.train import SegTrainConfig, SegTrainer
from tests.test_envs import CLASSES, GridSuite

GRID = "tests.test_envs:GridSuite"
TINY = dict(batch=2, warmup=1, input_size=(40, 30), stem=4, channels=(4, 8, 8),
            depth_channels=(4, 8, 8))


@pytest.fixture(scope="module", autouse=True)
def registered():
    register_env("grid-domain")(GridSuite)
    yield
    ENVS.pop("grid-domain", None)


@pytest.fixture(scope="module")
def grid_segmenter(tmp_path_factory):
    """Segmenter weights trained (two steps) on the grid rooms' walked frames."""
    cfg = SegTrainConfig(seed=0, steps=2, split="any", n_houses=2, env=GRID, classes=CLASSES,
                         walk_steps=20, **TINY)
    path = tmp_path_factory.mktemp("seg") / "grid.npz"
    SegTrainer(cfg).fit().export().save(path)
    return path


def _retagged(tmp_path, module, env: str | None, name: str):
    """The shipped weights of ``module`` with their domain record set to ``env``."""
    w = module.load_weights()
    if env is not None:
        w.meta["domain"] = {"env": env, "train_split": "train"}
    return w.save(tmp_path / name)


def _one_line(err: str) -> str:
    assert err.count("\n") == 1, err
    return err.strip()


# ---------------------------------------------------------------------- what weights record
def test_shipped_weights_count_as_trained_on_kgnav():
    for module in (segmenter_weights, encoder_weights):
        w = module.load_weights()
        # older weights predate the record; newer ones name kgnav (and their houses)
        assert w.meta.get("domain", {}).get("env", "kgnav") == "kgnav"
        assert weights_env(w.meta) == "kgnav"
        check_domain("segmenter", module.DEFAULT_WEIGHTS, w.meta, "kgnav")  # no error
    assert weights_env({"domain": {"env": ""}}) == "kgnav"
    assert weights_env({"domain": "miniworld"}) == "kgnav"  # not a record: no env named


def test_segmenter_weights_record_environment_and_vocabulary(grid_segmenter):
    w = segmenter_weights.load_weights(grid_segmenter)
    assert w.classes == CLASSES and w.arch.n_classes == len(CLASSES) + 1
    assert w.meta["domain"] == {"env": GRID, "train_split": "any", "scenes": 2,
                                "walk_steps": 20}
    assert weights_env(w.meta) == GRID


def test_a_name_and_its_module_path_are_one_environment():
    assert same_env(GRID, GRID) and same_env("grid-domain", GRID)
    assert not same_env("kgnav", GRID) and not same_env("nope", GRID)


def test_the_check_says_where_the_weights_belong_and_how_to_fix_it():
    with pytest.raises(DomainMismatchError) as e:
        check_domain("encoder", "e.npz", {"domain": {"env": "miniworld"}}, "kgnav")
    msg = str(e.value)
    assert "\n" not in msg
    assert msg.startswith("encoder weights e.npz were trained on environment 'miniworld', "
                          "not 'kgnav'")
    assert "kgnav train-encoder --env kgnav" in msg and "--encoder-weights FILE" in msg
    assert "--allow-domain-mismatch" in msg


# ---------------------------------------------------------------------- kgnav eval refuses
def test_eval_refuses_the_shipped_segmenter_on_another_environment(cli, tmp_path):
    code, _out, err = cli("eval", "--env", GRID, "--out", tmp_path / "ev", "--quiet")
    line = _one_line(err)
    assert code == 1
    assert "segmenter weights" in line and "segmenter.npz" in line
    assert f"trained on environment 'kgnav', not '{GRID}'" in line
    assert f"kgnav train-segmenter --env {GRID}" in line and "--segmenter-weights FILE" in line
    assert not (tmp_path / "ev" / "episodes.jsonl").exists()


def test_eval_refuses_the_shipped_encoder_on_another_environment(cli, tmp_path):
    code, _out, err = cli("eval", "--env", GRID, "--segmenter", "clean", "--out",
                          tmp_path / "ev", "--quiet")
    line = _one_line(err)
    assert code == 1 and "encoder weights" in line and "encoder.npz" in line
    assert f"kgnav train-encoder --env {GRID}" in line and "--encoder-weights FILE" in line


def test_eval_refuses_weights_of_another_environment_on_kgnav(cli, tmp_path, grid_segmenter):
    code, _out, err = cli("eval", "--segmenter-weights", grid_segmenter, "--out",
                          tmp_path / "ev", "--quiet")
    line = _one_line(err)
    assert code == 1 and f"trained on environment '{GRID}', not 'kgnav'" in line
    enc = _retagged(tmp_path, encoder_weights, "miniworld", "enc.npz")
    code, _out, err = cli("eval", "--segmenter", "clean", "--encoder-weights", enc, "--out",
                          tmp_path / "ev", "--quiet")
    line = _one_line(err)
    assert code == 1 and "encoder weights" in line and "'miniworld', not 'kgnav'" in line


def test_eval_takes_matching_weights_and_records_them(tmp_path, grid_segmenter):
    """Segmenter weights of the grid rooms run there (features that need no weights); the
    registered name of the environment matches weights tagged by its module path."""
    cfg = EvalConfig(env="grid-domain", variants=("ans",), segmenter_weights=str(grid_segmenter),
                     extractor="opencv-gist", max_steps=15, episodes=1, scenes=1)
    records, _summary = run_eval(cfg, tmp_path / "ev", progress=False)
    assert len(records) == 1 and records[0]["steps"] >= 1
    config = json.loads((tmp_path / "ev" / "config.json").read_text())
    assert config["segmenter_weights"] == str(grid_segmenter)
    assert config["allow_domain_mismatch"] is False


def test_allow_domain_mismatch_runs_them_anyway(cli, tmp_path):
    out = tmp_path / "ev"
    code, _out, err = cli("eval", "--env", GRID, "--segmenter", "clean", "--scenes", "1",
                          "--episodes", "1", "--allow-domain-mismatch", "--out", out, "--quiet")
    assert code == 0, err
    assert json.loads((out / "config.json").read_text())["allow_domain_mismatch"] is True
    kgnav_enc = _retagged(tmp_path, encoder_weights, "kgnav", "kgnav-enc.npz")
    cfg = EvalConfig(env="grid-domain", variants=("ans",), segmenter="clean",
                     encoder_weights=str(kgnav_enc), max_steps=5, episodes=1, scenes=1)
    with pytest.raises(DomainMismatchError):
        run_eval(cfg, None, progress=False)
    records, _ = run_eval(EvalConfig(**{**cfg.__dict__, "allow_domain_mismatch": True}), None,
                          progress=False)
    assert len(records) == 1


def test_noise_presets_and_other_features_are_not_checked(tmp_path):
    """Ground-truth segmenters and the OpenCV descriptor have no weights, so no domain."""
    cfg = EvalConfig(env="grid-domain", variants=("ans",), segmenter="clean",
                     extractor="opencv-gist", max_steps=5, episodes=1, scenes=1)
    records, _ = run_eval(cfg, None, progress=False)
    assert len(records) == 1 and np.isfinite(records[0]["steps"])


@pytest.mark.parametrize(("args", "code", "expected"), [
    (("--segmenter", "default", "--segmenter-weights", "W"), 2, "--segmenter-weights"),
    (("--segmenter-weights", "MISSING"), 1, "no such file"),
])
def test_bad_segmenter_weights_options_exit_in_one_line(cli, tmp_path, grid_segmenter, args,
                                                        code, expected):
    args = [str(grid_segmenter) if a == "W" else str(tmp_path / "none.npz") if a == "MISSING"
            else a for a in args]
    got, _out, err = cli("eval", *args, "--out", tmp_path / "ev", "--quiet")
    assert got == code and expected in _one_line(err)


# ---------------------------------------------------------------------- an environment's own
def test_an_environment_names_its_own_weights_and_a_run_uses_them(tmp_path, grid_segmenter,
                                                                    monkeypatch):
    from dataclasses import replace

    from kgnav.benchmark.runner import with_env_weights
    from kgnav.envs import env_weights

    assert env_weights(GRID) == {} and env_weights("kgnav") == {}
    cfg = EvalConfig(env=GRID, variants=("ans",), segmenter="learned", scenes=1, episodes=1,
                     extractor="opencv-gist")
    with pytest.raises(DomainMismatchError):  # kgnav's shipped segmenter on the grid rooms
        run_eval(cfg, None, progress=False)
    monkeypatch.setattr(GridSuite, "default_weights", {"segmenter": str(grid_segmenter)},
                        raising=False)
    assert env_weights(GRID) == {"segmenter": grid_segmenter}
    assert with_env_weights(cfg).segmenter_weights == str(grid_segmenter)
    mine = str(tmp_path / "mine.npz")
    assert with_env_weights(replace(cfg, segmenter_weights=mine)).segmenter_weights == mine
    assert with_env_weights(replace(cfg, segmenter="clean")).segmenter_weights is None
    _, summary = run_eval(cfg, None, progress=False)  # its own weights pass the check
    assert "ans" in summary


def test_miniworld_ships_and_names_a_segmenter_trained_on_its_frames():
    from kgnav.envs import env_weights  # the adapter imports MiniWorld only to render

    path = env_weights("miniworld")["segmenter"]
    w = segmenter_weights.load_weights(path)
    assert weights_env(w.meta) == "miniworld" and path.parent.name == "weights"
    check_domain("segmenter", path, w.meta, "miniworld")


def test_miniworld_ships_and_names_an_encoder_trained_on_its_frames():
    """MiniWorld's own encoder passes the domain check there, relocates at the loop threshold
    calibrated on MiniWorld's calib houses, and is another extractor than kgnav's."""
    from kgnav.benchmark.runner import with_env_weights
    from kgnav.envs import env_weights
    from kgnav.nets.encoder.extractor import NAME, LearnedEncoder

    path = env_weights("miniworld")["encoder"]
    w = encoder_weights.load_weights(path)
    assert weights_env(w.meta) == "miniworld" and path.parent.name == "weights"
    check_domain("encoder", path, w.meta, "miniworld")
    with pytest.raises(DomainMismatchError):
        check_domain("encoder", path, w.meta, "kgnav")
    assert "miniworld, split calib" in w.meta["loop_threshold_source"]
    enc = LearnedEncoder(path, device="cpu")
    assert enc.name.startswith(f"{NAME}:") and enc.loop_threshold == w.meta["loop_threshold"]
    cfg = EvalConfig(env="miniworld", variants=("si",))
    assert with_env_weights(cfg).encoder_weights == str(path)
