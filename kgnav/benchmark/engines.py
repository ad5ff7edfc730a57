"""Where the episodes of a benchmark round run: the scheduling engines of ``kgnav eval``.

An engine maps ``fn(context, task)`` over a round's tasks and returns the results in task order,
whatever order they finished in; the runner (:mod:`kgnav.benchmark.runner`) then merges them in
that fixed order, so the engine never changes results. ``context`` is what every task of the
round shares (the memory snapshot, the co-occurrence): the engine ships it once per call.

========  ==================================================================================
``local`` this process (``workers=1``), or ``workers`` processes forked per call, which inherit
          ``context`` without pickling it
``ray``   Ray tasks on a Ray instance started here (``num_cpus``) or on a cluster it joins
          (``address``); ``context`` goes to the object store once (``ray.put``) and each worker
          process deserializes it once; tasks whose worker dies are retried
========  ==================================================================================

>>> def add(context, task):
...     return context["k"] + task
>>> with make_engine("local", workers=1) as engine:
...     engine.map(add, [1, 2, 3], {"k": 10})
[11, 12, 13]
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import socket
from collections.abc import Callable, Iterable

from kgnav.errors import KgnavError


class _NoBar:
    def update(self, n: int) -> None:
        pass


class Engine:
    """Runs ``fn(context, task)`` for every task; ``initializer`` is called once in each worker
    process before its first task (not in this process)."""

    name = ""

    def __init__(self, initializer: Callable[[], None] | None = None):
        self.initializer = initializer

    def map(self, fn: Callable, tasks: Iterable, context=None, bar=None) -> list:
        """``[fn(context, t) for t in tasks]``; ``bar.update(1)`` as each one finishes."""
        raise NotImplementedError

    def describe(self) -> dict:
        """How it runs, for ``config.json``'s execution settings."""
        return {"engine": self.name}

    def slots(self) -> int:
        """How many tasks it runs at once."""
        return 1

    def close(self) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# ---------------------------------------------------------------------- local
_FORKED: tuple | None = None  # (fn, context, initializer) of the call whose processes fork


def _forked_init() -> None:
    initializer = _FORKED[2]
    if initializer is not None:
        initializer()


def _forked_call(task):
    fn, context, _init = _FORKED
    return fn(context, task)


class LocalEngine(Engine):
    """This machine: in this process, or ``workers`` processes forked per :meth:`map` (they
    inherit the caller's caches and ``context``; only tasks and results are pickled)."""

    name = "local"

    def __init__(self, workers: int = 1, initializer: Callable[[], None] | None = None):
        super().__init__(initializer)
        check_settings(self.name, workers, None)
        self.workers = workers

    def map(self, fn: Callable, tasks: Iterable, context=None, bar=None) -> list:
        global _FORKED
        tasks = list(tasks)
        bar = bar or _NoBar()
        out = []
        if self.workers <= 1 or len(tasks) <= 1:
            for t in tasks:
                out.append(fn(context, t))
                bar.update(1)
            return out
        _FORKED = (fn, context, self.initializer)
        try:
            with mp.get_context("fork").Pool(min(self.workers, len(tasks)),
                                             initializer=_forked_init) as pool:
                for r in pool.imap(_forked_call, tasks):
                    out.append(r)
                    bar.update(1)
        finally:
            _FORKED = None
        return out

    def describe(self) -> dict:
        return {"engine": self.name, "workers": self.workers}

    def slots(self) -> int:
        return max(1, self.workers)


# ---------------------------------------------------------------------- ray
# In a Ray worker process: the initializers already run, and the context last deserialized
# (with the id of its object), so the tasks of a round that land on one process share one copy.
_RAY_WORKER: dict = {"initialized": set(), "context": (None, None)}


def _ray_call(fn: Callable, boxed_context: list, task, initializer):
    import ray

    if initializer is not None:
        key = (initializer.__module__, initializer.__qualname__)
        if key not in _RAY_WORKER["initialized"]:
            initializer()
            _RAY_WORKER["initialized"].add(key)
    ref = boxed_context[0]  # boxed: Ray would otherwise deserialize it for every task
    if _RAY_WORKER["context"][0] != ref.hex():
        _RAY_WORKER["context"] = (None, None)  # free the previous round's before loading
        _RAY_WORKER["context"] = (ref.hex(), ray.get(ref))
    return fn(_RAY_WORKER["context"][1], task)


class RayEngine(Engine):
    """Ray tasks (one CPU each). Without ``address`` it starts a Ray instance on this machine
    with ``num_cpus`` CPUs (None: all) and stops it on :meth:`close`; with one (``"auto"``,
    ``"HOST:6379"``, ``"ray://HOST:10001"``) it joins that cluster and only disconnects. If
    this process is already connected to Ray (``ray.init`` called before), it uses that
    connection and leaves it open. A task whose worker process or node dies is retried up to
    ``max_retries`` times; an exception raised by ``fn`` is not retried but re-raised here,
    after the round's remaining tasks are cancelled (as on Ctrl-C)."""

    name = "ray"

    def __init__(self, address: str | None = None, num_cpus: int | None = None,
                 initializer: Callable[[], None] | None = None, max_retries: int = 3,
                 **init_kwargs):
        super().__init__(initializer)
        try:
            import ray
        except ImportError:
            raise KgnavError("the ray engine needs Ray: pip install 'kgnav[ray]'") from None
        if address is not None and num_cpus is not None:
            raise KgnavError("num_cpus is for a Ray instance started here; a cluster joined "
                             "at an address brings its own CPUs")
        self.address, self.num_cpus = address, num_cpus
        self._owner = not ray.is_initialized()
        if self._owner and address is not None:
            _check_reachable(address)
        if self._owner:
            kw = {"logging_level": logging.WARNING, **init_kwargs}
            if address is None:  # "local": a new instance, never someone else's on this host
                kw = {"num_cpus": num_cpus, "include_dashboard": False, **kw}
            try:
                ray.init(address=address or "local", **kw)
            except Exception as exc:  # whatever Ray raises: a setting or machine to fix
                where = f"join the Ray cluster at {address!r}" if address else "start Ray"
                hint = ("; a cluster with token authentication (the default of `ray start` "
                        "since Ray 2.59) also needs RAY_AUTH_MODE=token and its token here"
                        if address and os.environ.get("RAY_AUTH_MODE") != "token" else "")
                raise KgnavError(f"cannot {where}: {_first_line(exc)}{hint}") from None
        self._remote = ray.remote(num_cpus=1, max_retries=max_retries)(_ray_call)
        self._context = self._context_ref = None

    def map(self, fn: Callable, tasks: Iterable, context=None, bar=None) -> list:
        import ray

        tasks = list(tasks)
        bar = bar or _NoBar()
        if not tasks:
            return []
        if self._context_ref is None or context is not self._context:
            self._context_ref = None  # let the object store drop the previous round's
            self._context, self._context_ref = context, ray.put(context)
        refs = [self._remote.remote(fn, [self._context_ref], t, self.initializer)
                for t in tasks]
        where = {ref: i for i, ref in enumerate(refs)}
        out: list = [None] * len(tasks)
        pending = refs
        try:
            while pending:
                done, pending = ray.wait(pending, num_returns=1)
                for ref in done:
                    out[where[ref]] = ray.get(ref)
                    bar.update(1)
        except BaseException as exc:  # Ctrl-C or a failed task: stop the round's work
            _cancel(ray, pending)
            if isinstance(exc, ray.exceptions.RayTaskError):
                raise exc.cause from None  # the task's own error (a KgnavError stays one)
            if isinstance(exc, ray.exceptions.RayError):
                raise KgnavError(f"a Ray task failed: {_first_line(exc)}") from exc
            raise
        return out

    def describe(self) -> dict:
        import ray

        out = {"engine": self.name, "address": self.address}
        if ray.is_initialized():
            out["cpus"] = int(ray.cluster_resources().get("CPU", 0))
            out["nodes"] = sum(1 for n in ray.nodes() if n.get("Alive"))
        return out

    def slots(self) -> int:
        import ray

        return max(1, int(ray.cluster_resources().get("CPU", 1)) if ray.is_initialized() else 1)

    def close(self) -> None:
        """Drop the last context; stop the Ray instance this engine started, or disconnect
        from the cluster it joined (the cluster keeps running)."""
        self._context = self._context_ref = None
        if self._owner:
            import ray

            ray.shutdown()
            self._owner = False


def _check_reachable(address: str, timeout: float = 5.0) -> None:
    """Fail fast on a ``HOST:PORT`` (or ``ray://HOST:PORT``) nobody listens at: Ray itself
    retries such an address for minutes before giving up."""
    host, sep, port = address.removeprefix("ray://").rpartition(":")
    if not sep or not port.isdigit():
        return  # "auto" and the like: Ray resolves them and fails fast itself
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout).close()
    except OSError as exc:
        raise KgnavError(f"cannot join the Ray cluster at {address!r}: nothing answers there "
                         f"({exc.strerror or exc})") from None


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


#: The engines by name (``kgnav eval --engine``).
ENGINES: dict[str, type[Engine]] = {"local": LocalEngine, "ray": RayEngine}


def make_engine(name: str, workers: int = 1, address: str | None = None,
                initializer: Callable[[], None] | None = None) -> Engine:
    """The engine ``name`` for ``workers`` processes (``ray``: the CPUs of the instance it
    starts) or, for ``ray``, the cluster at ``address``."""
    check_settings(name, workers, address)
    if name == "local":
        return LocalEngine(workers, initializer)
    return RayEngine(address=address, num_cpus=None if address else workers,
                     initializer=initializer)


def check_settings(name: str, workers: int, address: str | None) -> None:
    """Raise :class:`KgnavError` for settings :func:`make_engine` cannot honour."""
    if name not in ENGINES:
        raise KgnavError(f"unknown engine {name!r} (known: {', '.join(ENGINES)})")
    if workers < 1:
        raise KgnavError(f"workers must be at least 1, got {workers}")
    if address is not None and name != "ray":
        raise KgnavError("an address is for the ray engine")
    if address is not None and workers > 1:
        raise KgnavError("workers sets the CPUs of a Ray instance started here; a cluster "
                         "joined at an address brings its own")


def _cancel(ray, refs: list, tries: int = 5, wait_s: float = 1.0) -> None:
    """Cancel ``refs`` and make sure they stopped: a cancel that reaches a task while its
    worker is still being handed it can be lost (seen on a loaded machine, where a cancelled
    60-s task then ran to its end and held its CPU), so whatever has not ended a second later
    is cancelled again, a few times at most."""
    for _ in range(tries):
        if not refs:
            return
        for ref in refs:
            ray.cancel(ref, force=True)
        _, refs = ray.wait(refs, num_returns=len(refs), timeout=wait_s)
