"""The scheduling engines: local processes and Ray give the same bytes; Ray retries a dead worker,
cancels a round on Ctrl-C and stops only the instance it started."""

from __future__ import annotations

import importlib.util
import json
import logging
import os
import shutil
import sys
import tempfile
import time
from functools import partial
from pathlib import Path

import pytest

from kgnav.benchmark import runner
from kgnav.benchmark.engines import LocalEngine, RayEngine, check_settings, make_engine
from kgnav.benchmark.runner import EvalConfig, resolve_extractor, run_eval, run_variant
from kgnav.benchmark.variants import VARIANTS
from kgnav.errors import KgnavError


def _quick(**kw) -> EvalConfig:
    # the encoder relocates si in its second round; the noise-model segmenter keeps it quick
    base = dict(split="val-small", scenes=2, episodes=2, max_steps=120, segmenter="default",
                extractor="kgnav-encoder", pre_explore_steps=150)
    return EvalConfig(**{**base, **kw})


def _needs_ray():
    if importlib.util.find_spec("ray") is None:
        reason = "ray is not installed (pip install 'kgnav[ray]')"
        # CI installs the dev extra and sets KGNAV_REQUIRE_RAY=1: there a missing Ray fails
        if os.environ.get("KGNAV_REQUIRE_RAY") == "1":
            pytest.fail(f"{reason} but KGNAV_REQUIRE_RAY=1 is set")
        pytest.skip(reason)


@pytest.fixture
def ray_tmp():
    """A short temporary directory for Ray's sockets (their paths must stay under 108 bytes)."""
    d = tempfile.mkdtemp(prefix="kgray", dir="/tmp")
    yield d
    shutil.rmtree(d, ignore_errors=True)


# ---------------------------------------------------------------------- tasks the engines run
_INITIALIZED = []


def _mark_initialized() -> None:
    _INITIALIZED.append(os.getpid())


def _add(context, task):
    return context["k"] + task, os.getpid(), list(_INITIALIZED)


def _raise_on_two(context, task):
    if task == 2:
        raise KgnavError("house 2 is broken")
    return task


def _sleep_unless_zero(context, task):
    if task:
        time.sleep(SLEEP_S)
    return task


# long enough that a task whose cancel was lost shows as itself, not as a loaded machine (where
# starting Ray's workers alone took 45 s)
SLEEP_S = 300


def _die_once(fn, marker_dir, context, task):
    """Kill this worker process the first time it runs scene 1 of round 1, then run ``fn``."""
    if task[2] == 1 and task[3] == 1:
        try:
            with open(Path(marker_dir) / "died", "x"):
                pass
        except FileExistsError:
            pass
        else:
            os._exit(1)
    return fn(context, task)


class _InterruptingBar:
    """A progress bar whose ``at``-th update is a Ctrl-C."""

    def __init__(self, at: int):
        self.at, self.n = at, 0

    def update(self, n: int) -> None:
        self.n += n
        if self.n >= self.at:
            raise KeyboardInterrupt

    def close(self) -> None:
        pass


# ---------------------------------------------------------------------- no Ray needed
def test_local_engine_returns_task_order_and_shares_the_context():
    with LocalEngine(1, _mark_initialized) as one:
        serial = one.map(_add, [3, 1, 2], {"k": 10})
    assert [r[0] for r in serial] == [13, 11, 12]
    assert {r[1] for r in serial} == {os.getpid()} and os.getpid() not in _INITIALIZED
    forked = LocalEngine(2, _mark_initialized).map(_add, [3, 1, 2, 5], {"k": 10})
    assert [r[0] for r in forked] == [13, 11, 12, 15]
    # forked processes ran the initializer, each before its first task; this one never did
    assert all(r[1] != os.getpid() and r[2] == [r[1]] for r in forked)
    assert _INITIALIZED == []


def test_engine_settings_are_checked(cli):
    for args, needle in [(("ray", 1, None), None), (("ray", 1, "auto"), None),
                         (("mpi", 1, None), "unknown engine 'mpi'"),
                         (("local", 1, "h:1"), "address is for the ray engine"),
                         (("ray", 2, "h:1"), "cluster joined at an address brings its own"),
                         (("local", 0, None), "workers must be at least 1")]:
        if needle is None:
            check_settings(*args)
        else:
            with pytest.raises(KgnavError, match=needle):
                check_settings(*args)
            with pytest.raises(KgnavError, match=needle):
                EvalConfig(engine=args[0], workers=args[1], address=args[2])
    code, _out, err = cli("eval", "--engine", "mpi")
    assert code == 2 and "--engine" in err and len(err.strip().splitlines()) == 1
    code, _out, err = cli("eval", "--address", "127.0.0.1:6379")
    assert code == 1 and err.strip() == "kgnav: error: an address is for the ray engine"


def test_ray_engine_without_ray_says_how_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray -> ImportError
    with pytest.raises(KgnavError, match=r"pip install 'kgnav\[ray\]'"):
        make_engine("ray", 2)


def test_local_interrupt_keeps_finished_rounds_and_the_earlier_run(tmp_path, monkeypatch):
    _interrupt_and_check(tmp_path, monkeypatch, _quick(variants=("si",), workers=2))


def _interrupt_and_check(tmp_path, monkeypatch, cfg):
    (tmp_path / "episodes.jsonl").write_text("an earlier complete run\n")
    monkeypatch.setattr(runner, "_bar", lambda total, desc, progress: _InterruptingBar(3))
    with pytest.raises(KeyboardInterrupt):
        run_eval(cfg, tmp_path, progress=False)
    # round 0 (two houses) finished and is kept; round 1 was stopped; the earlier run is intact
    part = [json.loads(x) for x in (tmp_path / "episodes.jsonl.part").read_text().splitlines()]
    assert [(r["round"], r["scene"]) for r in part] == [(0, "val-small_00"), (0, "val-small_01")]
    assert (tmp_path / "episodes.jsonl").read_text() == "an earlier complete run\n"


class _CountingEngine(LocalEngine):
    def __init__(self, workers):
        super().__init__(workers, runner._worker_init)
        self.calls = []

    def map(self, fn, tasks, context=None, bar=None):
        tasks = list(tasks)
        self.calls.append([(t[2], t[3]) for t in tasks])
        return super().map(fn, tasks, context, bar)


def test_rounds_are_batched_only_where_the_memory_cannot_change(tmp_path):
    """Memory-less and pre-explored variants send several rounds per engine call (enough for
    two episodes per worker), a learning one round by round; the records, in round order,
    are the bytes of one process."""
    cfg = _quick(variants=("ans", "si"), episodes=3, max_steps=60)
    ext = resolve_extractor(cfg.extractor)
    one = {v: run_variant(cfg, VARIANTS[v], ext, None, False, engine=LocalEngine(1))[0]
           for v in ("ans", "si")}
    for v, want in (("ans", [[(0, 0), (1, 0), (0, 1), (1, 1)], [(0, 2), (1, 2)]]),
                    ("si", [[(0, 0), (1, 0)], [(0, 1), (1, 1)], [(0, 2), (1, 2)]])):
        engine = _CountingEngine(2)
        parts = []
        recs, _ = run_variant(cfg, VARIANTS[v], ext, None, False, on_round=parts.append,
                              engine=engine)
        assert engine.calls == want
        assert [[r["episode"] for r in p] for p in parts] == [[0, 0], [1, 1], [2, 2]]
        assert json.dumps(recs) == json.dumps(one[v])


# ---------------------------------------------------------------------- Ray
def test_ray_interrupt_stops_the_instance_it_started(tmp_path, ray_tmp, monkeypatch):
    """Ctrl-C in a round of ``--engine ray`` (a Ray instance of 2 CPUs the run starts): the
    finished rounds are kept as with the local engine, and the instance is shut down."""
    _needs_ray()
    import ray

    assert not ray.is_initialized()
    monkeypatch.setenv("RAY_TMPDIR", ray_tmp)
    _interrupt_and_check(tmp_path, monkeypatch, _quick(variants=("si",), engine="ray",
                                                       workers=2))
    assert not ray.is_initialized()


@pytest.fixture(scope="module")
def ray_cluster():
    """A Ray instance of this process that engines join (and must leave running)."""
    _needs_ray()
    import ray

    tmp = tempfile.mkdtemp(prefix="kgray", dir="/tmp")
    ray.init(address="local", num_cpus=2, include_dashboard=False, _temp_dir=tmp,
             logging_level=logging.WARNING)
    yield ray
    ray.shutdown()
    shutil.rmtree(tmp, ignore_errors=True)


def test_ray_engine_writes_the_bytes_of_the_local_engine(ray_cluster, tmp_path):
    """The Ray engine (2 CPUs) against one local process: the same episodes.jsonl byte for
    byte, memory variants included, and the same picture; config.json differs only in how
    the run was executed."""
    kw = dict(variants=("si", "sp"), show=(1, 1))
    run_eval(_quick(**kw), tmp_path / "local", progress=False)
    run_eval(_quick(**kw, engine="ray"), tmp_path / "ray", progress=False)
    assert ray_cluster.is_initialized()  # a joined instance is left running
    local, distributed = (tmp_path / d / "episodes.jsonl" for d in ("local", "ray"))
    assert local.read_bytes() == distributed.read_bytes()
    recs = [json.loads(x) for x in local.read_text().splitlines()]
    assert len(recs) == 8 and {r["variant"] for r in recs if r["relocated"]} == {"si", "sp"}
    png = "topdown/si_01_e001.png"
    assert (tmp_path / "local" / png).read_bytes() == (tmp_path / "ray" / png).read_bytes()
    c1, c2 = (json.loads((tmp_path / d / "config.json").read_text()) for d in ("local", "ray"))
    assert c1.pop("execution") == {"engine": "local", "workers": 1, "address": None,
                                   "store": "directory"}
    assert c2.pop("execution") == {"engine": "ray", "workers": 1, "address": None, "cpus": 2,
                                   "nodes": 1, "store": "directory"}
    assert c1 == c2


class _DyingEngine(RayEngine):
    def __init__(self, marker_dir):
        super().__init__(initializer=runner._worker_init)
        self.marker_dir = str(marker_dir)

    def map(self, fn, tasks, context=None, bar=None):
        return super().map(partial(_die_once, fn, self.marker_dir), tasks, context, bar)


def test_a_worker_that_dies_is_retried_without_changing_results(ray_cluster, tmp_path):
    cfg, si = _quick(max_steps=60), VARIANTS["si"]
    name = resolve_extractor(cfg.extractor)
    expected, _ = run_variant(cfg, si, name, None, progress=False, engine=LocalEngine(1))
    with _DyingEngine(tmp_path) as engine:
        got, _ = run_variant(cfg, si, name, None, progress=False, engine=engine)
    assert (tmp_path / "died").is_file()  # the worker did die once
    assert json.dumps(got, sort_keys=True) == json.dumps(expected, sort_keys=True)


def test_a_task_error_comes_back_as_itself(ray_cluster):
    with RayEngine() as engine, pytest.raises(KgnavError) as exc:
        engine.map(_raise_on_two, [0, 1, 2, 3])
    assert str(exc.value) == "house 2 is broken"


def test_ctrl_c_cancels_the_rounds_ray_tasks(ray_cluster):
    engine = RayEngine()
    t0 = time.perf_counter()
    with pytest.raises(KeyboardInterrupt):
        engine.map(_sleep_unless_zero, [0, 1, 2], bar=_InterruptingBar(1))
    # the two long tasks were cancelled: both CPUs are free again long before they would end
    assert [r[0] for r in engine.map(_add, [1, 2], {"k": 0})] == [1, 2]
    assert time.perf_counter() - t0 < SLEEP_S * 0.8
    engine.close()
    assert ray_cluster.is_initialized()


def test_ray_workers_stay_warm_between_rounds(ray_cluster):
    with RayEngine(initializer=_mark_initialized) as engine:
        rounds = [engine.map(_add, range(6), {"k": k}) for k in (0, 100)]
    assert [r[0] for r in rounds[1]] == [100, 101, 102, 103, 104, 105]
    # each process ran the initializer once, before its first task; processes serve rounds on
    assert all(r[2] == [r[1]] for rnd in rounds for r in rnd)
    assert {r[1] for r in rounds[0]} & {r[1] for r in rounds[1]}
