"""Which environment (visual domain) a network's weights were trained on, and the check that
they fit the environment a run is on.

A learned segmenter or state encoder knows the frames it was trained on: on another
simulator's frames a segmenter trained on kgnav's renderer finds almost nothing, and an
encoder's distances stop meaning what its threshold assumes. So a weight file records its
environment (``meta["domain"]["env"]``; ``train-segmenter --env`` and ``train-encoder --env``
write it) and ``kgnav eval --env X`` refuses weights made for another one unless asked to run
them anyway (``--allow-domain-mismatch``). Weight files without the record, the shipped ones
among them, were trained on kgnav's own simulator.

>>> weights_env({}), weights_env({"domain": {"env": "miniworld"}})
('kgnav', 'miniworld')
>>> check_domain("segmenter", "w.npz", {}, "kgnav")
>>> try:
...     check_domain("segmenter", "w.npz", {}, "miniworld")
... except DomainMismatchError as e:
...     print(str(e)[:71])
segmenter weights w.npz were trained on environment 'kgnav', not 'miniw
"""

from __future__ import annotations

from kgnav.errors import KgnavError

#: The environment of weights that do not name one: kgnav's own simulator.
DEFAULT_ENV = "kgnav"

#: Per kind of weights: the training command and the ``kgnav eval`` option that takes a file.
_FIX = {"segmenter": ("train-segmenter", "--segmenter-weights"),
        "encoder": ("train-encoder", "--encoder-weights")}


class DomainMismatchError(KgnavError):
    """Weights trained on one environment asked to run on another (one line: what, where it
    was trained, and how to get weights for this one)."""


def weights_env(meta: dict) -> str:
    """The environment a weight file's metadata says it was trained on (default kgnav)."""
    domain = meta.get("domain") if isinstance(meta, dict) else None
    env = domain.get("env") if isinstance(domain, dict) else None
    return env if isinstance(env, str) and env else DEFAULT_ENV


def same_env(a: str, b: str) -> bool:
    """Whether two environment names are the same environment (a registered name and its
    ``MODULE:FACTORY`` spelling are)."""
    if a == b:
        return True
    from kgnav.envs import find_env

    try:
        return find_env(a) is find_env(b)
    except KgnavError:
        return False


def check_domain(kind: str, path, meta: dict, env: str) -> None:
    """Raise :class:`DomainMismatchError` unless weights of ``kind`` (``segmenter`` or
    ``encoder``) with metadata ``meta``, read from ``path``, were trained on ``env``."""
    trained = weights_env(meta)
    if same_env(trained, env):
        return
    command, option = _FIX[kind]
    raise DomainMismatchError(
        f"{kind} weights {path} were trained on environment {trained!r}, not {env!r}: train "
        f"{kind} weights there (kgnav {command} --env {env} --out FILE) and pass {option} "
        f"FILE, or pass --allow-domain-mismatch to run these anyway")
