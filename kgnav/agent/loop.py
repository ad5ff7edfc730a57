"""The ObjectNav agent: the paper's per-step cycle, wiring the parts and nothing more.

1. **Knowledge extraction**: segment the RGB-D frame, extract the state features, build the
   abstract state ``s = <F_s, C_s, {F_s,c}>``.
2. **Knowledge modelling**: fuse the frame into the episode map; add ``s`` and the transition
   ``(s_prev, a, s)`` to the current Abstract Model; with a memory, until a match was made in
   this episode, match ``s`` against every stored state and on a match merge the current model
   into the matched one, which becomes the current model.
3. **Reasoning**: if the current model holds the goal class, head for the paper's goal point
   (top five most-seen, then closest); otherwise explore with the global policy; plan with
   Fast Marching; act.

With a memory, the *hard* strategy trusts a remembered goal point and stops there; the *soft*
strategy searches an area around it, of a radius proportional to the distance from the agent at
the match to the goal, and keeps watching the live segmentation for the goal on the way.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from kgnav import query, se2
from kgnav.agent.camera import Camera
from kgnav.agent.features import FeatureExtractor
from kgnav.agent.mapping import EpisodeMap, MapBuilder
from kgnav.agent.memory import Memory
from kgnav.agent.planner import FMMPlanner, Plan
from kgnav.agent.policy import FrontierPolicy, GlobalPolicy
from kgnav.agent.state_creator import AbstractState, StateCreator
from kgnav.merge import merge
from kgnav.model import ACTIONS, AbstractModel

STRATEGIES = ("hard", "soft")


@dataclass(frozen=True)
class AgentConfig:
    """Tunable behaviour. Distances in metres."""

    stop_distance: float = 0.8  # call stop this close to a goal point (success is 1 m)
    explore_interval: int = 25  # steps between global-policy decisions (the paper's 25)
    explore_radius: float = 0.25  # an exploration goal counts as reached this close
    top_k: int = query.TOP_K
    min_goal_views: int = 2  # a goal seen from one state only is likely a segmenter glitch
    strategy: str = "soft"  # with memory: "hard" or "soft"
    soft_radius_factor: float = 0.25  # soft search radius per metre from match to goal
    soft_radius_bounds: tuple[float, float] = (1.0, 3.0)
    soft_search_steps: int = 40  # look around a remembered goal this long before dropping it
    stall_steps: int = 40  # steps without progress toward an object before giving it up
    confirm_matches: int = 2  # agreeing matches needed to relocate (1: the paper's first)
    confirm_window: int = 10  # steps within which they must fall
    confirm_tolerance: tuple[float, float] = (0.5, 15.0)  # m, degrees between transforms
    refine_radius: float = 1.5  # landmark pairing radius for transform refinement (0: off)
    refine_pairs: int = 60  # most recent landmark pairs used
    verify_checks: int = 15  # landmark checks before a relocation may be undone (0: never)
    verify_support: float = 0.25  # undo it when fewer checks than this share find their class
    merge_support: float = 0.5  # at the episode's end, merge into the matched model only above
    novel_goal_views: int = 4  # views a goal the memory never saw needs where it has looked
    known_area: float = 1.5  # m: the memory "has looked" within this of its states
    map_size: int = 480
    map_resolution: float = 0.05

    def __post_init__(self):
        if self.strategy not in STRATEGIES:
            raise ValueError(f"strategy must be one of {STRATEGIES}, got {self.strategy!r}")


@dataclass
class Target:
    """Where the agent is heading. ``source``: ``explore`` (global policy), ``episode`` (an
    object this episode perceived), ``memory`` (an object only a stored model knows) or
    ``live`` (the goal in the current frame)."""

    source: str
    point: tuple[float, float]  # episode frame
    object_id: str | None = None
    radius: float = 0.0  # soft strategy: the search area around a remembered goal
    stage: str = "area"  # soft strategy: reach the area, look around, then the point itself
    scan_left: int | None = None

    @property
    def key(self):
        return (self.source, self.object_id, self.point, self.stage)

    @property
    def is_object(self) -> bool:
        return self.source != "explore"


@dataclass
class Relocation:
    """The match made in this episode (at most one, as in the paper)."""

    step: int
    model_id: str
    state_id: str
    distance: float
    transform: tuple[float, float, float]  # episode frame -> model frame
    at: tuple[float, float] | None = None  # agent position at the match, episode frame
    checked: int = 0  # detections mapped where the stored model knows some object
    supported: int = 0  # ... of which found a remembered object of their own class


@dataclass
class Percept:
    """Output of knowledge extraction for one step."""

    segmentation: object
    state: AbstractState
    depth: np.ndarray


@dataclass
class EpisodeLog:
    """What the agent did, for metrics and failure analysis."""

    targets: list[tuple[int, str, float, float, str | None]] = field(default_factory=list)
    rejected: list[str] = field(default_factory=list)
    stop_reason: str | None = None
    undone: list[Relocation] = field(default_factory=list)  # relocations landmarks refuted


class ObjectNavAgent:
    """The with- or without-memory ObjectNav agent.

    ``memory`` (a :class:`Memory`) turns on relocation and reuse; without it this is the
    paper's memory-less ANS* baseline, still learning an Abstract Model of the episode
    (``model_``).
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
    ):
        self.camera = camera
        self.segmenter = segmenter
        self.extractor = extractor
        self.policy = policy or FrontierPolicy()
        self.planner = planner or FMMPlanner()
        self.memory = memory
        self.config = config or AgentConfig()
        self.map_builder = MapBuilder(camera, self.config.map_size, self.config.map_resolution)
        self.state_creator = StateCreator(camera)

    # ------------------------------------------------------------------ episode
    def reset(self, goal_class: str, *, seed: int = 0, scene: str = "", episode: int = 0,
              model_id: str | None = None) -> None:
        self.goal = goal_class
        self.episode = int(episode)
        self.segmenter.reset(seed, scene)
        self.policy.reset(seed)
        self.planner.reset()
        self.map_: EpisodeMap = self.map_builder.reset()
        self.model_ = AbstractModel(self.extractor.dim, model_id=model_id,
                                    extractor=self.extractor.name)
        self.current_: AbstractModel = self.model_  # the merged model after a relocation
        self.relocation_: Relocation | None = None
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
        self._candidates: list[tuple[int, str, tuple]] = []  # recent matches awaiting support
        self._pairs: list[tuple] = []  # (episode x, y, remembered x, y, object) landmarks
        self._escape: list[str] = []  # scripted way out after repeated bumps

    def act(self, obs) -> int:
        """One step of the paper's cycle; returns the simulator action index."""
        percept = self.extract(obs)
        self.model_knowledge(percept)
        action = self.reason(percept)
        self._last_action = action
        self.step_ += 1
        return ACTIONS.index(action)

    # ------------------------------------------------------------------ 1. extraction
    def extract(self, obs) -> Percept:
        seg = self.segmenter(obs["rgb"], obs["depth"], obs.get("semantic"))
        features = self.extractor(obs["rgb"])
        state = self.state_creator(features, seg, obs["depth"], obs["pose"])
        return Percept(seg, state, obs["depth"])

    # ------------------------------------------------------------------ 2. modelling
    def model_knowledge(self, p: Percept) -> None:
        pose = p.state.pose
        self.map_builder.update(p.depth, pose, p.segmentation)
        if (self._last_action == "move_forward" and self._prev_pose is not None
                and math.dist(pose[:2], self._prev_pose[:2]) < 0.03):
            self.planner.note_collision(self.map_, self._prev_pose)
            self._bumps += 1
        elif self._last_action == "move_forward":
            self._bumps = 0
        self._prev_pose = pose

        sid = self.model_.add_state(p.state.features, pose, p.state.detections,
                                    episode=self.episode, step=self.step_)
        cur = sid
        if self.current_ is not self.model_ and self._verify(p.state):
            self._refine(p.state)
            cur = self._add_to_current(p.state)
        if self._prev is not None and self._last_action is not None:
            self.model_.add_transition(self._prev[0], self._last_action, sid)
            if (self.current_ is not self.model_ and cur is not None
                    and self._prev[1] is not None):
                self.current_.add_transition(self._prev[1], self._last_action, cur)
        self._prev = (sid, cur)
        if self.current_ is self.model_:
            self._seen_here.update(self.model_.graph.successors(sid))
        if self.memory is not None and self.relocation_ is None:
            self._relocate(p.state, sid)

    def _confirmed(self, model_id: str, T) -> bool:
        """Accept a match once ``confirm_matches`` matches within a few steps agree on the
        model and on the frame transform: a single look-alike view can put the agent in the
        wrong house or metres off, and everything reused would then be misplaced."""
        need = self.config.confirm_matches
        if need <= 1:
            return True
        window = self.config.confirm_window
        self._candidates = [c for c in self._candidates if self.step_ - c[0] < window]
        agree = [c for c in self._candidates if c[1] == model_id and self._agree(c[2], T)]
        self._candidates.append((self.step_, model_id, tuple(T)))
        return len(agree) + 1 >= need

    def _agree(self, a, b) -> bool:
        tol_xy, tol_th = self.config.confirm_tolerance
        return (math.dist(a[:2], b[:2]) <= tol_xy
                and se2.angle_diff(a[2], b[2]) <= math.radians(tol_th))

    def _verify(self, state: AbstractState) -> bool:
        """Check the relocation against landmarks; undo it when they refute it.

        Each detection mapped into the stored model's frame where that model knows some object
        nearby is a check; it supports the relocation when one of those objects has its class.
        A wrong match (a look-alike room elsewhere, a rotated twin) places the episode's objects
        among unrelated ones, and merging it at the episode's end would corrupt the stored model
        for every later episode. Returns whether the relocation stands.
        """
        r = self.config.refine_radius
        if r <= 0:
            return True
        reloc = self.relocation_
        xy, cls = self._landmarks
        if len(cls):
            for d in state.detections:
                x, y = se2.apply_to_point(reloc.transform, *d.position[:2])
                near = np.hypot(xy[:, 0] - x, xy[:, 1] - y) <= r
                if near.any():
                    reloc.checked += 1
                    reloc.supported += bool((cls[near] == d.cls).any())
        if not self._refuted(reloc, self.config.verify_support):
            return True
        self.log_.undone.append(reloc)
        self.relocation_ = None
        self.current_ = self.model_
        self._seen_here = set(self.model_.objects())
        self._prev = (self._prev[0], self._prev[0]) if self._prev else None
        self._pairs, self._candidates = [], []
        self.log_.rejected = []  # object ids of the merged model, meaningless now
        self._target = None
        return False

    def _refine(self, state: AbstractState) -> None:
        """Correct the relocation's frame transform with landmarks.

        One matched view fixes the transform only as well as the two poses agree (the paper's
        "imperfect match"). Each object seen after the match is paired with the nearest
        remembered object of its class; every few pairs the rigid transform that best maps
        the episode's observations onto the remembered positions (least squares, one round of
        outlier rejection) replaces the current one, unless it moves implausibly far.
        """
        if self.config.refine_radius <= 0:
            return
        stored = self.memory.model(self.relocation_.model_id)
        T = self.relocation_.transform
        for d in state.detections:
            x, y = se2.apply_to_point(T, *d.position[:2])
            hit = stored.nearest_object(d.cls, x, y, self.config.refine_radius)
            if hit is not None:
                o = stored.graph.nodes[hit]
                self._pairs.append((d.position[0], d.position[1], o["x"], o["y"], hit))
        self._pairs = self._pairs[-self.config.refine_pairs:]
        if len({p[4] for p in self._pairs}) < 3 or len(self._pairs) % 5:
            return
        pts = np.array([p[:4] for p in self._pairs], float)
        new = _rigid_fit(pts[:, :2], pts[:, 2:])
        res = np.hypot(*(se2.apply_to_points(new, pts[:, :2]) - pts[:, 2:]).T)
        keep = res <= max(0.5, 2.0 * float(np.median(res)))
        if keep.sum() >= 3:
            new = _rigid_fit(pts[keep, :2], pts[keep, 2:])
        at = self.relocation_.at
        moved = math.dist(se2.apply_to_point(new, *at), se2.apply_to_point(T, *at))
        if moved <= 1.5 and se2.angle_diff(new[2], T[2]) <= math.radians(30):
            self.relocation_.transform = tuple(float(v) for v in new)

    def _doubtful(self) -> set[str]:
        """Goal-class objects of the merged model that only this episode has seen, where the
        stored model has been before, and that are not yet seen from ``novel_goal_views``
        states: the memory looked there and saw no such thing, so one more glimpse is
        likelier a segmenter false positive than a goal."""
        if self.relocation_ is None or self.config.novel_goal_views <= self.config.min_goal_views:
            return set()
        g, prefix = self.current_.graph, f"{self.model_.model_id}/"
        out = set()
        for o in self.current_._index.by_class.get(self.goal, ()):
            d = g.nodes[o]
            if d["n_views"] >= self.config.novel_goal_views:
                continue
            if not all(s.startswith(prefix) for s in d["origin"].split()):
                continue  # remembered
            gap = np.hypot(self._walked[:, 0] - d["x"], self._walked[:, 1] - d["y"])
            if len(gap) and gap.min() <= self.config.known_area:
                out.add(o)
        return out

    def _to_model(self, pose) -> tuple[float, float, float]:
        return se2.compose(self.relocation_.transform, pose)

    def _add_to_current(self, state: AbstractState) -> str:
        T = self.relocation_.transform
        dets = [replace(d, position=(*se2.apply_to_point(T, *d.position[:2]), d.position[2]))
                for d in state.detections]
        cur = self.current_.add_state(state.features, self._to_model(state.pose), dets,
                                      episode=self.episode, step=self.step_)
        self._seen_here.update(self.current_.graph.successors(cur))
        return cur

    def _relocate(self, state: AbstractState, sid: str) -> None:
        m = self.memory.match(state.features)
        if m is None:
            return
        stored = self.memory.model(m.model_id)
        T = se2.anchor_transform(stored.pose(m.state_id), state.pose)
        if any(u.model_id == m.model_id and self._agree(u.transform, T)
               for u in self.log_.undone):
            return  # refuted already
        if not self._confirmed(m.model_id, T):
            return
        self.relocation_ = Relocation(self.step_, m.model_id, m.state_id, m.distance,
                                      tuple(float(v) for v in T),
                                      (float(state.pose[0]), float(state.pose[1])))
        self.current_ = merge(stored, self.model_, transform=T)
        # objects of the merged model that this episode perceived: those merged from model_
        prefix = f"{self.model_.model_id}/"
        self._seen_here = {
            o for o in self.current_.objects()
            if any(s.startswith(prefix) for s in self.current_.graph.nodes[o]["origin"].split())
        }
        self._prev = (sid, self.current_.known_node(f"{prefix}{sid}"))
        self._target = None  # re-decide with the knowledge just gained
        nodes = stored.graph.nodes
        self._walked = np.array([(nodes[n]["x"], nodes[n]["y"]) for n in stored.states()],
                                float).reshape(-1, 2)
        objs = list(stored.objects())
        self._landmarks = (np.array([(nodes[o]["x"], nodes[o]["y"]) for o in objs],
                                    float).reshape(-1, 2),
                           np.array([nodes[o]["cls"] for o in objs], dtype=object))

    def mergeable(self) -> Relocation | None:
        """The relocation to merge this episode's model with at its end, or None to store it
        as a new model: a relocation that stood in the episode but that landmarks supported
        only weakly would misplace a whole episode in the stored model for good."""
        r = self.relocation_
        if r is None or self._refuted(r, self.config.merge_support):
            return None
        return r

    def _refuted(self, r: Relocation, share: float) -> bool:
        """Enough landmark checks (``verify_checks``), and fewer than ``share`` support ``r``."""
        need = self.config.verify_checks
        return need > 0 and r.checked >= need and r.supported < share * r.checked

    # ------------------------------------------------------------------ 3. reasoning
    @property
    def _soft(self) -> bool:
        return self.memory is not None and self.config.strategy == "soft"

    def reason(self, p: Percept) -> str:
        if self._bumps >= 3 and not self._escape:
            # stuck against something the map misses: turn away (alternating sides) and step
            turn = "turn_right" if (self._bumps // 3) % 2 else "turn_left"
            self._escape = [turn] * 3 + ["move_forward"]
        if self._escape:
            return self._escape.pop(0)
        target = self._choose_target(p)
        for _ in range(3):  # a target reached or given up is replaced within the step
            if target is None:
                return "turn_left"  # nothing known and nothing left to explore: look around
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

    def _approach(self, target: Target, plan: Plan, p: Percept) -> str | None:
        if plan.reached:
            if target.source == "memory" and self._soft:
                return self._search(target)
            self.log_.stop_reason = f"reached {target.source} goal"
            return "stop"
        if not math.isfinite(plan.distance):
            return self._drop(target)
        if plan.distance < self._best[0] - 0.1 or plan.distance > self._best[0] + 1.0:
            # progress, or the map revealed a longer way round: measure from here
            self._best = (plan.distance, self.step_)
        elif self.step_ - self._best[1] > self.config.stall_steps:
            if math.dist(p.state.pose[:2], target.point) <= 1.0 and target.source != "memory":
                self.log_.stop_reason = f"stalled near {target.source} goal"
                return "stop"
            return self._drop(target)
        return plan.action

    def _search(self, target: Target) -> str | None:
        """Soft strategy at a remembered goal: look all around (12 turns of 30°) on reaching
        its area, again at the point itself, then give it up. A goal in view ends the search
        (see :meth:`_choose_target`)."""
        if target.scan_left is None:
            target.scan_left = 12
        target.scan_left -= 1
        if target.scan_left > 0:
            return "turn_left"
        if target.stage == "area" and target.radius > self.config.stop_distance:
            target.stage, target.scan_left = "point", None
            self._best = (math.inf, self.step_)
            return None
        return self._drop(target)

    def _drop(self, target: Target) -> None:
        if target.object_id is not None:
            self.log_.rejected.append(target.object_id)
        self._target = None
        return None

    def _choose_target(self, p: Percept) -> Target | None:
        cur = self._target
        if self._soft and cur is not None and cur.source == "memory":
            live = self._live_goal(p)
            if live is not None:
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
        if cur is not None and cur.is_object:
            return cur
        self._explore_age += 1
        if cur is None or self._explore_age > self.config.explore_interval:
            self._explore_age = 0
            cell = self.policy.select(self.map_, p.state.pose, self.goal, self.planner)
            if cell is None:
                self._target = None
                return None
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

    def _model_goal(self, pose) -> Target | None:
        """The paper's goal point from the current model, mapped into the episode frame."""
        model = self.current_
        if self.goal not in model.classes:
            return None
        near = pose[:2] if self.relocation_ is None else self._to_model(pose)[:2]
        info = query.goal_point(model, self.goal, near, self.config.top_k,
                                exclude=set(self.log_.rejected) | self._doubtful(),
                                min_views=self.config.min_goal_views)
        if info is None:
            return None
        xy = info.position[:2]
        if self.relocation_ is not None:
            xy = se2.apply_to_point(se2.inverse(self.relocation_.transform), *xy)
        xy = (float(xy[0]), float(xy[1]))
        if info.id in self._seen_here:
            return Target("episode", xy, info.id)
        lo, hi = self.config.soft_radius_bounds
        d = math.dist(self.relocation_.at if self.relocation_ else pose[:2], xy)
        return Target("memory", xy, info.id, min(max(self.config.soft_radius_factor * d, lo), hi))

    def _live_goal(self, p: Percept) -> Target | None:
        """The goal in the current frame: the nearest goal-class object the current state
        sees, if it has been seen from enough states to be trusted."""
        model, sid = self.current_, self._prev[1] if self._prev else None
        if sid is None or self.goal is None:
            return None
        g = model.graph
        best, doubtful = None, self._doubtful()
        for o, edges in g.adj[sid].items():
            d = g.nodes[o]
            if d["kind"] != "object" or d["cls"] != self.goal:
                continue
            if (d["n_views"] < self.config.min_goal_views or o in self.log_.rejected
                    or o in doubtful):
                continue
            dist = min(e.get("distance", math.inf) for e in edges.values())
            if best is None or dist < best[0]:
                best = (dist, o, (d["x"], d["y"]))
        if best is None:
            return None
        xy = best[2]
        if self.relocation_ is not None:
            xy = se2.apply_to_point(se2.inverse(self.relocation_.transform), *xy)
        return Target("live", (float(xy[0]), float(xy[1])), best[1])

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


def _rigid_fit(src: np.ndarray, dst: np.ndarray) -> tuple[float, float, float]:
    """The SE(2) transform minimising squared distances from mapped ``src`` to ``dst``
    (2-D Kabsch)."""
    cs, cd = src.mean(axis=0), dst.mean(axis=0)
    a, b = src - cs, dst - cd
    theta = math.atan2(float((a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]).sum()),
                       float((a * b).sum()))
    c, s = math.cos(theta), math.sin(theta)
    t = cd - np.array([c * cs[0] - s * cs[1], s * cs[0] + c * cs[1]])
    return float(t[0]), float(t[1]), theta
