"""The ObjectNav agent: the paper's per-step cycle, wiring the parts and nothing more.

1. **Knowledge extraction**: segment the RGB-D frame, extract the state features and the range
   profile, build the abstract state ``s = <F_s, C_s, {F_s,c}>``.
2. **Knowledge modelling**: fuse the frame into the episode map; add ``s`` and the transition
   ``(s_prev, a, s)`` to the current Abstract Model; with a memory, let the
   :class:`~kgnav.agent.relocation.Relocalizer` propose and verify relocations; on one, merge
   the current model into the matched one (which becomes the current model) and seed the
   episode map with what that model saw of the place.
3. **Reasoning**: if the current model holds a trusted object of the goal class
   (:mod:`kgnav.agent.goals`), head for it; otherwise explore with the global policy; plan
   with Fast Marching; act. Before stopping at an object, see it again from close range.

With a memory, the *hard* strategy trusts a remembered goal point and stops there; the *soft*
strategy searches an area around it, of a radius proportional to the distance from the agent at
the match to the goal, and keeps watching the live segmentation for the goal on the way.
:meth:`AgentConfig.paper` gives the paper's own settings.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from kgnav.agent.camera import Camera
from kgnav.agent.features import FeatureExtractor
from kgnav.agent.goals import GoalConfig, choose_goal, trusts
from kgnav.agent.mapping import EpisodeMap, MapBuilder
from kgnav.agent.memory import Memory
from kgnav.agent.planner import FMMPlanner, Plan
from kgnav.agent.policy import FrontierPolicy, GlobalPolicy
from kgnav.agent.relocation import Relocalizer, Relocation, RelocationConfig
from kgnav.agent.segmentation import Segmentation
from kgnav.agent.state_creator import AbstractState, StateCreator
from kgnav.common import se2
from kgnav.common.classes import OBJECT_CLASSES
from kgnav.envs.spec import ActionSpec, EnvSpecError
from kgnav.errors import UnknownClassError
from kgnav.memory.evidence import ScanTable, belief, object_evidence
from kgnav.memory.merge import merge
from kgnav.memory.model import AbstractModel
from kgnav.memory.posegraph import bend

STRATEGIES = ("hard", "soft")
SOFT_SEARCHES = ("direct", "area")
LIVE_OVERRIDES = ("always", "belief")

#: Why an episode with a memory never headed for a goal taken from it
#: (:meth:`ObjectNavAgent.memory_goal_reason`), decided from what the agent knew. Across
#: several relocations the one that came closest to the remembered goal is given: the order of
#: :data:`_CLOSEST_FIRST`.
MEMORY_GOAL_REASONS = (
    "not_relocated",  # never relocated into a stored model
    "relocated_too_late",  # relocated, but never chose a target while relocated
    "goal_seen_in_episode",  # headed for a remembered goal-class object this episode had
    # itself perceived first (an "episode" target, not a "memory" one)
    "live_detection_preferred",  # the relocated model held a goal the rules trust, but the
    # agent headed for a closer object it had perceived itself
    "goal_in_other_model",  # the relocated model held no trusted goal; another model the
    # episode's views matched (a feature-space hypothesis or a bridge) did
    "belief_below_threshold",  # the relocated model held the goal class, none trusted
    "goal_not_in_relocated_model",  # it held no object of the class, nor did the other
    # models matched hold a trusted one
    "other",  # a trusted remembered goal at the end the loop never chose (evidence moved)
)
_CLOSEST_FIRST = ("goal_seen_in_episode", "live_detection_preferred", "other",
                  "goal_in_other_model", "belief_below_threshold",
                  "goal_not_in_relocated_model", "relocated_too_late")

__all__ = ["MEMORY_GOAL_REASONS", "AgentConfig", "EpisodeLog", "MemoryPeriod",
           "ObjectNavAgent", "Percept", "Relocation", "Target"]


@dataclass(frozen=True)
class AgentConfig:
    """Tunable behaviour. Distances in metres. The defaults are the best settings found on the
    ``train`` houses; :meth:`paper` returns the paper's."""

    stop_distance: float = 0.8  # call stop this close to a goal point (success is 1 m)
    explore_interval: int = 25  # steps between global-policy decisions (the paper's 25)
    explore_radius: float = 0.25  # an exploration goal counts as reached this close
    strategy: str = "soft"  # with memory: "hard" or "soft"
    soft_search: str = "direct"  # "direct": to the point, confirm, let evidence decide;
    # "area" (the paper): search an area around it whose radius grows with the distance
    soft_radius_factor: float = 0.25  # area search radius per metre from match to goal
    soft_radius_bounds: tuple[float, float] = (1.0, 3.0)
    live_override: str = "belief"  # soft: a live goal replaces a remembered one only when the
    # evidence believes it at least as much ("belief"), or "always" (the paper)
    stall_steps: int = 40  # steps without progress toward an object before giving it up
    # ... and, within 1 m of an object it saw itself (success is 1 m), before stopping there
    # (0: stall_steps). Pressed against furniture round the goal, an agent only drifts off
    # while it waits; but 10 left train's success as it was (1 won, 1 lost: docs/agent.md)
    near_stall_steps: int = 0
    # an object is given up when the map makes the way round to it longer twice while that
    # way is over this many times the straight line to it (plus 2 m): a growing detour is a
    # stall, not a way to walk to the step limit (0: off; one long way round is still walked)
    detour_ratio: float = 0.0
    goals: GoalConfig = field(default_factory=GoalConfig)
    relocation: RelocationConfig = field(default_factory=RelocationConfig)
    seed_map: bool = True  # after a relocation, plan with what the stored model saw
    # ... and explore beyond it: the frontiers of space neither the agent nor the memory saw
    # come first (False: the memory's seen space vouches for no absence; explore as without it)
    explore_beyond_memory: bool = True
    # ... and among the space it saw, prefer what it saw only from afar (beyond 3 m, where a
    # segmenter misses much) to the agent's own frontiers (kgnav.agent.policy.FrontierPolicy;
    # off: calibration houses gained, val did not, docs/agent.md)
    search_memory: bool = False
    unknown_speed: float = 0.5  # ... and count space neither it nor the agent saw this much
    # slower than known free space (1: no preference for the way the memory knows)
    prior_inflation: float | None = None  # m the remembered obstacles grow by for the
    # agent's centre (None: as much as its own; kgnav.agent.planner.FMMPlanner)
    confirm_distance: float = 2.5  # see an object this close before stopping at it (0: off)
    confirm_steps: int = 8  # turns spent looking for it on arrival before giving it up
    # ... and a close view confirms only when the segmenter scored it at least this; an object
    # seen close but never this confidently is given up after those turns, whatever the
    # evidence: a segmenter's persistent mistake (a cabinet read as a sofa) recurs from every
    # side, with views and belief to match, but is seldom scored high up close (0: any)
    confirm_score: float = 0.0
    map_size: int = 480  # starting side in cells; the map grows
    look_around: bool = True  # turn a full circle before the first move (turns cost no path
    # length); with a memory, the turn ends once a relocation is accepted
    map_resolution: float = 0.05
    # the segmenter's segments scoring at least this but under its detection threshold are
    # stored as weak views of the objects they see (None: off); what they are worth to the
    # belief in an object is goals.belief's weak_weight (kgnav.memory.evidence)
    weak_score: float | None = None
    # when the model relocated into holds no goal the rules trust, head for one of another
    # stored model this episode verifiably reached too (a bridge, not ambiguous), through
    # that bridge's transform: a house's memory split over two models is still one memory
    bridged_goals: bool = True

    def __post_init__(self):
        if self.live_override not in LIVE_OVERRIDES:
            raise ValueError(f"live_override must be one of {LIVE_OVERRIDES}, "
                             f"got {self.live_override!r}")
        if self.strategy not in STRATEGIES:
            raise ValueError(f"strategy must be one of {STRATEGIES}, got {self.strategy!r}")
        if not 0 < self.unknown_speed <= 1:
            raise ValueError(f"unknown_speed must be in (0, 1], got {self.unknown_speed}")
        if self.prior_inflation is not None and not 0 <= self.prior_inflation < math.inf:
            raise ValueError(f"prior_inflation must be None or a finite length >= 0 m, "
                             f"got {self.prior_inflation}")
        if not 0 <= self.confirm_score <= 1:
            raise ValueError(f"confirm_score must be in [0, 1], got {self.confirm_score}")
        if self.detour_ratio < 0 or 0 < self.detour_ratio < 1:
            raise ValueError(f"detour_ratio must be 0 (off) or at least 1, "
                             f"got {self.detour_ratio}")
        if self.soft_search not in SOFT_SEARCHES:
            raise ValueError(f"soft_search must be one of {SOFT_SEARCHES}, "
                             f"got {self.soft_search!r}")

    @classmethod
    def paper(cls, **overrides) -> AgentConfig:
        """The paper's settings: goal = closest of the five most-seen objects (seen once is
        enough), relocation on the first feature match with no verification, no landmark
        checks, no remembered geometry, stop on arrival."""
        base = cls(goals=GoalConfig(rule="views", min_views=1, keep_margin=0.0),
                   relocation=RelocationConfig(geometry=False, confirm_matches=1,
                                               landmark_radius=0.0, bridge_interval=0,
                                               unique=False, merge_check=False,
                                               late_match=False, scan_search=0,
                                               late_search=0),
                   seed_map=False, unknown_speed=1.0, confirm_distance=0.0, soft_search="area",
                   live_override="always", look_around=False, bridged_goals=False)
        return replace(base, **overrides)


PRESETS = {"default": AgentConfig, "paper": AgentConfig.paper}


@dataclass
class Target:
    """Where the agent is heading. ``source``: ``explore`` (global policy), ``episode`` (an
    object this episode perceived), ``memory`` (an object only a stored model knows) or
    ``live`` (the goal in the current frame)."""

    source: str
    point: tuple[float, float]  # episode frame
    object_id: str | None = None
    radius: float = 0.0  # soft strategy: the search area around a remembered goal
    stage: str = "area"  # soft strategy: the area, look around; the point; "commit": stop there
    scan_left: int | None = None
    seen_close: bool = False  # seen from within confirm_distance while heading for it
    close_score: float = 0.0  # the best score of those close views (confirm_score)
    detours: int = 0  # times the way to it grew while already a detour (detour_ratio)

    @property
    def key(self):
        return (self.source, self.object_id, self.point, self.stage)

    @property
    def is_object(self) -> bool:
        return self.source != "explore"


@dataclass
class Percept:
    """Output of knowledge extraction for one step."""

    segmentation: object
    state: AbstractState
    depth: np.ndarray
    columns: np.ndarray  # per image column, the range to the first obstacle


@dataclass
class MemoryPeriod:
    """A stretch of the episode spent relocated into one stored model, kept so that the end of
    the episode can say why no remembered goal was headed for
    (:meth:`ObjectNavAgent.memory_goal_reason`): references to what the agent reasoned with,
    nothing recomputed while it acts."""

    step: int  # when the relocation was accepted
    model_id: str
    model: AbstractModel  # the merged model the agent reasoned with
    seen: set  # its objects this episode perceived (the agent's own set, updated in place)
    scans: ScanTable  # its range profiles (the evidence's misses)
    reasoned: bool = False  # a target was chosen at least once while relocated
    perceived: set = field(default_factory=set)  # object targets it had perceived itself


@dataclass
class EpisodeLog:
    """What the agent did, for metrics and failure analysis."""

    targets: list[tuple[int, str, float, float, str | None]] = field(default_factory=list)
    rejected: list[str] = field(default_factory=list)
    stop_reason: str | None = None
    undone: list[Relocation] = field(default_factory=list)  # relocations landmarks refuted
    periods: list[MemoryPeriod] = field(default_factory=list)  # one per relocation accepted
    frontier_sources: dict[str, int] = field(default_factory=dict)  # exploration targets by
    # where the policy found them (FRONTIER_SOURCES; "policy": a policy that does not say)
    detour_drops: list[tuple[int, str | None]] = field(default_factory=list)  # (step, object)
    # given up because the way round kept growing (AgentConfig.detour_ratio)
    unconfirmed: list[tuple[int, str | None, float]] = field(default_factory=list)  # (step,
    # object, best close score): given up on arrival, seen close but never confidently


class ObjectNavAgent:
    """The with- or without-memory ObjectNav agent.

    ``memory`` (a :class:`Memory`) turns on relocation and reuse; without it this is the
    paper's memory-less ANS* baseline, still learning an Abstract Model of the episode
    (``model_``). ``classes`` is the object vocabulary of the map and the models; a segmenter
    labelling another one (its ``classes`` or ``class_names``) is mapped to it by name, its
    other classes dropped. ``actions``: the environment's action indices and geometry:
    look-arounds, escapes and the bump threshold derive from its step and turn angle;
    ``agent_radius`` (m) is what the planner keeps off obstacles.
    :meth:`for_env` takes camera, vocabulary and actions from an environment's spec.
    """

    def __init__(
        self,
        camera: Camera,
        segmenter,
        extractor: FeatureExtractor,
        *,
        policy: GlobalPolicy | None = None,
        planner: FMMPlanner | None = None,
        memory: Memory | None = None,
        config: AgentConfig | None = None,
        classes: Sequence[str] = OBJECT_CLASSES,
        actions: ActionSpec | None = None,
        agent_radius: float = 0.18,
    ):
        self.camera = camera
        self.segmenter = segmenter
        if hasattr(segmenter, "weak_score"):  # its sub-threshold segments, if asked for
            segmenter.weak_score = (config or AgentConfig()).weak_score
        self.extractor = extractor
        self.classes = tuple(classes)
        self.actions = actions or ActionSpec()
        self._relabel = _vocabulary_map(segmenter, self.classes)
        # a heading within half a turn of the goal cannot be improved by turning
        self._aim_tolerance = max(20.0, self.actions.turn_deg / 2 + 1.0)
        self.policy = policy or FrontierPolicy()
        self.memory = memory
        self.config = config or AgentConfig()
        # how a memory steers exploration is the agent's setting, whatever the policy's own
        if hasattr(self.policy, "beyond_memory"):
            self.policy.beyond_memory = self.config.explore_beyond_memory
        if hasattr(self.policy, "search_memory"):
            self.policy.search_memory = self.config.search_memory
        for cls, _ in self.config.goals.remembered_floor:  # a typo would silently do nothing
            if cls not in self.classes:
                raise UnknownClassError(cls, self.classes)
        self.planner = planner or FMMPlanner(agent_radius=agent_radius,
                                             turn_tolerance_deg=self._aim_tolerance,
                                             unknown_speed=self.config.unknown_speed,
                                             prior_inflation=self.config.prior_inflation)
        self.map_builder = MapBuilder(camera, self.config.map_size, self.config.map_resolution,
                                      classes=self.classes)
        self.state_creator = StateCreator(camera, obstacle_band=self.map_builder.obstacle_band)
        self.relocalizer = (Relocalizer(memory, self.config.relocation)
                            if memory is not None else None)

    @classmethod
    def for_env(cls, spec, segmenter, extractor: FeatureExtractor, **kw) -> ObjectNavAgent:
        """An agent with the camera, class vocabulary and actions an environment declares
        (its :class:`~kgnav.envs.EnvSpec`, or the environment itself)."""
        spec = getattr(spec, "env_spec", spec)
        return cls(Camera.from_spec(spec.camera), segmenter, extractor,
                   classes=spec.classes, actions=spec.actions,
                   agent_radius=spec.agent_radius, **kw)

    # ------------------------------------------------------------------ episode
    def reset(self, goal_class: str | None, *, seed: int = 0, scene: str = "",
              episode: int = 0, model_id: str | None = None) -> None:
        if goal_class is not None and goal_class not in self.classes:
            raise UnknownClassError(goal_class, self.classes)
        self.goal = goal_class
        self.episode = int(episode)
        self.segmenter.reset(seed, scene)
        self.policy.reset(seed)
        self.planner.reset()
        if self.relocalizer is not None:
            self.relocalizer.reset()
        self.map_: EpisodeMap = self.map_builder.reset()
        self.model_ = AbstractModel(self.extractor.dim, model_id=model_id,
                                    extractor=self.extractor.name, scan=self.state_creator.scan,
                                    classes=self.classes,
                                    relocation_threshold=(self.memory.threshold
                                                          if self.memory is not None else None))
        self.current_: AbstractModel = self.model_  # the merged model after a relocation
        self._scans = ScanTable(self.model_)  # range profiles of current_'s states
        self._evidence: dict = {}  # goal candidates' evidence, recounted every few states
        self._bridged: dict[str, tuple] = {}  # bridged model -> (usable, ScanTable, evidence)
        self.log_ = EpisodeLog()
        self.step_ = 0
        self._prev: tuple[str, str] | None = None  # (state in model_, state in current_)
        self._prev_pose: tuple[float, float, float] | None = None
        self._last_action: str | None = None
        self._seen_here: set[str] = set()  # current_ objects perceived in this episode
        self._target: Target | None = None
        self._explore_age = 0
        self._best = (math.inf, 0)  # closest approach to the object target, and when
        self._bumps = 0  # consecutive blocked forward moves
        self._escape: list[str] = []  # scripted way out after repeated bumps

    @property
    def relocation_(self) -> Relocation | None:
        """The relocation standing in this episode (model, state, distance, transform)."""
        return self.relocalizer.relocation if self.relocalizer is not None else None

    def act(self, obs) -> int:
        """One step of the paper's cycle; returns the environment's action index."""
        percept = self.extract(obs)
        self.model_knowledge(percept)
        action = self.reason(percept)
        self._last_action = action
        self.step_ += 1
        return self.actions.index(action)

    # ------------------------------------------------------------------ 1. extraction
    def extract(self, obs) -> Percept:
        seg = self.segmenter(obs["rgb"], obs["depth"], obs.get("semantic"))
        if self._relabel is not None:
            seg = _relabel(seg, self._relabel, self.classes)
        features = self.extractor(obs["rgb"])
        columns = self.camera.column_ranges(obs["depth"], self.map_builder.obstacle_band)
        state = self.state_creator(features, seg, obs["depth"], obs["pose"], columns)
        return Percept(seg, state, obs["depth"], columns)

    # ------------------------------------------------------------------ 2. modelling
    def model_knowledge(self, p: Percept) -> None:
        pose = p.state.pose
        self.map_builder.update(p.depth, pose, p.segmentation)
        if (self._last_action == "move_forward" and self._prev_pose is not None
                and math.dist(pose[:2], self._prev_pose[:2]) < self.actions.bump_distance):
            self.planner.note_collision(self.map_, self._prev_pose)
            self._bumps += 1
        elif self._last_action == "move_forward":
            self._bumps = 0
        self._prev_pose = pose

        s = p.state
        sid = self.model_.add_state(s.features, pose, s.detections + s.weak,
                                    episode=self.episode, step=self.step_, ranges=s.ranges)
        cur = sid
        reloc = self.relocalizer
        if self.relocation_ is not None:
            if reloc.check(s, self.step_, self.model_):
                reloc.refine(s)
                cur = self._add_to_current(s)
            else:
                self._undo()
        elif self.current_ is self.model_:
            self._note_scan(sid)
        if self._prev is not None and self._last_action is not None:
            self.model_.add_transition(self._prev[0], self._last_action, sid)
            if (self.current_ is not self.model_ and cur is not None
                    and self._prev[1] is not None):
                self.current_.add_transition(self._prev[1], self._last_action, cur)
        self._prev = (sid, cur)
        if self.current_ is self.model_:
            self._seen_here.update(self.model_.graph.successors(sid))
        if reloc is not None:
            new = reloc.observe(self.step_, s, self.state_creator.scan, self.model_)
            if new is not None:
                self._relocated(new, sid)

    def _relocated(self, r: Relocation, sid: str) -> None:
        stored = self.memory.model(r.model_id)
        self.current_ = merge(stored, self.model_, transform=r.transform)
        self._scans = ScanTable(self.current_)
        self._evidence = {}
        # objects of the merged model that this episode perceived: those merged from model_
        prefix = f"{self.model_.model_id}/"
        self._seen_here = {
            o for o in self.current_.objects()
            if any(s.startswith(prefix) for s in self.current_.graph.nodes[o]["origin"].split())
        }
        self._prev = (sid, self.current_.known_node(f"{prefix}{sid}"))
        self._target = None  # re-decide with the knowledge just gained
        self.log_.periods.append(MemoryPeriod(r.step, r.model_id, self.current_,
                                              self._seen_here, self._scans))
        if self.config.seed_map:
            geo = self.memory.geometry(r.model_id)
            if geo is not None:
                self.map_builder.seed(geo.grid, r.transform)
        if getattr(self.policy, "remembered", False):  # a policy that searches near them
            self.map_.prior_objects = remembered_objects(stored, r.transform,
                                                         self.config.goals.belief)

    def _undo(self) -> None:
        """Back to the episode's own model: the relocation was refuted."""
        self.log_.undone.append(self.relocalizer.undone[-1])
        self.current_ = self.model_
        self._scans = ScanTable(self.model_)
        self._evidence = {}
        self._seen_here = set(self.model_.objects())
        self._prev = (self._prev[0], self._prev[0]) if self._prev else None
        self.log_.rejected = []  # object ids of the merged model, meaningless now
        self._target = None
        self.map_.forget_prior()

    def _note_scan(self, sid: str) -> None:
        d = self.current_.graph.nodes[sid]
        if "ranges" in d and (not self._scans.ids or self._scans.ids[-1] != sid):
            self._scans.add(sid, (d["x"], d["y"], d["theta"]), d["ranges"])

    def _to_model(self, pose) -> tuple[float, float, float]:
        return se2.compose(self.relocation_.transform, pose)

    def _add_to_current(self, state: AbstractState) -> str:
        T = self.relocation_.transform
        dets = [replace(d, position=(*se2.apply_to_point(T, *d.position[:2]), d.position[2]))
                for d in state.detections + state.weak]
        cur = self.current_.add_state(state.features, self._to_model(state.pose), dets,
                                      episode=self.episode, step=self.step_,
                                      ranges=state.ranges)
        self._note_scan(cur)
        self._seen_here.update(self.current_.graph.successors(cur))
        return cur

    def mergeable(self) -> Relocation | None:
        """The relocation to merge this episode's model with at its end (possibly one found
        only now, from the whole episode), or None to store it as a new model (see
        :meth:`Relocalizer.mergeable`)."""
        if self.relocalizer is None:
            return None
        r = self.relocalizer.mergeable(self.model_)
        if r is None:
            # stored as a new model: its drift corrected by its loops on itself, if any
            self.relocalizer.close_own_loops()
        # drift corrected by the episode's loop closures (only with a drift model set); the
        # raw odometry and the closures' links are kept first, for the stored model's pose
        # graph to use again at this and every later merge
        self.model_.add_odometry(self.relocalizer.odometry_records(self.model_))
        T = r.transform if r is not None else (0.0, 0.0, 0.0)
        links = (self.relocalizer.closure_links(self.model_, r.model_id)
                 if r is not None else {})
        poses = self.relocalizer.corrected_poses(self.model_, T)
        if poses:
            bend(self.model_, poses)
            mid = self.model_.model_id
            self.model_.add_loop_closures(
                {"state": f"{mid}/{sid}", "episode": self.episode, "kept": kept,
                 **self._link(links.get(f"{mid}/{sid}") if kept else None)}
                for sid, kept in self.relocalizer.closure_states(self.model_))
        return r

    @staticmethod
    def _link(link) -> dict:
        return {} if link is None else {"to": link[0], "rel": link[1]}

    # ------------------------------------------------------------------ 3. reasoning
    @property
    def _soft(self) -> bool:
        return self.memory is not None and self.config.strategy == "soft"

    def reason(self, p: Percept) -> str:
        if self._bumps >= 3 and not self._escape:
            # stuck against something the map misses: turn away 90° (alternating sides), step
            turn = "turn_right" if (self._bumps // 3) % 2 else "turn_left"
            self._escape = [turn] * self.actions.turns(90) + ["move_forward"]
        if self._escape:
            return self._escape.pop(0)
        if (self.config.look_around and self.step_ < self.actions.full_turn
                and self.relocation_ is None and self._target is None):
            self._choose_target(p, explore=False)  # a goal in view ends the turn
            if self._target is None:
                return "turn_left"
        target = self._choose_target(p)
        for _ in range(3):  # a target reached or given up is replaced within the step
            if target is None:
                return "turn_left"  # nothing known and nothing left to explore: look around
            self._note_close(target, p)
            plan = self.planner.plan(self.map_, p.state.pose, self._goal_mask(target),
                                     key=target.key)
            action = (self._approach(target, plan, p) if target.is_object
                      else self._explore(plan))
            if action is not None:
                return action
            target = self._choose_target(p)
        return "turn_left"

    def _explore(self, plan: Plan) -> str | None:
        if plan.reached or not math.isfinite(plan.distance):
            self._target = None
            self._explore_age = 0
            return None
        return plan.action

    def _note_close(self, target: Target, p: Percept) -> None:
        """Whether the goal was seen near the target point from close range in this frame
        (where segmenters are most reliable)."""
        limit = self.config.confirm_distance
        if target.seen_close or not target.is_object or limit <= 0:
            return
        for d in p.state.detections:
            if (d.cls == self.goal and d.distance <= limit
                    and math.dist(d.position[:2], target.point) <= 1.0 + d.radius):
                target.close_score = max(target.close_score, float(d.score))
        target.seen_close = (target.close_score > 0
                             and target.close_score >= self.config.confirm_score)

    def _approach(self, target: Target, plan: Plan, p: Percept) -> str | None:
        if plan.reached:
            if (target.source == "memory" and self._soft and target.stage != "commit"
                    and self.config.soft_search == "area"):
                return self._search(target)
            trusted = target.source == "memory" and (self.config.strategy == "hard"
                                                     or target.stage == "commit")
            if self.config.confirm_distance > 0 and not target.seen_close and not trusted:
                return self._confirm(target, p)
            self.log_.stop_reason = f"reached {target.source} goal"
            return "stop"
        if not math.isfinite(plan.distance):
            return self._drop(target)
        longer = plan.distance > self._best[0] + 1.0  # the map revealed a longer way round
        if longer and self._detour(target, plan, p):
            target.detours += 1
            if target.detours >= 2:  # the way round grew twice past the limit: give it up
                self.log_.detour_drops.append((self.step_, target.object_id))
                return self._drop(target)
        if plan.distance < self._best[0] - 0.1 or longer:
            # progress, or the map revealed a longer way round: measure from here
            self._best = (plan.distance, self.step_)
            return plan.action
        stalled = self.step_ - self._best[1]
        near = math.dist(p.state.pose[:2], target.point) <= 1.0 and target.source != "memory"
        if near and stalled > (self.config.near_stall_steps or self.config.stall_steps):
            self.log_.stop_reason = f"stalled near {target.source} goal"
            return "stop"
        if stalled > self.config.stall_steps:
            return self._drop(target)
        return plan.action

    def _detour(self, target: Target, plan: Plan, p: Percept) -> bool:
        """Whether the way to ``target`` is so much longer than the straight line that it
        should not grow again: each wall the map reveals on an optimistic way through unseen
        space makes the next way round longer, and walking them one after another can take
        the agent to the step limit a few metres from the goal."""
        ratio = self.config.detour_ratio
        return ratio > 0 and plan.distance > ratio * math.dist(p.state.pose[:2],
                                                               target.point) + 2.0

    def _confirm(self, target: Target, p: Percept) -> str | None:
        """At an object not yet seen from close range: turn toward it for a few steps. If it
        does not show, the evidence decides: those looks count against it, and if the model
        (with its memory) still believes in it — an object the segmenter often misses, seen
        many times before — the agent stops there; otherwise it gives it up (likely a
        false positive seen from afar)."""
        if target.scan_left is None:
            target.scan_left = self.config.confirm_steps
        target.scan_left -= 1
        if target.scan_left < 0:
            if target.close_score > 0:  # seen close, never confidently: a persistent mistake
                self.log_.unconfirmed.append((self.step_, target.object_id,
                                              round(target.close_score, 3)))
                return self._drop(target)
            if self._still_believed(target.object_id):
                self.log_.stop_reason = f"reached {target.source} goal, still believed"
                return "stop"
            return self._drop(target)
        x, y, th = p.state.pose
        err = se2.wrap_angle(math.atan2(target.point[1] - y, target.point[0] - x) - th)
        if abs(err) > math.radians(self._aim_tolerance):
            return "turn_left" if err > 0 else "turn_right"
        return "turn_left" if target.scan_left % 2 else "turn_right"  # glance around it

    def _search(self, target: Target) -> str | None:
        """Soft strategy at a remembered goal: look all around (12 turns of 30°, or what the
        environment's turn angle makes a full turn) on reaching
        its area, again at the point itself; a goal in view ends the search (see
        :meth:`_choose_target`). If it never shows, the evidence decides: the looks just
        taken count against the remembered object, and if the memory still believes in it
        (an object a segmenter often misses, seen in many earlier visits) the agent goes to
        the point and stops there; otherwise it gives the object up."""
        if target.scan_left is None:
            target.scan_left = self.actions.full_turn
        target.scan_left -= 1
        if target.scan_left > 0:
            return "turn_left"
        if target.stage == "area" and target.radius > self.config.stop_distance:
            target.stage, target.scan_left = "point", None
            self._best = (math.inf, self.step_)
            return None
        if target.stage != "commit" and self._still_believed(target.object_id):
            target.stage, target.scan_left = "commit", None
            self._best = (math.inf, self.step_)
            return None
        return self._drop(target)

    def _still_believed(self, object_id: str | None) -> bool:
        # a bridged model's object: this episode's looks at it are not in that model, so
        # its own evidence would overrule them; not seen on arrival, it is given up
        if object_id is None or object_id not in self.current_.graph:
            return False
        goals = self.config.goals
        if goals.rule != "belief":
            return False
        ev = object_evidence(self.current_, [object_id], table=self._scans,
                             weak_below=goals.belief.weak_below)[object_id]
        return trusts(ev, goals)

    def _overrides(self, live: Target, remembered: Target) -> bool:
        """Whether a goal in view replaces the remembered one heading for: always (the
        paper), or when the evidence believes it at least as much, or it is the same place.
        A false positive seen twice on the way is believed less than an object seen in many
        earlier visits."""
        if self.config.live_override == "always" or remembered.object_id is None:
            return True
        if math.dist(live.point, remembered.point) <= 1.0:
            return True
        if remembered.object_id not in self.current_.graph:  # a bridged model's
            return True
        ids = [live.object_id, remembered.object_id]
        ev = object_evidence(self.current_, ids, table=self._scans, cache=self._evidence,
                             stale=self.config.goals.evidence_refresh,
                             weak_below=self.config.goals.belief.weak_below)
        if remembered.object_id not in ev:
            return True
        b = self.config.goals.belief
        return belief(ev[live.object_id], b) >= belief(ev[remembered.object_id], b)

    def _drop(self, target: Target) -> None:
        if target.object_id is not None:
            self.log_.rejected.append(target.object_id)
        self._target = None
        return None

    def _choose_target(self, p: Percept, explore: bool = True) -> Target | None:
        target = self._pick_target(p, explore)
        if self.relocation_ is not None and self.log_.periods:  # the period standing
            period = self.log_.periods[-1]
            period.reasoned = True
            if target is not None and target.source in ("episode", "live"):
                period.perceived.add(target.object_id)
        return target

    def _pick_target(self, p: Percept, explore: bool) -> Target | None:
        cur = self._target
        if self._soft and cur is not None and cur.source == "memory":
            live = self._live_goal(p)
            if live is not None and self._overrides(live, cur):
                return self._set_target(live)
        if cur is not None and cur.source == "live":
            return cur  # keep approaching what was seen
        obj = self._model_goal(p.state.pose)
        if obj is not None:
            if cur is not None and cur.is_object and cur.object_id == obj.object_id:
                if cur.source != "memory":  # a remembered point stays put while searching
                    cur.point = obj.point  # the estimate improves as the object is seen again
                return cur
            return self._set_target(obj)
        if cur is not None and cur.is_object or not explore:
            return cur
        self._explore_age += 1
        if cur is None or self._explore_age > self.config.explore_interval:
            self._explore_age = 0
            cell = self.policy.select(self.map_, p.state.pose, self.goal, self.planner)
            if cell is None:
                self._target = None
                return None
            if self.memory is not None:
                src = getattr(self.policy, "source_", None) or "policy"
                counts = self.log_.frontier_sources
                counts[src] = counts.get(src, 0) + 1
            return self._set_target(Target("explore", self.map_.to_xy(*cell)))
        return cur

    def _set_target(self, t: Target) -> Target:
        old = self._target
        if old is None or (t.source, t.object_id, t.point) != (old.source, old.object_id,
                                                               old.point):
            self.log_.targets.append((self.step_, t.source, *t.point, t.object_id))
            self._best = (math.inf, self.step_)
        self._target = t
        return t

    # ------------------------------------------------------------------ the episode's account
    def memory_goal_reason(self) -> str | None:
        """Why this episode never headed for a goal taken from memory, one of
        :data:`MEMORY_GOAL_REASONS`, decided from what the agent knew (the models, its
        relocations, the targets it chose); None without a memory or when it did head for
        one. For the end of the episode: it changes nothing the agent acts on, and its cost
        (the goal rule on the models relocated into and matched) is paid only when asked."""
        if self.memory is None or self.goal is None:
            return None
        if any(t[1] == "memory" for t in self.log_.targets):
            return None
        if not self.log_.periods:
            return "not_relocated"
        reasons = {self._period_reason(p) for p in self.log_.periods}
        return next(r for r in _CLOSEST_FIRST if r in reasons)

    def _period_reason(self, period: MemoryPeriod) -> str:
        """:meth:`memory_goal_reason` for one relocation (the rules in the order of
        :data:`MEMORY_GOAL_REASONS`)."""
        if not period.reasoned:
            return "relocated_too_late"
        stored = self.memory.model(period.model_id)
        g = period.model.graph
        remembered = {o for o in stored.objects()
                      if stored.graph.nodes[o]["cls"] == self.goal and o in g}
        if remembered & period.perceived:
            return "goal_seen_in_episode"
        if remembered and choose_goal(period.model, self.goal, (0.0, 0.0), self.config.goals,
                                      table=period.scans, among=remembered,
                                      perceived=period.seen) is not None:
            return "live_detection_preferred" if period.perceived else "other"
        matched = set(self.relocalizer.matched) - {period.model_id}
        if any(self._believes_goal(self.memory.model(mid)) for mid in sorted(matched)):
            return "goal_in_other_model"
        if remembered:
            return "belief_below_threshold"
        return "goal_not_in_relocated_model"

    def _believes_goal(self, model: AbstractModel) -> bool:
        """Whether the goal rule would head for some object of ``model`` (its own evidence)."""
        return (self.goal in model.classes
                and choose_goal(model, self.goal, (0.0, 0.0), self.config.goals,
                                perceived=()) is not None)

    def _model_goal(self, pose) -> Target | None:
        """The goal point from the current model (:mod:`kgnav.agent.goals`), mapped into the
        episode frame."""
        model = self.current_
        if self.goal not in model.classes:
            return self._bridged_goal(pose)
        near = pose[:2] if self.relocation_ is None else self._to_model(pose)[:2]
        cur = self._target
        info = choose_goal(model, self.goal, near, self.config.goals,
                           exclude=set(self.log_.rejected), table=self._scans,
                           cache=self._evidence,
                           current=cur.object_id if cur is not None else None,
                           perceived=self._seen_here)
        if info is None:
            return self._bridged_goal(pose)
        xy = info.position[:2]
        if self.relocation_ is not None:
            xy = se2.apply_to_point(se2.inverse(self.relocation_.transform), *xy)
        xy = (float(xy[0]), float(xy[1]))
        if info.id in self._seen_here:
            return Target("episode", xy, info.id)
        if self.config.soft_search != "area":
            return Target("memory", xy, info.id, stage="point")
        lo, hi = self.config.soft_radius_bounds
        d = math.dist(self.relocation_.at if self.relocation_ else pose[:2], xy)
        return Target("memory", xy, info.id, min(max(self.config.soft_radius_factor * d, lo), hi))

    def _bridged_goal(self, pose) -> Target | None:
        """The goal from another stored model this episode bridged to (the relocalizer's
        verified matches into models other than the one relocated into), mapped into the
        episode frame by the bridge's transform; the nearest over the bridges. Its id is
        ``<model id>/<object id>``. A bridge whose alignment is ambiguous (a repeated room)
        is not used: it was verified on a few profiles, without the confirmation a
        relocation gets."""
        if (not self.config.bridged_goals or self.relocation_ is None
                or not self.relocalizer.bridges):
            return None
        cur = self._target
        best: tuple[float, Target] | None = None
        for mid, v in sorted(self.relocalizer.bridges.items()):
            model = self.memory.model(mid)
            if self.goal not in model.classes or not self._bridge_usable(mid, v):
                continue
            prefix = f"{mid}/"
            near = se2.compose(v.transform, pose)[:2]
            info = choose_goal(model, self.goal, near, self.config.goals,
                               exclude={r[len(prefix):] for r in self.log_.rejected
                                        if r.startswith(prefix)},
                               table=self._bridged[mid][1], cache=self._bridged[mid][2],
                               current=(cur.object_id[len(prefix):] if cur is not None
                                        and (cur.object_id or "").startswith(prefix)
                                        else None), perceived=())
            if info is None:
                continue
            xy = se2.apply_to_point(se2.inverse(v.transform), *info.position[:2])
            t = Target("memory", (float(xy[0]), float(xy[1])), prefix + info.id,
                       stage="point")
            d = math.dist(pose[:2], t.point)
            if best is None or d < best[0]:
                best = (d, t)
        return best[1] if best is not None else None

    def _bridge_usable(self, mid: str, verdict) -> bool:
        """Whether a bridge's model may give goals: its alignment unambiguous (asked once)."""
        if mid not in self._bridged:
            ok = (not self.config.relocation.geometry or not self.config.relocation.unique
                  or self.relocalizer.ambiguity(mid, verdict) is None)
            # a stored model does not change during the episode: its evidence is cached
            self._bridged[mid] = (ok, ScanTable(self.memory.model(mid)) if ok else None, {})
        return self._bridged[mid][0]

    def _live_goal(self, p: Percept) -> Target | None:
        """The goal in the current frame: the nearest goal-class object the current state
        sees, if the goal rule would trust it."""
        model, sid = self.current_, self._prev[1] if self._prev else None
        if sid is None or self.goal is None:
            return None
        g = model.graph
        seen = [o for o in g.adj[sid] if g.nodes[o]["kind"] == "object"
                and g.nodes[o]["cls"] == self.goal and o not in self.log_.rejected]
        if not seen:
            return None
        near = self._to_model(p.state.pose)[:2] if self.relocation_ else p.state.pose[:2]
        info = choose_goal(model, self.goal, near, self.config.goals,
                           exclude=self.log_.rejected, table=self._scans, among=set(seen),
                           cache=self._evidence)
        if info is None:
            return None
        xy = info.position[:2]
        if self.relocation_ is not None:
            xy = se2.apply_to_point(se2.inverse(self.relocation_.transform), *xy)
        return Target("live", (float(xy[0]), float(xy[1])), info.id)

    def _goal_mask(self, t: Target) -> np.ndarray:
        m = self.map_
        r = self.config.stop_distance if t.is_object else self.config.explore_radius
        if t.source == "memory" and self._soft and t.stage == "area":
            r = max(r, t.radius)
        k = int(math.ceil(r / m.resolution))
        i, j = m.to_cell(*t.point)
        # a goal beyond what the agent has mapped (a remembered object rooms away) must be
        # on the map, or the planner could not head for it
        pad = k + int(self.planner.crop_margin / m.resolution)
        if m.cover(i - pad, i + pad + 1, j - pad, j + pad + 1, limit=self.map_builder.max_size):
            i, j = m.to_cell(*t.point)
        H, W = m.shape
        mask = np.zeros((H, W), bool)
        i0, i1, j0, j1 = max(i - k, 0), min(i + k + 1, H), max(j - k, 0), min(j + k + 1, W)
        if i0 >= i1 or j0 >= j1:
            return mask
        ii, jj = np.ogrid[i0:i1, j0:j1]
        mask[i0:i1, j0:j1] = (ii - i) ** 2 + (jj - j) ** 2 <= k * k
        return mask



def _vocabulary_map(segmenter, classes: tuple[str, ...]) -> np.ndarray | None:
    """None when the segmenter labels with ``classes`` (or does not say); else a table from
    its class ids to ids of ``classes`` (0: a class the agent's vocabulary lacks)."""
    own = getattr(segmenter, "classes", None) or getattr(segmenter, "class_names", None)
    if own is None or tuple(own) == classes:
        return None
    own = tuple(own)
    if not set(own) & set(classes):
        shown = ", ".join(own[:6]) + (", ..." if len(own) > 6 else "")
        raise EnvSpecError(
            f"segmenter {getattr(segmenter, 'name', type(segmenter).__name__)!r} labels none "
            f"of the environment's {len(classes)} classes ({', '.join(classes[:6])}"
            f"{', ...' if len(classes) > 6 else ''}); it knows {len(own)}: {shown}")
    return np.array([0] + [classes.index(c) + 1 if c in classes else 0 for c in own],
                    np.int32)


def remembered_objects(model, transform, belief_model, min_belief: float = 0.5) -> tuple:
    """The objects of a stored ``model`` believed real (belief at least ``min_belief``), as
    ``(class, x, y, belief)`` in the episode frame; ``transform`` maps the episode frame into
    the model's (a relocation's)."""
    inv = se2.inverse(transform)
    ev = object_evidence(model, weak_below=belief_model.weak_below)
    out = []
    for o, e in sorted(ev.items()):
        b = belief(e, belief_model)
        if b >= min_belief:
            d = model.graph.nodes[o]
            x, y = se2.apply_to_point(inv, d["x"], d["y"])
            out.append((d["cls"], x, y, b))
    return tuple(out)


def _relabel(seg: Segmentation, table: np.ndarray, classes: tuple[str, ...]) -> Segmentation:
    """A segmentation in the agent's vocabulary: ids mapped, other classes' segments gone."""
    out = Segmentation(table[seg.classes], seg.instances,
                       [sg for sg in seg.segments if sg.cls in classes])
    if seg.weak is not None:
        out.weak = _relabel(seg.weak, table, classes)
    return out
