"""Offline weight files of kgnav's networks: a numpy ``.npz`` of float32 arrays plus metadata.

No pickle anywhere (``allow_pickle=False``), so a weight file from elsewhere cannot run code.
Layout: one array per parameter of the inference network and ``__meta__``, the UTF-8 bytes of a
JSON object holding at least ``format``, ``version`` and ``arch``. :func:`read_npz` turns every
way a file can be wrong (missing, truncated, not an npz, another format or version, a bad
architecture record, missing or misshaped arrays, non-finite values) into one error naming the
file and the reason.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from kgnav.common.atomic import atomic_open
from kgnav.errors import KgnavError

#: Where the shipped weights lie (package data, ``kgnav/weights/``).
SHIPPED = Path(__file__).resolve().parents[1] / "weights"

META_KEY = "__meta__"


class WeightsError(KgnavError):
    """A weight file cannot be used; the message is ``"<path>: <reason>"`` on one line."""

    def __init__(self, path: str | os.PathLike[str], reason: str):
        self.path = os.fspath(path)
        self.reason = reason
        super().__init__(f"{self.path}: {reason}")


@dataclass
class NetWeights:
    """A weight file's content: architecture (with ``to_dict``), parameter arrays, metadata.
    Subclasses name their ``FORMAT`` and ``VERSION``."""

    arch: Any
    params: dict[str, np.ndarray]
    meta: dict = field(default_factory=dict)

    FORMAT: ClassVar[str] = "kgnav-weights"
    VERSION: ClassVar[int] = 1

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write atomically (a crash never leaves a half-written file at ``path``)."""
        meta = dict(self.meta, format=self.FORMAT, version=self.VERSION,
                    arch=self.arch.to_dict())
        return save_npz(path, self.params, meta)


def save_npz(path: str | os.PathLike[str], params: dict[str, np.ndarray], meta: dict) -> Path:
    """Write ``params`` (as float32) and ``meta`` atomically; readable by the user's group."""
    blob = np.frombuffer(json.dumps(meta, sort_keys=True).encode(), dtype=np.uint8)
    arrays = {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in params.items()}
    with atomic_open(path, "wb") as fh:
        np.savez(fh, **{META_KEY: blob}, **arrays)
    os.chmod(path, 0o644)  # the temporary file was private (0600); weights are shareable
    return Path(path)


def read_npz(path: str | os.PathLike[str], *, fmt: str, version: int, what: str,
             error: Callable[[str | os.PathLike[str], str], Exception],
             shapes: Callable[[dict], dict[str, tuple[int, ...]]]
             ) -> tuple[dict, dict[str, np.ndarray]]:
    """Read and validate a weight file: ``(meta, params)``.

    ``what`` names the kind of file in messages ("kgnav encoder weight file"); ``shapes(arch)``
    gives the expected parameter shapes of the metadata's ``arch`` record and raises on a bad
    record; ``error(path, reason)`` builds the exception raised.
    """
    path = Path(path)
    if not path.is_file():
        raise error(path, "no such file" if not path.exists() else "not a file")
    try:
        npz = np.load(path, allow_pickle=False)
    except Exception as exc:  # BadZipFile, ValueError, OSError, EOFError, ...: all "unreadable"
        raise error(path, f"not a {what} ({why(exc)})") from None
    if not hasattr(npz, "files"):  # a bare .npy array
        raise error(path, f"not a {what} (a single array)")
    with npz:
        if META_KEY not in npz.files:
            raise error(path, f"not a {what} (no metadata)")
        try:
            meta = json.loads(bytes(npz[META_KEY]).decode())
        except Exception as exc:
            raise error(path, f"corrupt metadata ({why(exc)})") from None
        if not isinstance(meta, dict) or meta.get("format") != fmt:
            got = meta.get("format") if isinstance(meta, dict) else type(meta).__name__
            raise error(path, f"not a {what} (format {got!r})")
        if meta.get("version") != version:
            raise error(path, f"weight format version {meta.get('version')!r}, this release "
                              f"reads {version}")
        try:
            expected = shapes(meta["arch"])
        except Exception as exc:
            raise error(path, f"bad architecture record ({why(exc)})") from None
        missing = sorted(set(expected) - set(npz.files))
        extra = sorted(set(npz.files) - set(expected) - {META_KEY})
        if missing or extra:
            raise error(path, f"parameters do not match the architecture "
                              f"(missing {missing}, unexpected {extra})")
        params = {}
        for name, shape in expected.items():
            try:
                a = np.asarray(npz[name])
            except Exception as exc:
                raise error(path, f"corrupt array {name!r} ({why(exc)})") from None
            if a.shape != shape or a.dtype.kind != "f":
                raise error(path, f"array {name!r} is {a.dtype} {a.shape}, expected float "
                                  f"{shape}")
            if not np.isfinite(a).all():
                raise error(path, f"array {name!r} holds non-finite values")
            params[name] = a.astype(np.float32)
    return meta, params


def why(exc: BaseException) -> str:
    """``Type: first line of the message`` of an exception, for one-line errors."""
    msg = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {msg[0]}" if msg else type(exc).__name__
