"""Shared fixtures: small seeded synthetic models (64-d features keep the suite fast)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import settings

from kgnav import AbstractModel, Detection
from kgnav.memory.synthetic import SyntheticWorld

DIM = 64


@pytest.fixture
def cli(capsys):
    """Run ``kgnav ARGS...`` in-process; returns (exit code, stdout, stderr)."""
    from kgnav.cli import main

    def run(*args):
        with pytest.raises(SystemExit) as exc:
            main([str(a) for a in args])
        out, err = capsys.readouterr()
        return exc.value.code, out, err

    return run


@pytest.fixture(scope="session")
def world() -> SyntheticWorld:
    return SyntheticWorld(seed=3, feature_dim=DIM)


@pytest.fixture
def episode_model(world) -> AbstractModel:
    return world.explore(80, episode=0, seed=11)


@pytest.fixture
def tiny() -> AbstractModel:
    """Three states in a row, a chair seen from all, a sofa from the last."""
    m = AbstractModel(feature_dim=4, model_id="tiny")
    feats = np.eye(4, dtype=np.float32)
    chair = Detection("chair", (2.0, 0.0, 0.5), (10, 20, 30, 40), 2.0, 400)
    s0 = m.add_state(feats[0], (0.0, 0.0, 0.0), [chair], episode=0, step=0)
    s1 = m.add_state(feats[1], (0.25, 0.0, 0.0), [chair], episode=0, step=1)
    s2 = m.add_state(
        feats[2], (0.25, 0.0, np.pi / 6), [chair, Detection("sofa", (1.0, 2.0, 0.4))], step=2
    )
    m.add_transition(s0, "move_forward", s1)
    m.add_transition(s1, "turn_left", s2)
    return m

# CI machines are slow and shared: property tests must not fail on wall-clock deadlines.
settings.register_profile("kgnav", deadline=None)
settings.load_profile("kgnav")
