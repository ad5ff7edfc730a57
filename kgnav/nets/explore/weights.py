"""The exploration policy's weight files (``kgnav/weights/explore.npz`` for ``ppo``,
``explore-semantic.npz`` for ``ppo-semantic``): arrays + JSON metadata.

The format is :mod:`kgnav.nets.weights`' (no pickle): one float32 array per parameter of
:class:`~kgnav.nets.explore.net.ExploreNet` (names as in its state dict) and ``__meta__``::

    {"format": "kgnav-explore-weights", "version": 1,
     "arch": {"local_cells": 240, "wide_cells": 960, "input_size": 60, "semantic": false, ...},
     "train": {"seed": 0, "steps": ..., "threads": 1, "curve": {...}, ...}}

Every way a file can be wrong raises :class:`PolicyWeightsError` naming the file and the reason
in one line.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import ClassVar

from kgnav.nets.explore.net import ExploreArch, ExploreNet
from kgnav.nets.weights import SHIPPED, NetWeights, WeightsError, read_npz

FORMAT = "kgnav-explore-weights"
VERSION = 1
_DIR = SHIPPED
#: The shipped weights of each learned policy.
DEFAULT_WEIGHTS = {"ppo": _DIR / "explore.npz", "ppo-semantic": _DIR / "explore-semantic.npz"}


class PolicyWeightsError(WeightsError):
    """An exploration-policy weight file cannot be used: missing, corrupt, foreign or of another
    version, or of the other variant."""


class PolicyWeights(NetWeights):
    """The content of a weight file: architecture, parameter arrays, metadata."""

    arch: ExploreArch
    FORMAT: ClassVar[str] = FORMAT
    VERSION: ClassVar[int] = VERSION


def expected_shapes(arch: ExploreArch | dict) -> dict[str, tuple[int, ...]]:
    """Parameter name → shape of the network of ``arch`` (refusing absurd sizes, so a hostile
    record cannot make the reader allocate gigabytes)."""
    if not isinstance(arch, ExploreArch):
        if not isinstance(arch, dict):
            raise ValueError("not a record")
        arch = ExploreArch.from_dict(arch)
    sizes = (*arch.channels, arch.hidden, arch.input_size)
    cells = (arch.local_cells, arch.wide_cells)
    if (not isinstance(arch.semantic, bool)
            or not all(isinstance(v, int) and 1 <= v <= 1024 for v in sizes)
            or not all(isinstance(v, int) and 1 <= v <= 8192 for v in cells)):
        raise ValueError("sizes out of range")
    return {k: tuple(v.shape) for k, v in ExploreNet(arch).state_dict().items()}


def load_weights(path: str | os.PathLike[str] | None = None, *,
                 semantic: bool | None = None) -> PolicyWeights:
    """Read and validate a weight file (default: the shipped ``ppo`` weights, or the
    ``ppo-semantic`` ones with ``semantic=True``). ``semantic`` also checks the file's kind."""
    if path is None:
        path = DEFAULT_WEIGHTS["ppo-semantic" if semantic else "ppo"]
        if not path.exists():  # ppo-semantic is not shipped: it is trained on demand
            raise PolicyWeightsError(path, "not shipped; train it first: kgnav train-policy "
                                     "--policy ppo-semantic --out " + str(path))
    path = Path(path)
    meta, params = read_npz(path, fmt=FORMAT, version=VERSION,
                            what="kgnav exploration-policy weight file",
                            error=PolicyWeightsError, shapes=expected_shapes)
    arch = ExploreArch.from_dict(meta["arch"])
    if semantic is not None and arch.semantic != semantic:
        want, got = ("ppo-semantic", "ppo") if semantic else ("ppo", "ppo-semantic")
        raise PolicyWeightsError(path, f"weights of a {got} policy, not {want}")
    return PolicyWeights(arch, params, meta)
