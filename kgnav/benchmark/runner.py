"""Run agent variants over a split and write ``episodes.jsonl`` and ``summary.json``.

Episode order (fixed, so results are reproducible): rounds ``r = 0, 1, ...``; round ``r`` runs
episode ``r`` of every selected scene, scenes in index order. Variants with memory see, during a
round, the store as it was at the round's start; at the round's end each episode's model is
merged into the model it relocated into (or stored as a new model), in scene order. Scenes of a
round are independent, so an engine (:mod:`kgnav.benchmark.engines`: ``workers`` local
processes, or Ray on a cluster) may run them in parallel with results identical to one
process. Every episode is seeded from ``(seed, scene, episode)``: all variants meet the
same segmenter noise, which makes their comparison paired.

The scenes come from a registered environment (``EvalConfig.env``, :mod:`kgnav.envs`; kgnav's
own simulator by default) through the environment protocol only: the agent gets the camera,
class vocabulary and actions the environment declares, and metrics that need ground truth the
environment does not offer are recorded as missing (``None``).

>>> cfg = EvalConfig(split="val", variants=("oracle",), scenes=1, episodes=1)
>>> records, summary = run_eval(cfg, out=None, progress=False)
>>> records[0]["variant"], records[0]["success"], summary["oracle"]["episodes"]
('oracle', True, 1)
"""

from __future__ import annotations

import json
import math
import os
import re
import tempfile
import time
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from kgnav.agent.camera import Camera
from kgnav.agent.consolidation import Join, consolidate
from kgnav.agent.features import loop_threshold, make_extractor
from kgnav.agent.loop import MEMORY_GOAL_REASONS, AgentConfig, ObjectNavAgent
from kgnav.agent.memory import Memory
from kgnav.agent.noise_segmenters import GROUND_TRUTH_SEGMENTERS
from kgnav.agent.oracle import OracleAgent
from kgnav.agent.policy import cooccurrence, make_policy
from kgnav.agent.segmentation import make_segmenter
from kgnav.benchmark import fidelity
from kgnav.benchmark.engines import Engine, check_settings, make_engine
from kgnav.benchmark.failures import FAILURE_CLASSES, classify
from kgnav.benchmark.memory_update import absorb as _absorb
from kgnav.benchmark.stats import METRICS, paired_differences
from kgnav.benchmark.variants import VARIANTS, Variant, with_policy
from kgnav.common import se2
from kgnav.common.atomic import atomic_open
from kgnav.envs import (
    DEFAULT_ENV,
    EnvOptions,
    EnvProtocolError,
    EnvSpec,
    EnvSuite,
    NavEnv,
    check_env,
    check_observation,
    env_applies_noise,
    env_weights,
    find_env,
    make_env,
)
from kgnav.envs.protocol import episode_seed
from kgnav.errors import KgnavError, UnknownClassError
from kgnav.memory.evidence import forget
from kgnav.memory.model import AbstractModel
from kgnav.memory.posegraph import DriftModel
from kgnav.memory.store import ModelStore
from kgnav.sim.episodes import SPLITS
from kgnav.sim.noise import BENCHMARK_NOISE, NoiseSpec, parse_noise, resolve_noise


@dataclass(frozen=True)
class EvalConfig:
    """What to run. ``env``: a registered environment (:mod:`kgnav.envs`; ``kgnav``, the
    embedded simulator, by default); ``split``: a built-in split, or ``scenes_dir``: a
    directory of your own (``kgnav scenes generate``), passed to the environment in
    :class:`~kgnav.envs.EnvOptions`; ``scenes``: the first K scenes (None: all); ``episodes``:
    per scene (None: the split's default, or all of a directory's); ``threshold``: relocation
    cosine distance (None: the extractor's calibrated value); ``noise``: the environment's
    motion, pose-sensor and depth noise by spec (:mod:`kgnav.sim.noise`: ``"none"``,
    ``"locobot"``, ``"locobot,depth=0.01"``, ...; None: :data:`~kgnav.sim.noise.BENCHMARK_NOISE`,
    a LoCoBot's motion and wheel odometry, where the environment applies noise
    (:func:`~kgnav.envs.env_applies_noise`), else none; ``"none"``: the noise-free ObjectNav
    task);
    ``actuation_noise`` / ``odometry_noise``: the older generic levels instead (then None
    means no other noise).
    ``workers``, ``engine`` and ``address`` (:data:`EXECUTION`) say how to run it, never
    what comes out: ``engine`` ``local`` (``workers`` processes) or ``ray`` (a Ray instance
    with ``workers`` CPUs, or the cluster at ``address``)."""

    split: str = "val"
    scenes_dir: str | None = None
    variants: tuple[str, ...] = ("ans",)
    scenes: int | None = None
    episodes: int | None = None
    workers: int = 1
    segmenter: str = "learned"
    extractor: str = "auto"
    threshold: float | None = None
    seed: int = 0
    width: int = 160
    height: int = 120
    pre_explore_steps: int = 1500
    max_steps: int = 500  # per episode (the task's 500; lower only for quick checks)
    actuation_noise: float = 0.0
    odometry_noise: float = 0.0
    noise: str | None = None  # a noise spec (kgnav.sim.noise); None: BENCHMARK_NOISE
    # with a drifting pose sensor, bend each episode onto the model it merges into by its
    # loop closures (kgnav.memory.posegraph; docs/drift.md); off: one rigid transform
    drift_correction: bool = True
    forget_below: float = 0.2  # stored objects whose belief falls below this are forgotten
    forget_label_share: float = 0.5  # ... and those whose place mostly gave another class
    # after each round, join the stored models that verifiably fit each other as a whole
    # (kgnav.agent.consolidation): one memory per house
    consolidate: bool = True
    preset: str = "default"  # the name of the agent settings (recorded in config.json)
    show: tuple[int, int] | None = None  # (scene, episode) to draw from above per variant
    policy: str | None = None  # global policy of ans/si (see variants.with_policy)
    agent: AgentConfig = field(default_factory=AgentConfig)
    engine: str = "local"
    address: str | None = None
    env: str = DEFAULT_ENV
    encoder_weights: str | None = None  # kgnav-encoder's weight file (None: the shipped one)
    segmenter_weights: str | None = None  # the learned segmenter's (None: the shipped one)
    # run learned weights made for another environment (kgnav.nets.domain) instead of refusing
    allow_domain_mismatch: bool = False
    store: str = "directory"  # where the memory is written: GraphML files, or "ladybug"

    def __post_init__(self):
        find_env(self.env)  # a one-line error for an unknown or broken one
        if self.env == "kgnav" and self.scenes_dir is None and self.split not in SPLITS:
            raise KgnavError(f"unknown split {self.split!r} (known: {', '.join(SPLITS)})")
        if self.actuation_noise < 0 or self.odometry_noise < 0:
            raise KgnavError("noise levels must be >= 0")
        applies = env_applies_noise(self.env)
        if self.noise is None:
            # the older levels name the whole noise themselves; an environment that does not
            # apply noise is run (and recorded) without
            levels = self.actuation_noise or self.odometry_noise
            object.__setattr__(self, "noise",
                               "none" if levels or not applies else BENCHMARK_NOISE)
        # canonical, so that config.json names it and equal settings compare equal
        object.__setattr__(self, "noise", parse_noise(self.noise).text)
        # both a named model and levels: an error
        if resolve_noise(self.noise, self.actuation_noise, self.odometry_noise).active \
                and not applies:
            raise KgnavError(f"environment {self.env!r} does not apply noise (its factory has "
                             f"no applies_noise = True): run it with --noise none")
        for v in self.variants:
            if v not in VARIANTS:
                raise KgnavError(f"unknown variant {v!r} (known: {', '.join(VARIANTS)})")
        check_settings(self.engine, self.workers, self.address)
        if self.store not in STORES:
            raise KgnavError(f"unknown store {self.store!r} (known: {', '.join(STORES)})")
        if self.encoder_weights is not None and self.extractor not in ("auto", ENCODER):
            raise KgnavError(f"encoder weights are for extractor {ENCODER!r}, not "
                             f"{self.extractor!r}")
        if self.segmenter_weights is not None and self.segmenter not in LEARNED_SEGMENTERS:
            raise KgnavError(f"segmenter weights are for the learned segmenter, not "
                             f"{self.segmenter!r}")

    @property
    def env_options(self) -> EnvOptions:
        return EnvOptions(self.split, self.scenes_dir, self.width, self.height, self.max_steps,
                          self.actuation_noise, self.odometry_noise, self.noise)

    @property
    def noise_spec(self) -> NoiseSpec:
        """The noise this run asks of the environment, resolved (name and parameters)."""
        return resolve_noise(self.noise, self.actuation_noise, self.odometry_noise)

    @property
    def suite(self) -> EnvSuite:
        """The environment's scenes (built once per process)."""
        key = ("suite", self.env, self.env_options)
        if key not in _CACHE:
            _CACHE[key] = make_env(self.env, self.env_options)
        return _CACHE[key]

    @property
    def source_name(self) -> str:
        return self.scenes_dir if self.scenes_dir is not None else self.split

    @property
    def scene_indices(self) -> list[int]:
        n = len(self.suite)
        return list(range(min(self.scenes, n) if self.scenes else n))


#: The fields of :class:`EvalConfig` that say how a run executes; they never change its results
#: (``config.json`` keeps them apart, under ``execution``). ``store`` says where the memory is
#: written (:func:`memory_store`); the agents work on the models in memory either way.
EXECUTION = ("workers", "engine", "address", "store")


ENCODER = "kgnav-encoder"
LEARNED_SEGMENTERS = ("learned", "kgnav-segnet")  # the names that take --segmenter-weights


def resolve_extractor(name: str, weights: str | None = None) -> str:
    """``auto`` → the learned encoder when it loads (``weights``: its weight file; None: the
    shipped one), else the OpenCV descriptor. With ``weights`` the encoder must load."""
    if name != "auto":
        return name
    if weights is not None:
        return ENCODER
    try:
        make_extractor(ENCODER)
        return ENCODER
    except KgnavError:
        return "opencv-gist"


# ---------------------------------------------------------------------- per-process state
# Environments and extractors are kept per process (forked workers inherit them); ``_ROUND`` is
# the round's context (memory snapshot, co-occurrence) an engine hands each task.
_CACHE: dict = {}
_ROUND: dict = {}


def _env(cfg: EvalConfig, scene: int) -> NavEnv:
    key = ("env", cfg.env, cfg.env_options, scene, cfg.episodes)
    if key not in _CACHE:
        env = cfg.suite.make(scene, cfg.episodes)
        check_env(env, cfg.env)
        _CACHE[key] = env
    return _CACHE[key]


def scene_name(env: NavEnv, cfg: EvalConfig, scene: int) -> str:
    """The environment's name for a scene (hook ``scene_name``), else ``<env>-<k>``; characters
    a model id cannot hold become ``_`` (models are named after their scene).

    >>> scene_name(object(), EvalConfig(env="kgnav.envs.kgnav_sim:KgnavScenes"), 3)
    'kgnav.envs.kgnav_sim_KgnavScenes-03'
    """
    name = getattr(env, "scene_name", None) or f"{cfg.env}-{scene:02d}"
    return re.sub(r"[^A-Za-z0-9_.+-]", "_", str(name))[:100]


def _extractor(name: str, weights: str | None = None):
    """The extractor ``name`` (kgnav-encoder with ``weights`` when given), once per process."""
    key = ("extractor", name, weights)
    if key not in _CACHE:
        _CACHE[key] = (make_extractor(name, weights=weights)
                       if weights is not None and name == ENCODER else make_extractor(name))
    return _CACHE[key]


def _threshold(cfg: EvalConfig, extractor) -> float:
    if cfg.threshold is not None:
        return float(cfg.threshold)
    return loop_threshold(extractor)


def _make_agent(cfg: EvalConfig, variant: Variant, env: NavEnv, memory: Memory | None,
                extractor_name: str):
    spec = env.env_spec
    if variant.oracle:
        missing = [h for h in ("navigable_map", "world_pose") if not hasattr(env, h)]
        if missing:
            raise EnvProtocolError(f"variant oracle needs the environment's ground truth "
                                   f"({', '.join(missing)}); environment {cfg.env!r} has none")
        return OracleAgent(env, step=spec.actions.step_m, turn_deg=spec.actions.turn_deg)
    policy = make_policy(variant.policy)
    if variant.policy == "semantic":
        policy.cooccurrence_ = _ROUND.get("cooccurrence", {})
    config = replace(cfg.agent, strategy=variant.strategy)
    config = replace(config, relocation=replace(config.relocation, drift=_drift(cfg)))
    return ObjectNavAgent.for_env(spec, _segmenter(cfg, spec),
                                  _extractor(extractor_name, cfg.encoder_weights),
                                  policy=policy, memory=memory, config=config)


def _drift(cfg: EvalConfig) -> DriftModel | None:
    """The odometry's drift model the agent corrects its episodes with: the configured one,
    or, when the robot's odometry drifts (and correction is on), the default."""
    if cfg.agent.relocation.drift is not None:
        return cfg.agent.relocation.drift
    if cfg.drift_correction and cfg.noise_spec.odometry.active:
        # the robot's odometry drifts: its episodes are bent onto the memory before merging
        return DriftModel()
    return None


def _segmenter(cfg: EvalConfig, spec: EnvSpec):
    """``cfg.segmenter``; a ground-truth one gets the environment's camera and vocabulary."""
    if cfg.segmenter_weights is not None:
        return _learned_segmenter(cfg.segmenter, cfg.seed, cfg.segmenter_weights)
    if cfg.segmenter not in GROUND_TRUTH_SEGMENTERS:
        return make_segmenter(cfg.segmenter, cfg.seed)
    if not spec.semantic:
        raise EnvProtocolError(f"segmenter {cfg.segmenter!r} needs the ground-truth semantic "
                               f"frame, which environment {spec.name!r} does not provide "
                               f"(use --segmenter learned)")
    cam = Camera.from_spec(spec.camera)
    return make_segmenter(cfg.segmenter, cfg.seed, hfov_deg=cam.hfov_deg,
                          min_depth=cam.min_depth, max_depth=cam.max_depth,
                          classes=spec.classes)


def _learned_segmenter(name: str, seed: int, weights: str):
    """The learned segmenter with ``weights``, its file read once per process."""
    key = ("segmenter-weights", weights)
    if key not in _CACHE:
        from kgnav.nets.segnet.weights import load_weights

        _CACHE[key] = load_weights(weights)
    return make_segmenter(name, seed, weights=_CACHE[key])


def with_env_weights(cfg: EvalConfig) -> EvalConfig:
    """``cfg`` with the weights ``cfg.env`` names as its own (:func:`kgnav.envs.env_weights`)
    where the run gave none: a MiniWorld run's learned segmenter is MiniWorld's."""
    own = env_weights(cfg.env)
    if cfg.segmenter_weights is None and "segmenter" in own and (
            cfg.segmenter in LEARNED_SEGMENTERS):
        cfg = replace(cfg, segmenter_weights=str(own["segmenter"]))
    if cfg.encoder_weights is None and "encoder" in own and cfg.extractor in ("auto", ENCODER):
        cfg = replace(cfg, encoder_weights=str(own["encoder"]))
    return cfg


def check_domains(cfg: EvalConfig, extractor_name: str) -> None:
    """Refuse, in one line, learned weights trained on another environment than ``cfg.env``
    (:mod:`kgnav.nets.domain`): the segmenter's when it is the learned one, the encoder's when
    the features are its; ``cfg.allow_domain_mismatch`` runs them anyway."""
    if cfg.allow_domain_mismatch:
        return
    from kgnav.nets.domain import check_domain

    if cfg.segmenter in LEARNED_SEGMENTERS:
        from kgnav.nets.segnet.weights import DEFAULT_WEIGHTS, load_weights

        w = load_weights(cfg.segmenter_weights)
        check_domain("segmenter", cfg.segmenter_weights or DEFAULT_WEIGHTS, w.meta, cfg.env)
    if extractor_name == ENCODER:
        from kgnav.nets.encoder.weights import DEFAULT_WEIGHTS as ENCODER_WEIGHTS
        from kgnav.nets.encoder.weights import load_weights as load_encoder

        w = load_encoder(cfg.encoder_weights)
        check_domain("encoder", cfg.encoder_weights or ENCODER_WEIGHTS, w.meta, cfg.env)


# ---------------------------------------------------------------------- one episode
@dataclass
class Outcome:
    """An episode's record, and what it gives the memory: its model, the stored model it
    relocated into (with the episode -> model transform), verified bridges to other stored
    models (id -> episode -> model transform), the real instances it saw (ids), and the true
    world (x, y) of every state its model recorded, keyed ``model_id/node_id`` (scoring
    only: the agent never sees it)."""

    record: dict
    model: AbstractModel | None = None
    transform: tuple[float, float, float] | None = None
    matched: str | None = None
    bridges: dict = field(default_factory=dict)
    seen: set = field(default_factory=set)
    files: dict = field(default_factory=dict)  # path -> bytes, for the caller to write
    truth: dict = field(default_factory=dict)  # "model_id/node_id" -> true world (x, y)


#: An instance counts as seen by an episode when this many of its pixels lie within SEEN_RANGE.
SEEN_PIXELS, SEEN_RANGE = 50, 3.5


def seen_instances(obs) -> set[int]:
    """Ground-truth instances visible in a frame, large and near enough to be segmented."""
    sem = obs.get("semantic")
    if sem is None:
        return set()
    ids = sem[..., 1][obs["depth"] <= SEEN_RANGE]
    counts = np.bincount(ids.ravel())
    return {int(i) for i in np.flatnonzero(counts >= SEEN_PIXELS) if i > 0}


def goal_instances(env: NavEnv, goal: str) -> set[int] | None:
    """Ids of the true instances of ``goal`` (scoring only); None when the environment does
    not list its objects (``scene_objects``)."""
    objects = getattr(env, "scene_objects", None)
    return None if objects is None else {int(o.id) for o in objects() if o.cls == goal}


def needs_semantic(agent, variant: Variant) -> bool:
    """Whether an episode's frames must carry the ground-truth semantic channel: for a segmenter
    that reads it, and for the instances a learning variant's memory is scored against
    (:func:`seen_instances`). Otherwise the environment is told it may skip the labels."""
    seg = getattr(agent, "segmenter", None)
    return variant.learns or (seg is not None and getattr(seg, "needs_semantic", True))


def run_episode(cfg: EvalConfig, variant: Variant, scene: int, episode: int, round_: int,
                extractor_name: str, topdown: str | None = None) -> Outcome:
    """One episode of ``variant``; ``topdown``: where to draw it from above (PNG)."""
    env = _env(cfg, scene)
    spec = env.env_spec
    memory = _ROUND.get("memory") if variant.memory else None
    agent = _make_agent(cfg, variant, env, memory, extractor_name)
    seed = episode_seed(cfg.seed, scene, episode)
    labels = needs_semantic(agent, variant)
    obs, info = env.reset(seed=seed, options={"episode": episode, "semantic": labels})
    check_observation(obs, spec, labels)
    goal = spec.class_name(int(np.asarray(obs["objectgoal"]).reshape(-1)[0]))
    name = scene_name(env, cfg, scene)
    agent.reset(goal, seed=seed, scene=name, episode=scene * 1000 + episode,
                model_id=f"{name}-e{episode:03d}")
    gt = _GroundTruth(env, name, episode)
    house_truth = _ROUND.get("truth", {}).get(name, {})  # scoring only: the agent never sees it
    held = goal_in_memory(gt, memory, goal, house_truth)
    # the house's own models as the episode starts: what it could relocate into
    house_models = (None if memory is None
                    else sum(_house_of(mid) == name for mid in memory.models))
    # scoring only: had the house's earlier episodes a true goal instance in view, and when
    # did this one first have one (what a segmenter should have recognised)
    goals = goal_instances(env, goal)
    before = _ROUND.get("seen", {}).get(name) if memory is not None else None
    watch = labels and goals is not None and not variant.oracle
    seen = seen_instances(obs) if variant.learns or watch else set()
    in_view = 0 if watch and goals & seen else None
    track = variant.learns or memory is not None
    path = [gt.world_pose()] if track else []  # true pose after each step
    if cfg.noise_spec.active:  # with drift, judge relocations by where the agent truly was
        gt.path = path
    done, steps = False, 0
    tracking = _Tracking(gt, memory, house_truth) if memory is not None else None
    while not done:
        action = agent.act(obs)
        if tracking is not None:
            tracking.note(agent.relocation_, obs.get("pose"), path, steps)
        obs, _r, term, trunc, info = env.step(action)
        check_observation(obs, spec, labels)
        steps += 1
        done = term or trunc
        if variant.learns or watch:
            now = seen_instances(obs)
            seen |= now
            if in_view is None and watch and now & goals:
                in_view = steps
        if track:
            path.append(gt.world_pose())
    if "success" not in info:
        raise EnvProtocolError(f"environment {spec.name!r}: the last step's info has no "
                               f"'success'")

    if topdown is not None:
        _draw(env, agent, topdown)
    reloc = agent.relocation_
    record = {
        "variant": variant.name,
        "scene": name,
        "episode": episode,
        "episode_id": info.get("episode_id"),
        "round": round_,
        "goal": goal,
        "success": bool(info["success"]),
        "spl": _metric(info, "spl"),
        "softspl": _metric(info, "softspl"),
        "dts": _metric(info, "dts"),
        "steps": steps,
        "path_length": _metric(info, "path_length"),
        "shortest_path_length": _metric(info, "shortest_path_length"),
        "relocated": reloc is not None,
    }
    target_source, target_err = None, math.inf
    if not variant.oracle:
        objects = [t for t in agent.log_.targets if t[1] != "explore"]
        if objects:
            _step, target_source, tx, ty, _oid = objects[-1]
            target_err = gt.target_error(tx, ty)
        record["stop_reason"] = agent.log_.stop_reason
        # every object the agent headed for: when, why, and how far from a real goal
        record["object_targets"] = [
            [t[0], t[1], None if (e := gt.target_error(t[2], t[3])) is None else round(e, 2)]
            for t in objects]
        record["memory_goal_step"] = next((t[0] for t in objects if t[1] == "memory"), None)
        record["target_source"] = target_source
        record["target_error"] = (None if target_err is None or math.isinf(target_err)
                                  else round(target_err, 3))
    record["failure"] = _failure(record, variant, target_source, target_err)
    record["goal_in_memory"] = held
    if watch:
        record["goal_in_view_step"] = in_view
    if goals is not None and memory is not None:
        record["goal_seen_before"] = bool(goals & (before or set()))
    if house_models is not None:
        record["house_models"] = house_models
    record["memory_goal_reason"] = (agent.memory_goal_reason()
                                    if held and record.get("memory_goal_step") is None else None)
    if not variant.oracle and agent.memory is not None:
        # which frontiers exploration took (kgnav.agent.policy.FRONTIER_SOURCES)
        record["frontier_sources"] = dict(agent.log_.frontier_sources)
    if not variant.oracle and agent.log_.detour_drops:  # (step, object) given up as detours
        record["detour_drops"] = [list(d) for d in agent.log_.detour_drops]
    if not variant.oracle and agent.log_.unconfirmed:  # (step, object, best close score)
        record["unconfirmed"] = [list(u) for u in agent.log_.unconfirmed]
    if not variant.oracle and agent.log_.undone:
        record["undone"] = [_relocation_fields(gt, u) for u in agent.log_.undone]
    if reloc is not None:
        record["relocation"] = {"distance": (round(float(reloc.distance), 4)
                                             if math.isfinite(reloc.distance) else None),
                                "source": reloc.source, **_relocation_fields(gt, reloc)}
        if tracking is not None:
            record["relocation"].update(tracking.summary(reloc, path))
    rel = getattr(agent, "relocalizer", None)
    into = agent.mergeable() if variant.learns else None  # (the merge checks count decisions)
    if rel is not None:  # why hypotheses were accepted or refused, and bridges found
        record["relocation_decisions"] = dict(sorted(rel.decisions.items()))
        record["hypotheses"] = judged_hypotheses(gt, rel.hypotheses)
        if house_truth:
            record["memory_overlap"] = memory_overlap(path, house_truth.values())
    if variant.learns:
        bridges = {}
        if reloc is not None:
            record["relocation"]["merged"] = into is reloc
            final = rel.final.get(reloc.model_id)
            if final is not None:  # the whole episode's verdict before merging
                record["relocation"]["final"] = {
                    "reason": final.reason, "inliers": round(final.inliers, 3),
                    "conflicts": round(final.conflicts, 3), "points": final.points,
                    **_relocation_error(gt, reloc.model_id, final.transform, reloc.at,
                                        _at_step(reloc))}
        if into is not None and into.late:  # found from the whole episode at its end
            record["late_merge"] = _relocation_fields(gt, into)
        if into is not None:  # where the merge lays the episode's states (bent, if drifting)
            placed = _placement(gt, into.model_id, into.transform, agent.model_, path,
                                tracking)
            if placed:
                (record["late_merge"] if into.late
                 else record["relocation"])["placed"] = placed
        if into is not None and rel.bridges:
            bridges = {mid: v.transform for mid, v in rel.bridges.items()}
            record["bridges"] = [
                {"model": mid, **_relocation_error(gt, mid, T, into.at, _at_step(into))}
                for mid, T in sorted(bridges.items())]
        return Outcome(record, agent.model_, into.transform if into else None,
                       into.model_id if into else None, bridges, seen,
                       truth=state_truth(agent.model_, path))
    return Outcome(record)


def goal_in_memory(gt: _GroundTruth, memory: Memory | None, goal: str,
                   truth: dict | None = None) -> bool | None:
    """Whether the house's memory (any of its stored models) holds a true instance of the
    goal class: an object of the class that fidelity matching
    (:func:`kgnav.benchmark.fidelity.holds_true_instance`) maps to a real instance of it,
    each model placed in its own frame (:func:`kgnav.benchmark.fidelity.aligned_frames`,
    ``truth``: the true poses of the house's stored states) so that a model its creator's
    drift turned still holds what it holds. Asked as the episode starts, to split where
    success is lost; None without a memory, or without the ground truth it needs
    (``scene_objects``, ``episode_start``)."""
    objects = getattr(gt.env, "scene_objects", None)
    if memory is None or objects is None or not hasattr(gt.env, "episode_start"):
        return None
    mine = [(m, frame) for mid, m in sorted(memory.models.items())
            if (frame := _model_frame(gt, mid)) is not None]
    return fidelity.holds_true_instance(fidelity.aligned_frames(mine, truth or {}), goal,
                                        objects())


def _metric(info: dict, key: str) -> float | None:
    """A metric the environment reported, or None when it offers none."""
    v = info.get(key)
    return None if v is None else float(v)


def _failure(record: dict, variant: Variant, target_source: str | None,
             target_err: float | None) -> str | None:
    """The failure class (:mod:`kgnav.benchmark.failures`); None for a success, or when the
    ground truth it needs (the target's distance to a real goal, DTS) is missing."""
    if record["success"]:
        return None
    if variant.oracle:
        return "Misc"
    if target_source is None:
        return "Exploration"
    if target_err is None or record["dts"] is None:
        return None
    return classify(False, record["dts"], target_source, target_err)


def state_truth(model: AbstractModel, path: list) -> dict[str, tuple[float, ...]]:
    """The true world pose (x, y, θ; (x, y) where the environment gives no heading) of each
    state ``model`` recorded, keyed by its creator (``model_id/node_id``, the first entry of
    its ``origin``): ``path[k]`` is the true pose after ``k`` steps (None where the
    environment does not say), and a state records its step. Plain data: it goes back from
    the worker that ran the episode."""
    out = {}
    for sid in model.states():
        d = model.graph.nodes[sid]
        k = int(d["step"])
        if 0 <= k < len(path) and path[k] is not None:
            out[d["origin"].split(" ", 1)[0]] = tuple(float(v) for v in path[k][:3])
    return out


class _GroundTruth:
    """The optional ground-truth hooks of an environment for one episode
    (:data:`kgnav.envs.GROUND_TRUTH_HOOKS`); every answer is None where a hook is missing."""

    def __init__(self, env: NavEnv, name: str, episode: int):
        self.env, self.name, self.episode = env, name, episode
        # the true world pose after each step, when relocation errors are to be judged by it
        self.path: list | None = None

    def world_pose(self) -> tuple[float, float, float] | None:
        """The agent's true world pose now (the ``world_pose`` hook)."""
        p = getattr(self.env, "world_pose", None)
        return None if p is None else tuple(float(v) for v in p)

    def start(self, i: int):
        f = getattr(self.env, "episode_start", None)
        return None if f is None else f(i)

    def target_error(self, x: float, y: float) -> float | None:
        """L2 distance (m) from an episode-frame point to the nearest real goal instance."""
        env = self.env
        l2 = getattr(env, "l2_distance_to_goal", None)
        if l2 is None:
            return None
        to_world = getattr(env, "start_frame_to_world", None)
        if to_world is not None:
            wx, wy = to_world(x, y)
        else:
            start = self.start(self.episode)
            if start is None:
                return None
            wx, wy = se2.apply_to_point(start, x, y)
        return float(l2(wx, wy))


def _draw(env: NavEnv, agent, path: str) -> None:
    draw = getattr(env, "topdown", None)
    if draw is None:  # the environment cannot draw itself from above
        return
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    m = getattr(agent, "map_", None)
    if m is None:
        draw(path)
        return
    draw(path, agent_map=m.explored, map_resolution=m.resolution, map_origin=m.corner)


def _relocation_fields(gt: _GroundTruth, reloc) -> dict:
    """What ``episodes.jsonl`` says of a relocation, kept or undone: when and into which
    model, whether that model is of this house, its geometric verification (share of inlier
    points, conflicts, points judged), its landmark support and its error."""
    out = {"step": reloc.step, "model": reloc.model_id,
           "same_house": _house_of(reloc.model_id) == gt.name,
           "checked": reloc.checked, "supported": reloc.supported}
    if reloc.inliers is not None:
        out.update(inliers=reloc.inliers, conflicts=reloc.conflicts, points=reloc.points)
    if reloc.look is not None:  # how the place looked against what the memory saw there
        out.update(look=reloc.look, look_views=reloc.look_views)
    return {**out, **_relocation_error(gt, reloc.model_id, reloc.made,
                                       reloc.at, _at_step(reloc))}


def _at_step(reloc) -> int:
    """The step at which ``reloc.at`` was the agent's position (a late match places the
    episode's origin, step 0)."""
    return 0 if reloc.late else reloc.step


def _house_of(model_id: str) -> str:
    return model_id.rpartition("-")[0]


def _model_frame(gt: _GroundTruth, model_id: str):
    """World pose of a model's frame: models are named ``<house>-e<episode>`` (or
    ``<house>-pre``) and live in that episode's start frame. None for another house's, or
    when the environment does not say where its episodes start."""
    house, _, tag = model_id.rpartition("-")
    if house != gt.name:
        return None
    return gt.start(0 if tag == "pre" else int(tag[1:]))


def _relocation_error(gt: _GroundTruth, model_id: str, transform, at, step=None) -> dict:
    """How far off a frame transform (episode -> model) is, from ground truth: the error (m)
    of the agent's own position ``at`` mapped into the model frame, and the heading error
    (degrees). Empty for another house's model, or without ground truth.

    With a drifting pose sensor (``gt.path`` set), ``at`` (the odometry's position at
    ``step``) is judged against where the agent truly was at that step: the true start frame
    would count the drift since the start as the relocation's error."""
    frame = _model_frame(gt, model_id)
    if frame is None or at is None:
        return {}
    truth = se2.compose(se2.inverse(frame), gt.start(gt.episode))
    ex, ey = se2.apply_to_point(transform, *at)
    tx, ty = se2.apply_to_point(truth, *at)
    path = gt.path
    if path is not None and step is not None and 0 <= step < len(path) and path[step]:
        tx, ty = se2.apply_to_point(se2.inverse(frame), *path[step][:2])
    return {"error_m": round(math.hypot(ex - tx, ey - ty), 3),
            "error_deg": round(math.degrees(se2.angle_diff(transform[2], truth[2])), 2)}


class _Tracking:
    """Where the agent believed it was in the memory, step by step, against where it was:
    after each step's decision, the standing relocation's transform (as refined by then)
    applied to the odometry's position, against the true position in that model's frame.
    A relocation judged only where it was made says nothing of the steps after it, when a
    drifting odometry carries the agent away from the transform found then.

    Each error is measured twice: against the truth in the model's frame (the frame of the
    episode that created it), and against where the stored model has that place (the true
    position moved by the median offset of the stored states within ``LOCAL_RADIUS`` of it,
    stored against true). A stored model bent by its creators' drift has a place elsewhere
    than the truth; a relocation that lays the agent on the model as stored is right for
    everything the model holds there, and the first measure counts the bend against it."""

    def __init__(self, gt: _GroundTruth, memory: Memory | None, truth: dict):
        self.gt, self.memory, self.truth = gt, memory, truth
        self.errors: list[float] = []
        self.local: list[float] = []
        self._frames: dict[str, tuple | None] = {}
        self._stored: dict[str, tuple[np.ndarray, np.ndarray]] = {}

    def _frame(self, mid: str):
        if mid not in self._frames:
            self._frames[mid] = _model_frame(self.gt, mid)
        return self._frames[mid]

    def offset(self, mid: str, q: tuple[float, float]) -> tuple[float, float] | None:
        """How far the stored model has the true place ``q`` (model frame) moved: the median
        (stored - true) of the stored states with a known truth within LOCAL_RADIUS."""
        if mid not in self._stored:
            stored, true = [], []
            model = self.memory.model(mid) if self.memory is not None else None
            inv = se2.inverse(self._frame(mid))
            if model is not None:
                for sid in model.states():
                    d = model.graph.nodes[sid]
                    t = self.truth.get(d["origin"].split(" ", 1)[0])
                    if t is not None:
                        stored.append((d["x"], d["y"]))
                        true.append(se2.apply_to_point(inv, t[0], t[1]))
            self._stored[mid] = (np.asarray(stored, np.float64).reshape(-1, 2),
                                 np.asarray(true, np.float64).reshape(-1, 2))
        stored, true = self._stored[mid]
        near = np.hypot(true[:, 0] - q[0], true[:, 1] - q[1]) <= LOCAL_RADIUS
        if near.sum() < 3:
            return None
        dx, dy = np.median(stored[near] - true[near], axis=0)
        return float(dx), float(dy)

    def errors_at(self, mid: str, transform, at, step: int, path: list
                  ) -> tuple[float, float | None] | None:
        """The error of ``transform`` at the odometry position ``at`` of ``step``: against
        the truth, and against the model as stored (None where it holds no state near)."""
        frame = self._frame(mid)
        if frame is None or at is None or not 0 <= step < len(path) or path[step] is None:
            return None
        bx, by = se2.apply_to_point(transform, float(at[0]), float(at[1]))
        tx, ty = se2.apply_to_point(se2.inverse(frame), *path[step][:2])
        off = self.offset(mid, (tx, ty))
        local = None if off is None else math.hypot(bx - tx - off[0], by - ty - off[1])
        return math.hypot(bx - tx, by - ty), local

    def note(self, reloc, pose, path: list, step: int) -> None:
        if reloc is None or pose is None:
            return
        pose = np.asarray(pose, np.float64).reshape(-1)
        e = self.errors_at(reloc.model_id, reloc.transform, pose[:2], step, path)
        if e is not None:
            self.errors.append(e[0])
            if e[1] is not None:
                self.local.append(e[1])

    def summary(self, reloc, path: list) -> dict:
        """What ``episodes.jsonl`` adds to the relocation: its error where it was made
        against the stored model (``local_error_m``), and the median over the steps after it
        (``tracking_error_m``, ``tracking_local_m``)."""
        out = {}
        if not reloc.late:
            e = self.errors_at(reloc.model_id, reloc.made, reloc.at,
                               reloc.step, path)
            if e is not None and e[1] is not None:
                out["local_error_m"] = round(e[1], 3)
        if self.errors:
            out["tracking_error_m"] = round(float(np.median(self.errors)), 3)
        if self.local:
            out["tracking_local_m"] = round(float(np.median(self.local)), 3)
        return out


def _placement(gt: _GroundTruth, model_id: str, transform, episode: AbstractModel,
               path: list, tracking: _Tracking | None = None) -> dict:
    """How far a merge lays the episode's states from where they truly were: each state's
    pose (bent by the loop closures when the odometry drifts) mapped by ``transform`` into
    the model's frame, against its true pose there; the median position error (m) and
    median heading error (degrees) over the states, and (with ``tracking``, which knows the
    stored model) the median position error against where the stored model has each place
    (``local_error_m``). Empty for another house's model, or without the true path. With a
    drifting odometry this, not the transform judged at one step, says whether a merge put
    the episode where it belongs."""
    frame = _model_frame(gt, model_id)
    if frame is None or not path:
        return {}
    inv = se2.inverse(frame)
    dist, deg, local = [], [], []
    g = episode.graph
    for sid in episode.states():
        d = g.nodes[sid]
        k = int(d.get("step", -1))
        if not 0 <= k < len(path) or path[k] is None:
            continue
        x, y = se2.apply_to_point(transform, d["x"], d["y"])
        tx, ty = se2.apply_to_point(inv, *path[k][:2])
        dist.append(math.hypot(x - tx, y - ty))
        off = tracking.offset(model_id, (tx, ty)) if tracking is not None else None
        if off is not None:
            local.append(math.hypot(x - tx - off[0], y - ty - off[1]))
        if len(path[k]) > 2:
            deg.append(abs(math.degrees(se2.angle_diff(d["theta"] + transform[2],
                                                        path[k][2] - frame[2]))))
    if not dist:
        return {}
    out = {"error_m": round(float(np.median(dist)), 3)}
    if deg:
        out["error_deg"] = round(float(np.median(deg)), 2)
    if local:
        out["local_error_m"] = round(float(np.median(local)), 3)
    return out


def _run_task(context: dict, task) -> Outcome:
    """An episode with the round's ``context``; its picture from above comes back as bytes
    (it may run on another machine) for :func:`run_variant` to write."""
    _ROUND.clear()
    _ROUND.update(context)
    *args, topdown = task
    if topdown is None:
        return run_episode(*args)
    with tempfile.TemporaryDirectory() as tmp:
        png = Path(tmp) / "topdown.png"
        outcome = run_episode(*args, topdown=str(png))
        if png.is_file():  # not every environment can draw itself from above
            outcome.files[topdown] = png.read_bytes()
    return outcome


def pre_explore(cfg: EvalConfig, scene: int, extractor_name: str
                ) -> tuple[AbstractModel, set[int], dict]:
    """One long frontier exploration of a house from its first episode's start: the
    pre-explored model of ``hp``/``sp`` (the paper explores 10000 steps; here until nothing is
    left to explore or ``cfg.pre_explore_steps``), the real instances it saw, and the true
    world (x, y) of its states (:func:`state_truth`)."""
    env = _env(cfg, scene)
    # no look-around: it finds a goal sooner, and the exploration turns all round anyway; with
    # it, a walk of val_00 ended walled in by its own collision marks after 51 steps
    agent = _make_agent(replace(cfg, agent=replace(cfg.agent, look_around=False)),
                        VARIANTS["ans"], env, None, extractor_name)
    # an environment with a writable step limit explores longer than one episode
    saved = getattr(env, "max_steps", None)
    if saved is not None:
        env.max_steps = cfg.pre_explore_steps
    try:
        seed = episode_seed(cfg.seed, scene, 10**6)
        obs, _info = env.reset(seed=seed, options={"episode": 0})
        name = scene_name(env, cfg, scene)
        agent.reset(None, seed=seed, scene=name, episode=scene * 1000 + 999,
                    model_id=f"{name}-pre")
        seen = seen_instances(obs)
        gt = _GroundTruth(env, name, 0)
        path = [gt.world_pose()]
        idle = 0
        stop = agent.actions.index("stop")
        for _ in range(cfg.pre_explore_steps):
            action = agent.act(obs)
            # (the look-around at the start has no target either)
            idle = idle + 1 if agent._target is None and agent.step_ > agent.actions.full_turn \
                else 0
            # a full turn with nothing left to explore
            if idle >= agent.actions.full_turn or action == stop:
                break
            obs, _r, term, trunc, _info = env.step(action)
            seen |= seen_instances(obs)
            path.append(gt.world_pose())
            if trunc or term:
                break
    finally:
        if saved is not None:
            env.max_steps = saved
    return agent.model_, seen, state_truth(agent.model_, path)


def _pre_task(_context, task) -> tuple[AbstractModel, set[int], dict]:
    return pre_explore(*task)


# ---------------------------------------------------------------------- scheduling
def _worker_init() -> None:
    _torch_threads(1)


def _torch_threads(n: int) -> int:
    """Set torch's intra-op threads; returns the previous count."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(n)
    return before


class _NoBar:
    def update(self, n: int) -> None:
        pass

    def close(self) -> None:
        pass


def _bar(total: int, desc: str, progress: bool):
    if not progress:
        return _NoBar()
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, unit="ep", dynamic_ncols=True)


def _episode_count(cfg: EvalConfig) -> list[int]:
    """Episodes per selected scene."""
    return [cfg.suite.episode_count(s, cfg.episodes) for s in cfg.scene_indices]


def _rounds_per_call(engine: Engine, houses: int) -> int:
    """Rounds one engine call may hold for a variant whose memory never changes between
    rounds (``ans``, ``oracle``, the pre-explored ones): enough to give every CPU two episodes,
    so a wide cluster is not idle waiting on a round of one episode per house. A variant that
    learns runs round by round: each round sees the memory the previous ones left."""
    return max(1, -(-2 * engine.slots() // max(houses, 1)))


def run_variant(cfg: EvalConfig, variant: Variant, extractor_name: str, out: Path | None,
                progress: bool = True, on_round: Callable[[list[dict]], None] | None = None,
                engine: Engine | None = None) -> tuple[list[dict], dict | None]:
    """All episodes of one variant, in the documented order, each round's on ``engine``
    (default: one made from ``cfg`` for this call); returns their records and, for a variant
    with memory, the fidelity of its memory at the end (:func:`memory_fidelity`)."""
    if engine is None:
        with make_engine(cfg.engine, cfg.workers, cfg.address, _worker_init) as engine:
            return run_variant(cfg, variant, extractor_name, out, progress, on_round, engine)
    scenes = cfg.scene_indices
    counts = dict(zip(scenes, _episode_count(cfg), strict=True))
    rounds = max(counts.values())
    store_dir = (memory_path(out, variant.name, cfg.store)
                 if (out is not None and variant.learns) else None)
    models: dict[str, AbstractModel] = {}
    seen: dict[str, set[int]] = {}  # per house, the real instances its episodes saw
    truth: dict[str, dict] = {}  # per house, the true world (x, y) of its recorded states
    threshold = (_threshold(cfg, _extractor(extractor_name, cfg.encoder_weights))
                 if variant.memory else None)
    if variant.memory == "pre":
        models, seen, truth = _pre_explored(cfg, extractor_name, out, progress, engine)
        for m in models.values():  # matched at this run's threshold
            m.relocation_threshold = threshold
    if store_dir is not None:  # (both kinds: a memory-map must not find a previous run's)
        for kind in STORES:
            _clear_store(memory_path(out, variant.name, kind))
        truth_path(out, variant.name).unlink(missing_ok=True)
    store = ModelStore(store_dir) if store_dir is not None else None
    stored: set[str] = set()  # ids of the models written to the store
    bar = _bar(sum(counts.values()), variant.name, progress)
    records: list[dict] = []
    step = 1 if variant.learns else _rounds_per_call(engine, len(scenes))
    try:
        for r0 in range(0, rounds, step):
            if r0 == 0 or variant.learns:  # pre-explored memories never change: index once
                context = {}
                if variant.memory:
                    context["memory"] = Memory(models, threshold=threshold)
                    context["truth"] = truth  # scoring only: where the stored states truly are
                    context["seen"] = seen  # scoring only: what the house's episodes had in view
                if variant.policy == "semantic":
                    context["cooccurrence"] = cooccurrence(models.values())
            tasks = [(cfg, variant, s, r, r, extractor_name, _topdown_path(cfg, out, variant, s, r))
                     for r in range(r0, min(r0 + step, rounds)) for s in scenes if r < counts[s]]
            outcomes = engine.map(_run_task, tasks, context, bar)
            for o in outcomes:
                for path, data in o.files.items():
                    Path(path).parent.mkdir(parents=True, exist_ok=True)
                    Path(path).write_bytes(data)
            if variant.learns:
                updated = []  # (outcome, the model its memory update changed)
                for o in outcomes:  # merges in scene order: the same with any worker count
                    changed, gone = absorb(models, o, cfg.forget_below,
                                           cfg.forget_label_share,
                                           _drift(cfg) if cfg.agent.relocation.joint else None)
                    seen.setdefault(o.record["scene"], set()).update(o.seen)
                    truth.setdefault(o.record["scene"], {}).update(o.truth)
                    updated.append((o, changed))
                    _write(store, stored, models, [changed], gone)
                if cfg.consolidate and updated:
                    joins = consolidate(models, [c for _, c in updated], threshold=threshold,
                                        config=cfg.agent.relocation,
                                        forget_below=cfg.forget_below,
                                        forget_label_share=cfg.forget_label_share,
                                        drift=(_drift(cfg) if cfg.agent.relocation.joint
                                               else None))
                    for j in joins:  # on the episode whose update changed one of the two
                        o = next((o for o, c in updated if c in (j.model_id, j.into)),
                                 updated[-1][0])
                        o.record.setdefault("joins", []).append(_join_fields(cfg, j))
                    _write(store, stored, models, sorted({j.into for j in joins} & set(models)),
                           [j.model_id for j in joins])
                if store_dir is not None:  # where the stored states truly are: scoring only
                    _write_truth(truth_path(out, variant.name), truth)
            for r in range(r0, min(r0 + step, rounds)):  # records and .part, round by round
                round_records = [o.record for o in outcomes if o.record["episode"] == r]
                records.extend(round_records)
                if on_round is not None:
                    on_round(round_records)
    finally:
        bar.close()
        _ROUND.clear()
    return records, (memory_fidelity(cfg, models, seen, truth) if variant.memory else None)


def memory_fidelity(cfg: EvalConfig, models: dict[str, AbstractModel],
                    seen: dict[str, set[int]], truth: dict[str, dict] | None = None) -> dict:
    """The memory scored against ground truth (:mod:`kgnav.benchmark.fidelity`), per house
    and pooled; None when the environment offers no ground truth for it (``scene_objects``,
    ``episode_start``). ``truth``: per house, the true world pose of the recorded states
    (:func:`state_truth`), for ``pose_error_m``: the stored states' position error after a
    rigid fit of each model, per house and pooled over every state of every house, and
    ``heading_error_deg``: their headings' error after the same fit; ``own_frame``: the
    object scores again with each model placed by that fit (the map's own frame,
    :func:`kgnav.benchmark.fidelity.alignment`) instead of its creating episode's start, and
    ``frame_error`` (per house, by model; pooled ``frame_error_m``: median and max over the
    models) how far apart the two frames are."""
    truth = truth or {}
    per_house, aligned = {}, {}
    residuals, headings, frame_errors = [], [], []
    for k in cfg.scene_indices:
        env = _env(cfg, k)
        objects = getattr(env, "scene_objects", None)
        if objects is None or not hasattr(env, "episode_start"):
            return None
        name = scene_name(env, cfg, k)
        gt = _GroundTruth(env, name, 0)
        mine = [(m, _model_frame(gt, mid)) for mid, m in sorted(models.items())
                if _house_of(mid) == name]
        per_house[name] = fidelity.score_memory(mine, objects(), seen.get(name),
                                                cfg.agent.goals.belief)
        house_truth = truth.get(name, {})
        r, h = fidelity.residuals((m for m, _ in mine), house_truth)
        per_house[name]["pose_error_m"] = fidelity.error_summary(r)
        per_house[name]["heading_error_deg"] = fidelity.error_summary(h)
        residuals.append(r)
        headings.append(h)
        own = fidelity.aligned_frames(mine, house_truth)
        aligned[name] = fidelity.score_memory(own, objects(), seen.get(name),
                                              cfg.agent.goals.belief)
        per_house[name]["own_frame"] = {key: aligned[name][key] for key in OWN_FRAME_KEYS}
        per_house[name]["frame_error"] = {
            m.model_id: fidelity.frame_error(m, start, at)
            for (m, start), (_, at) in zip(mine, own, strict=True) if at is not start}
        frame_errors += [e["error_m"] for e in per_house[name]["frame_error"].values()]
    pooled = fidelity.pooled(per_house)
    pooled["pose_error_m"] = fidelity.error_summary(
        np.concatenate(residuals) if residuals else ())
    pooled["heading_error_deg"] = fidelity.error_summary(
        np.concatenate(headings) if headings else ())
    own_pooled = fidelity.pooled(aligned)
    pooled["own_frame"] = {key: own_pooled[key] for key in OWN_FRAME_KEYS}
    pooled["frame_error_m"] = {
        "median": round(float(np.median(frame_errors)), 3) if frame_errors else None,
        "max": round(float(np.max(frame_errors)), 3) if frame_errors else None,
        "models": len(frame_errors)}
    return {"pooled": pooled, "houses": per_house}


def _topdown_path(cfg: EvalConfig, out: Path | None, variant: Variant, scene: int,
                  episode: int) -> str | None:
    if out is None or cfg.show is None or (scene, episode) != tuple(cfg.show):
        return None
    return str(out / "topdown" / f"{variant.name}_{scene:02d}_e{episode:03d}.png")


def _write(store: ModelStore | None, stored: set[str], models: dict[str, AbstractModel],
           changed: list[str], gone: list[str]) -> None:
    """Keep the run's store as the memory: ``changed`` models saved, ``gone`` ones deleted
    (those never saved, joined in the update that made them, are not there to delete)."""
    if store is None:
        return
    for mid in changed:
        store.save(models[mid])
        stored.add(mid)
    for mid in gone:
        if mid in stored:
            store.delete(mid)
            stored.discard(mid)


def _join_fields(cfg: EvalConfig, j: Join) -> dict:
    """A join of two stored models, for ``episodes.jsonl``: the models, the verification, and
    (scoring only) whether both are of one house and how far the join's transform is from the
    truth at the folded model's centre (``error_m``, ``error_deg``; a wrong join is one of two
    houses, or over 1 m or 30 degrees off)."""
    same = _house_of(j.model_id) == _house_of(j.into)
    out = {"model": j.model_id, "into": j.into, "transform": [round(v, 4) for v in j.transform],
           "inliers": round(j.inliers, 3), "conflicts": round(j.conflicts, 3),
           "same_house": same}
    if j.links:
        out["links"] = len(j.links)
    if same:
        scene = next((k for k in cfg.scene_indices
                      if scene_name(_env(cfg, k), cfg, k) == _house_of(j.into)), None)
        if scene is not None:
            gt = _GroundTruth(_env(cfg, scene), _house_of(j.into), 0)
            fa, fb = _model_frame(gt, j.into), _model_frame(gt, j.model_id)
            if fa is not None and fb is not None:
                truth = se2.compose(se2.inverse(fa), fb)
                c = j.centre
                ex, ey = se2.apply_to_point(j.transform, *c)
                tx, ty = se2.apply_to_point(truth, *c)
                out["error_m"] = round(math.hypot(ex - tx, ey - ty), 3)
                out["error_deg"] = round(math.degrees(se2.angle_diff(j.transform[2],
                                                                     truth[2])), 2)
    return out


def absorb(models: dict[str, AbstractModel], o: Outcome, forget_below: float = 0.0,
           forget_label_share: float = 0.0, drift: DriftModel | None = None
           ) -> tuple[str, list[str]]:
    """Fold an episode's :class:`Outcome` into the memory (in place):
    :func:`kgnav.benchmark.memory_update.absorb` with its model, the model it relocated
    into, the transform and its bridges (and, with ``drift``, the merged model's pose graph
    optimised again)."""
    return _absorb(models, o.model, into=o.matched, transform=o.transform, bridges=o.bridges,
                   forget_below=forget_below, forget_label_share=forget_label_share,
                   drift=drift)


STORES = ("directory", "ladybug")
#: The object scores repeated with each model in its own frame (``own_frame``).
OWN_FRAME_KEYS = ("objects", "precision", "trusted_precision", "recall", "copies")
LOCAL_RADIUS = 1.5  # m: the stored states that say where a model has a place


def memory_path(out: Path, name: str, store: str = "directory") -> Path:
    """Where a run writes the memory of variant ``name``: ``out/memory/NAME/`` of GraphML files,
    or the database ``out/memory/NAME.lbug`` (the hp/sp memory: ``pre-explored/`` or
    ``pre-explored/models.lbug``, beside its cache keys)."""
    return out / "memory" / (f"{name}.lbug" if store == "ladybug" else name)


def truth_path(out: Path, name: str) -> Path:
    """Where a run keeps the true world pose of the stored states of variant ``name``'s
    memory (``out/memory/NAME.truth.json``; the hp/sp memory keeps its own ``truth.json``
    beside its models): ground truth for scoring the memory afterwards, which the agent never
    reads."""
    return out / "memory" / f"{name}.truth.json"


def _write_truth(path: Path, truth: dict[str, dict]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_open(path, "w") as f:
        json.dump({h: {k: [round(float(v), 4) for v in t] for k, t in sorted(tr.items())}
                   for h, tr in sorted(truth.items())}, f)


def read_truth(path: Path) -> dict[str, dict[str, tuple]]:
    """:func:`truth_path`'s file (or the hp/sp memory's ``truth.json``), per house; empty when
    there is none or it does not read as one."""
    try:
        raw = json.loads(path.read_text(encoding="utf-8"))
        return {str(h): {str(k): tuple(float(v) for v in t) for k, t in tr.items()}
                for h, tr in raw.items()}
    except (OSError, ValueError, AttributeError, TypeError):
        return {}


def _clear_store(path: Path) -> None:
    """A fresh run starts from an empty memory: remove the models a previous run left."""
    if path.is_dir():
        for f in path.glob("*.graphml"):
            f.unlink()
    elif path.suffix == ".lbug":  # the database and what LadybugDB and the store keep beside it
        for f in path.parent.glob(path.name + "*"):
            if f.is_file():
                f.unlink()


def _pre_explored(cfg: EvalConfig, extractor_name: str, out: Path | None, progress: bool,
                  engine: Engine
                  ) -> tuple[dict[str, AbstractModel], dict[str, set[int]], dict[str, dict]]:
    """The hp/sp memory: one pre-explored model per house, built once per output directory;
    with the instances each walk saw and the true positions of its states (``truth.json``
    beside the models; a memory stored without it is scored without ``pose_error_m``)."""
    params = {"split": cfg.source_name, "scenes": cfg.scene_indices, "seed": cfg.seed,
              "forget": [cfg.forget_below, cfg.forget_label_share], "agent": asdict(cfg.agent),
              "steps": cfg.pre_explore_steps,
              "extractor": _extractor(extractor_name, cfg.encoder_weights).name,
              "segmenter": cfg.segmenter, "size": [cfg.width, cfg.height]}
    if cfg.env != DEFAULT_ENV:  # (kgnav's keys stay as they were: stored memories stay valid)
        params["env"] = cfg.env
    if cfg.noise_spec.active:  # a noisy walk makes another memory (noiseless keys unchanged)
        params["noise"] = cfg.noise_spec.text
    key = json.dumps(params, sort_keys=True)
    store_dir = out / "memory" / "pre-explored" if out is not None else None
    models_at = (store_dir / "models.lbug" if cfg.store == "ladybug" else store_dir
                 ) if store_dir is not None else None
    models: dict[str, AbstractModel] = {}
    seen: dict[str, set[int]] = {}
    truth: dict[str, dict] = {}
    stored = False  # this output directory already holds this memory
    if _CACHE.get("pre_key") == key:  # built by this process for another run: not rebuilt
        # (copies: a run sets its threshold on the models it uses; the stored memory is as built)
        models = {k: m.copy() for k, m in _CACHE["pre_models"].items()}
        seen = dict(_CACHE["pre_seen"])
        truth = dict(_CACHE["pre_truth"])
    if store_dir is not None and (store_dir / "params.json").is_file():
        if (store_dir / "params.json").read_text() == key:
            loaded, problems = ModelStore(models_at).load_all()
            try:
                saw = {h: set(v) for h, v in
                       json.loads((store_dir / "seen.json").read_text()).items()}
            except (OSError, ValueError, AttributeError, TypeError):
                saw = None
            if not problems and len(loaded) == len(cfg.scene_indices) and saw is not None:
                models, seen, stored = loaded, saw, True
                truth = read_truth(store_dir / "truth.json")
    if not models:
        bar = _bar(len(cfg.scene_indices), "pre-explore", progress)
        try:
            tasks = [(cfg, s, extractor_name) for s in cfg.scene_indices]
            for m, saw, tr in engine.map(_pre_task, tasks, {}, bar):
                if cfg.forget_below > 0 or cfg.forget_label_share > 0:
                    forget(m, cfg.forget_below, min_label_share=cfg.forget_label_share)
                models[m.model_id] = m
                seen[_house_of(m.model_id)] = saw
                truth[_house_of(m.model_id)] = tr
        finally:
            bar.close()
    if store_dir is not None and not stored:
        _clear_store(store_dir)
        _clear_store(store_dir / "models.lbug")
        store = ModelStore(models_at)
        for m in models.values():
            store.save(m)
        with atomic_open(store_dir / "seen.json", "w") as f:
            json.dump({h: sorted(v) for h, v in sorted(seen.items())}, f)
        with atomic_open(store_dir / "truth.json", "w") as f:
            json.dump(truth, f, sort_keys=True)
        with atomic_open(store_dir / "params.json", "w") as f:
            f.write(key)
    _CACHE["pre_key"] = key
    _CACHE["pre_models"] = {k: m.copy() for k, m in models.items()}
    _CACHE["pre_seen"] = seen
    _CACHE["pre_truth"] = truth
    return dict(models), dict(seen), dict(truth)


# ---------------------------------------------------------------------- whole benchmark
def summarize(records: Iterable[dict], seed: int = 0) -> dict[str, dict]:
    """Per variant: mean Success/SPL/SoftSPL/DTS, episodes, relocation rate and failures, the
    learning curve, (``vs_ans``) the paired difference in success and SPL against ``ans`` on
    the same episodes with a 95 % bootstrap interval, and, for a variant with memory, where
    its success is lost (:func:`where_lost`)."""
    records = list(records)
    by: dict[str, list[dict]] = {}
    for rec in records:
        by.setdefault(rec["variant"], []).append(rec)
    out = {}
    for name, recs in by.items():
        n = len(recs)
        reloc = [r for r in recs if r["relocated"]]
        out[name] = {
            "episodes": n,
            "success": sum(r["success"] for r in recs) / n,
            "spl": _mean(recs, "spl"),
            "softspl": _mean(recs, "softspl"),
            "dts": _mean(recs, "dts"),
            "relocation_rate": len(reloc) / n,
            "relocation_same_house": (sum(r["relocation"]["same_house"] for r in reloc)
                                      / len(reloc)) if reloc else None,
            "relocation_error_m": _median([r["relocation"].get("error_m") for r in reloc]),
            "relocation_local_m": _median([r["relocation"].get("local_error_m")
                                           for r in reloc]),
            "relocation_tracking_m": _median([r["relocation"].get("tracking_error_m")
                                              for r in reloc]),
            "relocation_tracking_local_m": _median([r["relocation"].get("tracking_local_m")
                                                    for r in reloc]),
            "relocation_step": _median([r["relocation"].get("step") for r in reloc]),
            **_later_relocation(recs),
            "late_merges": sum(1 for r in recs if "late_merge" in r),
            "wrong_merges": sum(1 for r in recs for m in _merges(r)
                                if not m["same_house"] or _wrong(m)),
            # ... judged against the model as stored, not against the truth: a model bent
            # by its creators' drift is scored by pose_error_m, not here again
            "wrong_merges_local": sum(1 for r in recs for m in _merges(r)
                                      if not m["same_house"] or _wrong(m, local=True)),
            "joins": sum(len(r.get("joins", ())) for r in recs),
            "wrong_joins": sum(1 for r in recs for j in r.get("joins", ())
                               if not j["same_house"] or _wrong(j)),
            "wrong_bridges": sum(1 for r in recs if any(True for _ in _merges(r))
                                 for b in r.get("bridges", ())
                                 if _house_of(b["model"]) != r["scene"] or _wrong(b)),
            "failures": {c: sum(r["failure"] == c for r in recs) for c in FAILURE_CLASSES},
            **learning_curve(recs),
        }
        if _has_memory(name):
            out[name].update(where_lost(recs))
            out[name]["hypotheses"] = hypotheses_summary(recs)
    for name, diff in paired_differences(records, "ans", seed=seed).items():
        out[name]["vs_ans"] = diff
    if "ans" in by:
        for name, recs in by.items():
            if name != "ans" and _has_memory(name):
                out[name]["goal_not_in_memory_vs_ans"] = _not_in_memory_vs_ans(
                    name, recs, by["ans"], seed)
    return out


def _has_memory(variant: str) -> bool:
    v = VARIANTS.get(variant)
    return v is not None and v.memory is not None


def learning_curve(recs: list[dict]) -> dict:
    """Success by episode index within a house (0: each house's first episode of the run),
    over the houses that ran that many; and success from a house's fifth episode on (None
    before): what a memory that keeps learning should raise."""
    by: dict[str, list[bool]] = {}
    for r in sorted(recs, key=lambda r: (r.get("scene", ""), r.get("episode", 0))):
        by.setdefault(r.get("scene", ""), []).append(bool(r["success"]))
    at: list[list[bool]] = []
    for outcomes in by.values():
        for i, ok in enumerate(outcomes):
            if i == len(at):
                at.append([])
            at[i].append(ok)
    late = [ok for outcomes in by.values() for ok in outcomes[4:]]
    return {"success_by_episode_index": [sum(v) / len(v) for v in at],
            "success_from_fifth_episode": sum(late) / len(late) if late else None}


def where_lost(recs: list[dict]) -> dict:
    """A memory variant's episodes split by whether the house's memory held a true instance
    of the goal as they started (``goal_in_memory``; episodes that cannot know are in
    neither part): episodes, success and SPL of each part; of the goal-in-memory ones, how
    many headed for a goal taken from memory, and why the others did not, counted. The
    goal-not-in-memory part is split again by whether the house's earlier episodes had had a
    true goal instance in view (``goal_seen_before``: the memory was near it and did not keep
    it), and the Exploration failures are counted by whether the goal came into view
    (``goal_in_view_step``: the segmenter did not recognise it) or never did."""
    held = [r for r in recs if r.get("goal_in_memory") is True]
    missing = [r for r in recs if r.get("goal_in_memory") is False]
    reasons = Counter(r.get("memory_goal_reason") for r in held)
    sources: Counter = Counter()
    for r in missing:
        sources.update(r.get("frontier_sources") or {})
    # scoring only: the goal-not-in-memory episodes whose house's earlier episodes had had a
    # true goal instance in view (perception missed it) and those whose had not (it was
    # never near); the Exploration failures whose goal came into view unrecognised
    missed = [r for r in missing if r.get("goal_seen_before") is True]
    unseen = [r for r in missing if r.get("goal_seen_before") is False]
    explored = [r for r in recs if r.get("failure") == "Exploration" and "goal_in_view_step" in r]
    return {"goal_in_memory": _part(held), "goal_not_in_memory": _part(missing),
            "goal_not_in_memory_seen_before": _part(missed),
            "goal_not_in_memory_never_seen": _part(unseen),
            "exploration_failures_goal_in_view": {
                "episodes": len(explored),
                "in_view": sum(r["goal_in_view_step"] is not None for r in explored)},
            "memory_goal_headed": sum(r.get("memory_goal_step") is not None for r in held),
            "memory_goal_reasons": {k: reasons[k] for k in MEMORY_GOAL_REASONS},
            # where the goal-not-in-memory episodes explored: beside unseen space, space seen
            # only from afar, or the episode's own frontiers
            "frontier_sources_goal_not_in_memory": dict(sorted(sources.items()))}


def _part(recs: list[dict]) -> dict:
    return {"episodes": len(recs),
            "success": sum(r["success"] for r in recs) / len(recs) if recs else None,
            "spl": _mean(recs, "spl") if recs else None}


def _not_in_memory_vs_ans(name: str, recs: list[dict], ans: list[dict], seed: int) -> dict:
    """The paired difference against ``ans`` over the episodes whose memory did not hold the
    goal (:func:`~kgnav.benchmark.stats.paired_differences`): what the memory gives beyond
    remembered objects. Numbers are None without pairs."""
    mine = [r for r in recs if r.get("goal_in_memory") is False]
    diff = paired_differences([*mine, *ans], "ans", seed=seed).get(name, {})
    empty = {"diff": None, "low": None, "high": None, "pairs": 0}
    return {m: {k: (None if isinstance(v, float) and math.isnan(v) else v)
                for k, v in diff.get(m, empty).items()} for m in METRICS}


def _merges(record: dict):
    """What an episode was merged into: its relocation, if merged, or its late match; judged
    by where the merge laid the episode's states (``placed``) where that is known, else by
    the transform where it was made."""
    if record.get("relocated") and record["relocation"].get("merged"):
        yield _as_merged(record["relocation"])
    if "late_merge" in record:
        yield _as_merged(record["late_merge"])


def _as_merged(fields: dict) -> dict:
    placed = fields.get("placed")
    return {**fields, **placed} if placed else fields


#: How a hypothesis stands against ground truth: into a model of this house and within 1 m
#: and 30 degrees (as merges are judged, :func:`_wrong`), into one of this house but farther
#: off, or into another house's model.
HYPOTHESIS_TRUTH = ("right", "wrong", "other_house")


def judged_hypotheses(gt: _GroundTruth, judged) -> dict[str, dict[str, int]]:
    """The hypotheses the loop judged (:attr:`~kgnav.agent.relocation.Relocalizer.hypotheses`)
    by truth (:data:`HYPOTHESIS_TRUTH`), each counted by outcome
    (:data:`~kgnav.agent.relocation.HYPOTHESIS_OUTCOMES`): whether an episode that never
    relocated was never offered the right place, or refused it. Hypotheses whose truth the
    environment cannot tell (no episode starts) are left out."""
    out = {t: Counter() for t in HYPOTHESIS_TRUTH}
    for step, model_id, T, at, _source, outcome in judged:
        if _house_of(model_id) != gt.name:
            out["other_house"][outcome] += 1
            continue
        err = _relocation_error(gt, model_id, T, at, step)
        if err:
            out["wrong" if _wrong(err) else "right"][outcome] += 1
    return {t: dict(sorted(c.items())) for t, c in out.items()}


#: m: an episode's step is on remembered ground when a stored state of its house stood this
#: close to where the agent truly was (:func:`memory_overlap`)
OVERLAP_RADIUS = 1.0


def memory_overlap(path, stored) -> float | None:
    """Share of an episode's true positions (``path``, world poses; None entries skipped)
    within :data:`OVERLAP_RADIUS` of the true position of a stored state of its house
    (``stored``, world poses): how much of the episode walked where the memory had been,
    so could have relocated. None without positions on both sides.

    >>> memory_overlap([(0, 0, 0), (0.5, 0, 0), (3, 0, 0), None], [(0.2, 0.1, 1.0)])
    0.667
    """
    walk = np.array([p[:2] for p in path if p is not None], float).reshape(-1, 2)
    where = np.array([p[:2] for p in stored], float).reshape(-1, 2)
    if not len(walk) or not len(where):
        return None
    near = np.zeros(len(walk), bool)
    for k in range(0, len(where), 2048):  # (memory: steps x a chunk of states at a time)
        d2 = ((walk[:, None, :] - where[None, k:k + 2048, :]) ** 2).sum(-1)
        near |= (d2 <= OVERLAP_RADIUS ** 2).any(axis=1)
    return round(float(near.mean()), 3)


def hypotheses_summary(recs: list[dict]) -> dict:
    """The episodes' :func:`judged_hypotheses` added up; and of the episodes that never
    relocated although the memory held a model of their house (``not_relocated``), how
    many were offered the right place at least once (``not_relocated_offered_right``) and
    how many of those refused it only for its geometry (``..._refused_geometry``: few
    points, geometry or conflict), and the median of their :func:`memory_overlap`
    (``not_relocated_overlap``)."""
    total = {t: Counter() for t in HYPOTHESIS_TRUTH}
    for r in recs:
        for t, c in (r.get("hypotheses") or {}).items():
            total[t].update(c)
    stuck = [r for r in recs if not r["relocated"] and "hypotheses" in r
             and r.get("house_models", 1) > 0]
    offered = [r for r in stuck if r["hypotheses"].get("right")]
    geometric = {"few points", "geometry", "conflict"}
    overlap = [r["memory_overlap"] for r in stuck if r.get("memory_overlap") is not None]
    return {"judged": {t: dict(sorted(c.items())) for t, c in total.items()},
            "not_relocated": len(stuck),
            # how much of them walked where the house's memory had been (median share)
            "not_relocated_overlap": float(np.median(overlap)) if overlap else None,
            "not_relocated_offered_right": len(offered),
            "not_relocated_refused_geometry": sum(
                1 for r in offered if set(r["hypotheses"]["right"]) <= geometric)}


def _wrong(fields: dict, local: bool = False) -> bool:
    """A frame transform more than 1 m or 30 degrees off the truth (``local``: 1 m off
    where the stored model has the place, where that is known)."""
    error = fields.get("local_error_m", fields.get("error_m", 0)) if local else \
        fields.get("error_m", 0)
    return error > 1.0 or abs(fields.get("error_deg", 0)) > 30


def _later_relocation(recs: list[dict]) -> dict:
    """Relocation rate over each house's episodes after its first: the lowest house's, and
    the mean over houses."""
    by: dict[str, list[bool]] = {}
    for r in sorted(recs, key=lambda r: (r.get("scene", ""), r.get("episode", 0))):
        by.setdefault(r.get("scene", ""), []).append(r["relocated"])
    rates = [sum(v[1:]) / len(v[1:]) for v in by.values() if len(v) > 1]
    if not rates:
        return {}
    return {"relocated_after_first_min": round(min(rates), 3),
            "relocated_after_first_mean": round(float(np.mean(rates)), 3)}


def _mean(recs: list[dict], key: str) -> float | None:
    """The mean of a metric over episodes; None if an episode lacks it (an environment
    without that ground truth): a mean over some episodes would not be comparable."""
    if any(r.get(key) is None for r in recs):
        return None
    return sum(r[key] for r in recs) / len(recs)


def _median(values) -> float | None:
    v = [x for x in values if x is not None]
    return float(np.median(v)) if v else None


def run_eval(cfg: EvalConfig, out: str | os.PathLike | None, progress: bool = True
             ) -> tuple[list[dict], dict]:
    """Run every variant of ``cfg``; with ``out``, write ``episodes.jsonl`` (one line per
    episode, rounds in order), ``summary.json`` (per variant) and ``config.json``.
    Returns (records, summary)."""
    cfg = with_env_weights(cfg)
    extractor_name = resolve_extractor(cfg.extractor, cfg.encoder_weights)
    check_domains(cfg, extractor_name)
    if cfg.agent.goals.remembered_floor and cfg.scene_indices:  # before any episode runs
        classes = _env(cfg, cfg.scene_indices[0]).env_spec.classes
        for cls, _ in cfg.agent.goals.remembered_floor:
            if cls not in classes:
                raise UnknownClassError(cls, classes)
    features = _extractor(extractor_name, cfg.encoder_weights).name  # weights' fingerprint
    out_dir = Path(out) if out is not None else None
    engine = make_engine(cfg.engine, cfg.workers, cfg.address, _worker_init)
    part = None
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
        # results go to a side file first: a crash keeps what finished, and an earlier
        # complete run stays intact until this one completes
        part = open(out_dir / "episodes.jsonl.part", "w", encoding="utf-8")  # noqa: SIM115

    def write(recs: list[dict]) -> None:
        if part is not None:
            for rec in recs:
                part.write(json.dumps(rec, sort_keys=True) + "\n")
            part.flush()

    records: list[dict] = []
    timing = {}
    threads = _torch_threads(1)  # the networks run best on one thread per process
    try:
        for name in cfg.variants:
            t0 = time.perf_counter()
            recs, memory = run_variant(cfg, with_policy(VARIANTS[name], cfg.policy),
                                       extractor_name, out_dir, progress, write, engine)
            dt = time.perf_counter() - t0
            timing[name] = {"seconds": round(dt, 2),
                            "episodes_per_second": round(len(recs) / dt, 4) if dt > 0 else None}
            if memory is not None:
                timing[name]["memory"] = memory
            records.extend(recs)
        execution = {**{k: getattr(cfg, k) for k in EXECUTION}, **engine.describe()}
    finally:
        engine.close()
        _torch_threads(threads)
        if part is not None:
            part.close()
    summary = summarize(records, cfg.seed)
    for name, t in timing.items():
        summary[name].update(t)
    if out_dir is not None:
        os.replace(out_dir / "episodes.jsonl.part", out_dir / "episodes.jsonl")
        with atomic_open(out_dir / "summary.json", "w") as f:
            json.dump(summary, f, indent=2, sort_keys=True)
        with atomic_open(out_dir / "config.json", "w") as f:
            settings = {k: v for k, v in asdict(cfg).items() if k not in EXECUTION}
            json.dump({**settings, "extractor": extractor_name, "features": features,
                       "noise_model": cfg.noise_spec.to_dict(), "execution": execution}, f,
                      indent=2, sort_keys=True)
        write_plots(records, summary, cfg, out_dir)
    return records, summary


def write_plots(records: list[dict], summary: dict, cfg: EvalConfig, out_dir: Path) -> list[Path]:
    """The figures of a run, as PNG files in ``out_dir``; returns their paths."""
    import cv2

    from kgnav.benchmark import plots

    paths = [out_dir / "success_curve.png", out_dir / "failures.png"]
    plots.success_curve(records, paths[0])
    plots.failure_bars(summary, paths[1])
    if cfg.show is not None:
        scene, ep = cfg.show
        imgs = {}
        for name in cfg.variants:
            f = out_dir / "topdown" / f"{name}_{scene:02d}_e{ep:03d}.png"
            if f.is_file():
                imgs[name] = cv2.cvtColor(cv2.imread(str(f)), cv2.COLOR_BGR2RGB)
        pair = {k: imgs[k] for k in ("ans", "si")} if {"ans", "si"} <= imgs.keys() else imgs
        if pair:
            p = out_dir / f"topdown_{scene:02d}_e{ep:03d}.png"
            plots.side_by_side(pair, p, f"{cfg.source_name} scene {scene}, episode {ep}")
            paths.append(p)
    return paths
