"""The environment protocol (kgnav.envs) with an environment that is not kgnav's simulator.

``GridRoom`` is a room with a few boxes, ray cast per pixel with numpy: its own class names,
a 45° turn and 0.2 m step, actions in another index order, and a camera unlike kgnav's (64×48,
a vertical field of view, pitched down, mounted ahead of the centre, principal point off
centre). The agent and the benchmark runner must work with it through the protocol alone.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from dataclasses import dataclass, replace

import numpy as np
import pytest

from kgnav.agent.camera import Camera
from kgnav.agent.features import make_extractor
from kgnav.agent.loop import AgentConfig, ObjectNavAgent, Target
from kgnav.agent.segmentation import make_segmenter
from kgnav.benchmark.memory_update import absorb
from kgnav.benchmark.runner import EvalConfig, run_eval
from kgnav.envs import (
    ENVS,
    ActionSpec,
    CameraSpec,
    EnvProtocolError,
    EnvSpec,
    EnvSpecError,
    check_observation,
    env_applies_noise,
    make_env,
    register_env,
)
from kgnav.errors import KgnavError, UnknownClassError
from kgnav.memory.model import AbstractModel

CLASSES = ("crate", "barrel", "cone")
WALL_H, RADIUS = 2.2, 0.15


@dataclass(frozen=True)
class Box:
    cls: str
    x0: float
    y0: float
    x1: float
    y1: float
    top: float

    def l2(self, x: float, y: float) -> float:
        dx = max(self.x0 - x, 0.0, x - self.x1)
        dy = max(self.y0 - y, 0.0, y - self.y1)
        return math.hypot(dx, dy)


ROOMS = [  # (width, depth, boxes); the room spans [0, width] x [0, depth]
    (6.0, 5.0, (Box("crate", 4.6, 3.4, 5.3, 4.1, 0.7), Box("barrel", 1.0, 3.8, 1.5, 4.3, 1.0),
                Box("cone", 4.8, 0.6, 5.1, 0.9, 0.5))),
    (5.0, 6.0, (Box("cone", 3.8, 4.6, 4.2, 5.0, 0.5), Box("crate", 0.7, 4.5, 1.4, 5.2, 0.8),
                Box("barrel", 3.9, 1.0, 4.4, 1.5, 1.0))),
]
# (start x, y, theta; goal class) per episode, the same in both rooms
EPISODES = [((1.2, 1.2, 0.0), "crate"), ((2.5, 2.5, math.pi / 2), "cone"),
            ((1.0, 2.0, -math.pi / 4), "barrel")]

CAMERA = CameraSpec(64, 48, vfov_deg=55.0, cx=33.0, cy=23.0, pitch_deg=-12.0, height_m=0.7,
                    forward_m=0.1, min_depth=0.1, max_depth=4.0)
ACTIONS = ActionSpec(("move_forward", "turn_left", "turn_right", "stop"), 0.2, 45.0)
PALETTE = {"wall": (200, 190, 170), "floor": (90, 80, 70), "ceiling": (230, 230, 230),
           "crate": (170, 110, 40), "barrel": (40, 90, 170), "cone": (240, 120, 20)}


class GridRoom:
    """One room of :data:`ROOMS` with the episodes of :data:`EPISODES` (the first ``n``).

    Ground truth offered: ``info["success"]`` only, unless ``hooks`` (then also the metric
    keys, ``episode_start``, ``start_frame_to_world``, ``l2_distance_to_goal`` and
    ``scene_name``). ``camera`` and ``actions`` may be other than the defaults.
    """

    def __init__(self, k: int, n: int | None = None, hooks: bool = False, max_steps: int = 60,
                 camera: CameraSpec = CAMERA, actions: ActionSpec = ACTIONS):
        self.width, self.depth, self.boxes = ROOMS[k]
        self.episodes = EPISODES[:n] if n else EPISODES
        self.hooks = hooks
        self.camera, self.actions = camera, actions
        self.env_spec = EnvSpec("grid", camera, actions, CLASSES, semantic=True,
                                max_steps=max_steps, agent_radius=RADIUS)
        cam = Camera.from_spec(camera)
        v, u = np.mgrid[0:camera.height, 0:camera.width] + 0.5
        fx, fy, cx, cy = cam.focal, cam._rays[3], cam._rays[4], cam._rays[5]
        p = math.radians(camera.pitch_deg)
        up = (cy - v) / fy
        # per pixel, the agent-frame direction of a ray of unit z-depth
        self._dir = np.stack([math.cos(p) - up * math.sin(p), -(u - cx) / fx,
                              math.sin(p) + up * math.cos(p)], -1)
        if hooks:
            self.scene_name = f"grid-room-{k}"

    # ------------------------------------------------------------------ protocol
    def reset(self, *, seed=None, options=None):
        self.i = int((options or {}).get("episode", 0))
        (x, y, t), self.goal = self.episodes[self.i]
        self.start = self.pose = (x, y, t)
        self.steps, self.path, self.done = 0, 0.0, False
        return self._observe(), {"goal_class": self.goal}

    def step(self, action):
        assert not self.done, "step after the end"
        name = self.actions.names[int(action)]
        self.move(name)
        x, y, _t = self.pose
        stop = name == "stop"
        trunc = not stop and self.steps >= self.env_spec.max_steps
        self.done = stop or trunc
        info = {"success": stop and self.l2_distance_to_goal(x, y) <= 1.0}
        if self.hooks:
            info.update(spl=float(info["success"]), softspl=0.5, dts=0.0,
                        path_length=self.path, shortest_path_length=1.0,
                        episode_id=f"ep{self.i}")
        return self._observe(), 0.0, stop, trunc, info

    # ------------------------------------------------------------------ ground truth
    def l2_distance_to_goal(self, x, y):
        return min(b.l2(x, y) for b in self.boxes if b.cls == self.goal)

    def __getattr__(self, name):  # the optional hooks exist only with hooks=True
        if name in ("episode_start", "start_frame_to_world") and self.__dict__.get("hooks"):
            return getattr(self, "_" + name)
        raise AttributeError(name)

    def _episode_start(self, i):
        return self.episodes[i][0]

    def _start_frame_to_world(self, x, y):
        sx, sy, st = self.start
        return (sx + math.cos(st) * x - math.sin(st) * y,
                sy + math.sin(st) * x + math.cos(st) * y)

    # ------------------------------------------------------------------ internals
    def move(self, name: str) -> None:
        x, y, t = self.pose
        if name == "move_forward":
            step = self.actions.step_m
            nx, ny = x + step * math.cos(t), y + step * math.sin(t)
            if self._free(nx, ny):
                self.path += step
                x, y = nx, ny
        elif name in ("turn_left", "turn_right"):
            t += math.radians(self.actions.turn_deg) * (1 if name == "turn_left" else -1)
        self.pose = (x, y, t)
        self.steps += 1

    def _free(self, x, y) -> bool:
        inside = RADIUS <= x <= self.width - RADIUS and RADIUS <= y <= self.depth - RADIUS
        return inside and all(b.l2(x, y) > RADIUS for b in self.boxes)

    def render(self):
        """(rgb, z-depth unclipped, class ids, instance ids) from the current pose."""
        x, y, t = self.pose
        cam = self.camera
        c, s = math.cos(t), math.sin(t)
        d = self._dir
        world = np.stack([c * d[..., 0] - s * d[..., 1], s * d[..., 0] + c * d[..., 1],
                          d[..., 2]], -1)
        world[np.abs(world) < 1e-9] = 1e-9
        o = np.array([x + cam.forward_m * c, y + cam.forward_m * s, cam.height_m])
        # the room from inside: where the ray leaves it (t is the z-depth: unit-depth rays)
        lo, hi = np.zeros(3), np.array([self.width, self.depth, WALL_H])
        exits = np.maximum((lo - o) / world, (hi - o) / world)
        depth = exits.min(-1)
        axis = exits.argmin(-1)  # 0, 1: a wall; 2: floor or ceiling
        label = np.where(axis < 2, 0, np.where(world[..., 2] < 0, -1, -2))
        inst = np.zeros(depth.shape, np.int32)
        for k, b in enumerate(self.boxes, 1):
            blo, bhi = np.array([b.x0, b.y0, 0.0]), np.array([b.x1, b.y1, b.top])
            t0, t1 = (blo - o) / world, (bhi - o) / world
            near = np.minimum(t0, t1).max(-1)
            far = np.maximum(t0, t1).min(-1)
            hit = (near <= far) & (near > 0) & (near < depth)
            depth = np.where(hit, near, depth)
            inst = np.where(hit, k, inst)
        names = ["wall", "floor", "ceiling"]
        rgb = np.zeros((*depth.shape, 3), np.uint8)
        for code, name in zip((0, -1, -2), names, strict=True):
            rgb[(label == code) & (inst == 0)] = PALETTE[name]
        # wall stripes every 0.5 m, so that places look different
        wx, wy = o[0] + depth * world[..., 0], o[1] + depth * world[..., 1]
        stripe = ((np.floor(wx * 2) + np.floor(wy * 2)) % 2 == 0) & (label == 0) & (inst == 0)
        rgb[stripe] = (150, 160, 190)
        self.surface = label  # 0 wall, -1 floor, -2 ceiling (for tests)
        cls = np.zeros(depth.shape, np.int32)
        for k, b in enumerate(self.boxes, 1):
            rgb[inst == k] = PALETTE[b.cls]
            cls[inst == k] = CLASSES.index(b.cls) + 1
        return rgb, depth, cls, inst

    def _observe(self):
        rgb, depth, cls, inst = self.render()
        x, y, t = self.pose
        cam = self.camera
        dx, dy = x - self.start[0], y - self.start[1]
        sc, ss = math.cos(self.start[2]), math.sin(self.start[2])
        pose = np.array([sc * dx + ss * dy, -ss * dx + sc * dy, t - self.start[2]])
        return {"rgb": rgb,
                "depth": np.clip(depth, cam.min_depth, cam.max_depth).astype(np.float32),
                "semantic": np.stack([cls, inst], -1),
                "pose": pose,
                "objectgoal": CLASSES.index(self.goal) + 1}


class GridSuite:
    """Both rooms, as a registered environment's scenes."""

    def __init__(self, options, hooks: bool = False):
        self.name, self.hooks, self.max_steps = "grid-rooms", hooks, options.max_steps

    def __len__(self):
        return len(ROOMS)

    def episode_count(self, k, n=None):
        return min(n or len(EPISODES), len(EPISODES))

    def make(self, k, n=None):
        return GridRoom(k, n, self.hooks, self.max_steps)


@pytest.fixture(scope="module", autouse=True)
def registered():
    register_env("grid-test")(GridSuite)
    register_env("grid-test-gt")(lambda o: GridSuite(o, hooks=True))
    yield
    for name in ("grid-test", "grid-test-gt", "grid-broken"):
        ENVS.pop(name, None)


def _segmenter(spec: EnvSpec):
    cam = Camera.from_spec(spec.camera)
    return make_segmenter("clean", 0, classes=spec.classes, hfov_deg=cam.hfov_deg,
                          min_depth=cam.min_depth, max_depth=cam.max_depth)


def _run(env, agent, episode):
    obs, _info = env.reset(seed=0, options={"episode": episode})
    goal = env.env_spec.class_name(obs["objectgoal"])
    agent.reset(goal, seed=0, scene="grid", episode=episode)
    actions = []
    while True:
        check_observation(obs, env.env_spec)
        a = agent.act(obs)
        actions.append(a)
        obs, _r, term, trunc, info = env.step(a)
        if term or trunc:
            return info, actions


# ---------------------------------------------------------------------- the agent
def test_camera_from_intrinsics_matches_the_rendered_geometry():
    """Points back-projected by the agent's camera land where the environment put them: a
    box face, the floor, both with the pitch, the offset principal point and forward mount."""
    env = GridRoom(0)
    obs, _ = env.reset(options={"episode": 0})
    cam = Camera.from_spec(CAMERA)
    fwd, left, up = cam.points(obs["depth"])
    floor = (env.surface == -1) & (obs["semantic"][..., 1] == 0) & (obs["depth"] < 3.9)
    assert floor.sum() > 50
    assert np.abs(up[floor]).max() < 0.02  # the floor is at height 0
    crate = obs["semantic"][..., 1] == 1  # seen from the start, which faces +x
    assert crate.sum() > 20
    sx, sy, _ = env.start
    box = env.boxes[0]
    on_box = [box.l2(sx + f, sy + lf) for f, lf in zip(fwd[crate], left[crate], strict=True)]
    assert max(on_box) < 0.03
    assert up[crate].min() > -0.03 and up[crate].max() < box.top + 0.03
    # a level camera at the centre keeps its forward coordinate equal to the depth
    level = Camera.from_intrinsics(64, 48, vfov_deg=55.0)
    assert level.level and not cam.level
    assert math.isclose(level.hfov_deg, math.degrees(2 * math.atan(32 / (24 / math.tan(
        math.radians(27.5))))))


def test_agent_finds_goals_with_another_vocabulary_camera_and_turn():
    env = GridRoom(0)
    spec = env.env_spec
    agent = ObjectNavAgent.for_env(env, _segmenter(spec), make_extractor("opencv-gist"))
    assert agent.actions.full_turn == 8 and agent.map_builder.classes == CLASSES
    assert agent.planner.agent_radius == RADIUS
    successes = 0
    for ep in range(len(EPISODES)):
        info, actions = _run(env, agent, ep)
        assert set(actions) <= set(range(4))
        successes += info["success"]
        model = agent.model_
        assert model.classes == CLASSES
        seen = {model.graph.nodes[o]["cls"] for o in model.objects()}
        assert seen and seen <= set(CLASSES)
        goal = EPISODES[ep][1]
        if info["success"]:  # stopped at the goal it mapped, where it is
            assert agent.log_.stop_reason.startswith("reached")
            assert actions[-1] == ACTIONS.index("stop") == 3
            box = next(b for b in env.boxes if b.cls == goal)
            sx, sy, st = env.start
            pts = [(model.graph.nodes[o]["x"], model.graph.nodes[o]["y"])
                   for o in model.objects() if model.graph.nodes[o]["cls"] == goal]
            errs = [box.l2(sx + math.cos(st) * px - math.sin(st) * py,
                           sy + math.sin(st) * px + math.cos(st) * py) for px, py in pts]
            assert min(errs) < 0.4
    assert successes >= 2


def test_look_around_and_escape_follow_the_turn_angle():
    spec = replace(GridRoom(0).env_spec, actions=ActionSpec(turn_deg=45.0))
    agent = ObjectNavAgent.for_env(spec, _segmenter(spec), make_extractor("opencv-gist"))
    assert agent.actions.full_turn == 8 and agent.actions.turns(90) == 2
    assert agent.actions.bump_distance == pytest.approx(0.03)
    assert agent.planner.turn_tolerance == pytest.approx(math.radians(23.5))
    agent.reset("cone")
    agent._bumps = 3  # three blocked moves: turn 90° (two turns of 45°), then step
    assert [agent.reason(None) for _ in range(3)] == ["turn_right", "turn_right", "move_forward"]
    # the soft search at a remembered goal looks all round: 8 views of 45°
    target = Target("memory", (1.0, 0.0), "gone", stage="point")
    looks = []
    while (a := agent._search(target)) is not None:
        looks.append(a)
    assert looks == ["turn_left"] * 7


# ---------------------------------------------------------------------- the runner
def test_runner_runs_a_registered_environment(tmp_path):
    cfg = EvalConfig(env="grid-test", variants=("ans", "si"), segmenter="clean",
                     extractor="opencv-gist", max_steps=60, episodes=2)
    records, summary = run_eval(cfg, tmp_path, progress=False)
    assert len(records) == 8
    assert {r["scene"] for r in records} == {"grid-test-00", "grid-test-01"}
    assert {r["goal"] for r in records} <= set(CLASSES)
    assert sum(r["success"] for r in records) >= 6
    for r in records:  # no ground truth for these: missing, never invented
        assert r["spl"] is None and r["dts"] is None and r["episode_id"] is None
        assert r["target_error"] is None
        assert r["failure"] in (None, "Exploration")
    for name in ("ans", "si"):
        assert summary[name]["spl"] is None and summary[name]["success"] >= 0.5
        assert "memory" not in summary[name]
    assert summary["si"]["vs_ans"]["spl"]["pairs"] == 0
    assert json.loads((tmp_path / "config.json").read_text())["env"] == "grid-test"
    stored = sorted((tmp_path / "memory" / "si").glob("*.graphml"))
    assert stored
    m = AbstractModel.load(stored[0])
    assert m.classes == CLASSES
    # built with opencv-gist's calibrated threshold, and recorded with it
    assert m.extractor == "opencv-gist" and m.relocation_threshold == 0.1006


def test_runner_reports_the_ground_truth_an_environment_offers():
    cfg = EvalConfig(env="grid-test-gt", variants=("ans",), segmenter="clean",
                     extractor="opencv-gist", max_steps=60, episodes=2, scenes=1)
    records, summary = run_eval(cfg, None, progress=False)
    assert [r["scene"] for r in records] == ["grid-room-0"] * 2
    assert [r["episode_id"] for r in records] == ["ep0", "ep1"]
    assert all(r["softspl"] == 0.5 and r["spl"] in (0.0, 1.0) for r in records)
    assert summary["ans"]["softspl"] == 0.5
    for r in records:
        if r["target_source"] is not None:
            assert r["target_error"] is not None and r["target_error"] < 1.5


def test_memory_update_merges_or_stores():
    models: dict = {}
    a = AbstractModel(4, model_id="h-e000", classes=CLASSES)
    assert absorb(models, a) == ("h-e000", [])
    b = AbstractModel(4, model_id="h-e001", classes=CLASSES)
    c = AbstractModel(4, model_id="h-e002", classes=CLASSES)
    absorb(models, b)
    changed, gone = absorb(models, c, into="h-e000", transform=(0.0, 0.0, 0.0),
                           bridges={"h-e001": (1.0, 0.0, 0.0)})
    assert (changed, gone, sorted(models)) == ("h-e000", ["h-e001"], ["h-e000"])
    assert absorb(models, AbstractModel(4, model_id="h-e003"), into="gone")[0] == "h-e003"


# ---------------------------------------------------------------------- protocol violations
def _one_line(e: BaseException) -> str:
    msg = str(e)
    assert "\n" not in msg
    return msg


@pytest.mark.parametrize(("change", "expected"), [
    (lambda o: {k: v for k, v in o.items() if k != "depth"}, "no 'depth'"),
    (lambda o: {**o, "depth": o["depth"].astype(np.float64)}, "'depth' must be float32"),
    (lambda o: {**o, "depth": o["depth"][:-1]}, "'depth' must have shape (48, 64)"),
    (lambda o: {**o, "rgb": o["rgb"].astype(np.float32)}, "'rgb' must be uint8"),
    (lambda o: {**o, "pose": np.zeros(2)}, "'pose' must be 3 floats"),
    (lambda o: {**o, "objectgoal": 7}, "'objectgoal' 7 is no class id (1..3)"),
    (lambda o: {k: v for k, v in o.items() if k != "semantic"}, "no 'semantic'"),
])
def test_observation_violations_are_one_line(change, expected):
    env = GridRoom(0)
    obs, _ = env.reset()
    with pytest.raises(EnvProtocolError) as e:
        check_observation(change(obs), env.env_spec)
    assert expected in _one_line(e.value) and "'grid'" in str(e.value)


def test_an_episode_that_declined_labels_may_lack_them():
    env = GridRoom(0)
    obs, _ = env.reset()
    bare = {k: v for k, v in obs.items() if k != "semantic"}
    check_observation(bare, env.env_spec, semantic=False)
    for asked in (None, True):
        with pytest.raises(EnvProtocolError, match="no 'semantic'"):
            check_observation(bare, env.env_spec, semantic=asked)
    with pytest.raises(EnvProtocolError, match="'semantic' must be an integer"):  # still checked
        check_observation({**obs, "semantic": obs["semantic"][..., 0]}, env.env_spec, False)


@pytest.mark.parametrize(("variant", "segmenter", "asked"), [
    ("ans", "depth-only", False),  # nothing reads the labels
    ("ans", "clean", True),  # the ground-truth segmenter reads them
    ("si", "depth-only", True),  # the memory's fidelity counts the instances seen
])
def test_the_benchmark_asks_for_labels_only_when_something_reads_them(variant, segmenter,
                                                                       asked, monkeypatch):
    from kgnav.agent.segmentation import SEGMENTERS
    from kgnav.nets.segnet.segmenter import ClassMapSegmenter

    seen = []

    class Spy(GridSuite):
        def make(self, k, n=None):
            room = super().make(k, n)
            reset = room.reset

            def spy(*, seed=None, options=None):
                seen.append(options.get("semantic"))
                return reset(seed=seed, options=options)

            room.reset = spy
            return room

    def near_crates(seed=0):  # RGB-D only: anything within a metre is a crate
        return ClassMapSegmenter(lambda rgb, depth: (depth < 1.0).astype(np.int32),
                                 name="depth-only", class_names=CLASSES)

    monkeypatch.setitem(SEGMENTERS, "depth-only", near_crates)
    name = f"grid-spy-{variant}-{segmenter}"  # the runner keeps environments by name
    register_env(name)(lambda o: Spy(o, hooks=True))
    try:
        cfg = EvalConfig(env=name, variants=(variant,), segmenter=segmenter,
                         extractor="opencv-gist", max_steps=5, episodes=1, scenes=1)
        run_eval(cfg, None, progress=False)
    finally:
        ENVS.pop(name, None)
    assert seen == [asked]


def test_runner_stops_on_a_broken_environment():
    class Broken(GridRoom):
        def _observe(self):
            obs = super()._observe()
            obs["depth"] = obs["depth"].astype(np.float64)
            return obs

    class BrokenSuite(GridSuite):
        def make(self, k, n=None):
            return Broken(k, n)

    register_env("grid-broken")(BrokenSuite)
    cfg = EvalConfig(env="grid-broken", variants=("ans",), segmenter="clean",
                     extractor="opencv-gist", max_steps=10, episodes=1, scenes=1)
    with pytest.raises(EnvProtocolError, match="'depth' must be float32, got float64"):
        run_eval(cfg, None, progress=False)


def test_unknown_classes_and_mismatched_vocabularies():
    env = GridRoom(0)
    spec = env.env_spec
    agent = ObjectNavAgent.for_env(env, _segmenter(spec), make_extractor("opencv-gist"))
    with pytest.raises(UnknownClassError, match="unknown object class 'chair'"):
        agent.reset("chair")
    with pytest.raises(EnvSpecError) as e:  # kgnav's vocabulary has none of the room's
        ObjectNavAgent.for_env(env, make_segmenter("clean"), make_extractor("opencv-gist"))
    msg = _one_line(e.value)
    assert "labels none of the environment's 3 classes (crate, barrel, cone)" in msg
    assert "it knows 24: chair" in msg
    with pytest.raises(UnknownClassError):
        spec.class_id("chair")


class OtherVocabulary:
    """A segmenter with its own vocabulary: the room's classes in another order, and more."""

    classes = ("tree", "cone", "lamp", "crate", "barrel")
    name = "other-vocabulary"

    def __init__(self, spec):
        self.inner = _segmenter(spec)

    def reset(self, seed, scene=""):
        self.inner.reset(seed, scene)

    def __call__(self, rgb, depth, semantic=None):
        seg = self.inner(rgb, depth, semantic)
        mine = np.array([0] + [self.classes.index(c) + 1 for c in CLASSES], np.int32)
        # what the room calls its object 1 (the crate) this one calls a lamp
        lamp = set(np.unique(seg.instances[semantic[..., 1] == 1]).tolist()) - {0}
        out = mine[seg.classes]
        out[np.isin(seg.instances, list(lamp))] = 3
        segments = [replace(sg, cls="lamp") if sg.id in lamp else sg for sg in seg.segments]
        return type(seg)(out, seg.instances, segments)


def test_a_segmenter_vocabulary_is_mapped_to_the_environments_by_name():
    env = GridRoom(0)
    spec = env.env_spec
    seg = OtherVocabulary(spec)
    # (no look-around: 8 of the room's 60 steps would go to turning in place)
    agent = ObjectNavAgent.for_env(env, seg, make_extractor("opencv-gist"),
                                   config=AgentConfig(look_around=False))
    obs, _ = env.reset(options={"episode": 0})
    agent.reset("crate")
    p = agent.extract(obs)
    ids = set(np.unique(p.segmentation.classes).tolist())
    names = {sg.cls for sg in p.segmentation.segments}
    assert names and names <= set(CLASSES) and ids <= {0, 1, 2, 3}
    crate = obs["semantic"][..., 1] == 1
    assert crate.any() and not p.segmentation.classes[crate].any()  # the "lamp": dropped
    info, _ = _run(env, agent, 1)  # the cone, labelled 2 by this segmenter and 3 by the room
    assert info["success"]


def test_specs_refuse_impossible_declarations():
    with pytest.raises(EnvSpecError, match="exactly one of hfov_deg, vfov_deg, fx"):
        CameraSpec(64, 48, hfov_deg=90.0, fx=30.0)
    with pytest.raises(EnvSpecError, match="depth range"):
        CameraSpec(64, 48, hfov_deg=90.0, min_depth=2.0, max_depth=1.0)
    with pytest.raises(EnvSpecError, match="must name each of stop"):
        ActionSpec(("stop", "move_forward", "turn_left"))
    with pytest.raises(EnvSpecError, match="turn_deg"):
        ActionSpec(turn_deg=0.0)
    with pytest.raises(EnvSpecError, match="declares no object classes"):
        EnvSpec("x", CAMERA)
    with pytest.raises(KgnavError, match="unknown environment 'nope'"):
        make_env("nope")
    with pytest.raises(KgnavError, match="unknown environment 'nope'"):
        EvalConfig(env="nope")


def test_ground_truth_segmenter_needs_a_semantic_frame():
    class NoSemantic(GridSuite):
        def make(self, k, n=None):
            env = GridRoom(k, n)
            env.env_spec = replace(env.env_spec, semantic=False)
            return env

    register_env("grid-broken")(NoSemantic)
    cfg = EvalConfig(env="grid-broken", variants=("ans",), segmenter="default",
                     extractor="opencv-gist", max_steps=5, episodes=1, scenes=1)
    with pytest.raises(EnvProtocolError, match="needs the ground-truth semantic frame"):
        run_eval(cfg, None, progress=False)


# ---------------------------------------------------------------------- kgnav's simulator
def test_kgnav_simulator_declares_what_the_agent_assumed():
    env = make_env("kgnav").make(0, 1)
    spec = env.env_spec
    assert spec.actions == ActionSpec() and spec.classes[0] == "chair" and spec.semantic
    assert spec.agent_radius == 0.18
    cam = Camera.from_env(env)
    assert cam == Camera(160, 120, 79.0, 0.88, 0.5, 5.0)
    assert np.array_equal(cam.ray_up, Camera().ray_up) and cam.focal == Camera().focal
    obs, _ = env.reset(seed=0, options={"episode": 0})
    check_observation(obs, spec)
    assert spec.observation_space().contains({k: obs[k] for k in spec.observation_space()})
    assert spec.action_space() == env.action_space


def test_observations_fit_the_declared_gymnasium_spaces():
    env = GridRoom(0)
    space = env.env_spec.observation_space()
    obs, _ = env.reset(options={"episode": 1})
    for a in (0, 1, 0, 2):
        assert space.contains(obs), {k: (v.dtype, v.shape) for k, v in obs.items()
                                     if hasattr(v, "dtype")}
        obs, *_ = env.step(a)
    assert set(space) == {"rgb", "depth", "pose", "objectgoal", "semantic"}


def test_oracle_needs_ground_truth_the_environment_lacks():
    cfg = EvalConfig(env="grid-test", variants=("oracle",), segmenter="clean",
                     extractor="opencv-gist", max_steps=5, episodes=1, scenes=1)
    with pytest.raises(EnvProtocolError) as e:
        run_eval(cfg, None, progress=False)
    assert "variant oracle needs the environment's ground truth (navigable_map, world_pose)" in (
        _one_line(e.value))


def test_agent_does_not_import_the_simulator():
    code = ("import sys, kgnav.agent.loop, kgnav.agent.oracle, kgnav.agent.noise_segmenters, "
            "kgnav.envs; bad = [m for m in sys.modules if m.startswith('kgnav.sim')]; "
            "print(bad); sys.exit(1 if bad else 0)")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert res.returncode == 0, res.stdout + res.stderr


# ---------------------------------------------------------------------- the command line
def _kgnav(argv, capsys) -> tuple[int, str, str]:
    from kgnav.cli import main

    with pytest.raises(SystemExit) as e:
        main(argv)
    out, err = capsys.readouterr()
    return e.value.code, out, err


def test_cli_eval_takes_an_environment_by_module_path(tmp_path, capsys):
    out = tmp_path / "eval"
    code, stdout, err = _kgnav(
        ["eval", "--env", "tests.test_envs:GridSuite", "--segmenter", "clean",
         "--extractor", "opencv-gist", "--variants", "ans", "--scenes", "1", "--episodes", "1",
         "--out", str(out), "--quiet"], capsys)
    assert code == 0, err
    (rec,) = [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines()]
    assert rec["scene"] == "tests.test_envs_GridSuite-00" and rec["goal"] == "crate"
    assert rec["spl"] is None and "–" in stdout  # missing metrics shown as a dash


def test_noise_only_for_environments_that_apply_it(capsys):
    """The benchmark's default noise goes to environments that say they apply it; one that
    does not is run (and recorded) without noise, and asking it for noise is one line."""
    assert env_applies_noise("kgnav") and not env_applies_noise("grid-test")
    assert EvalConfig(split="val-small").noise == "locobot"
    assert EvalConfig(env="grid-test").noise == "none"
    with pytest.raises(KgnavError, match="'grid-test' does not apply noise"):
        EvalConfig(env="grid-test", noise="locobot")
    with pytest.raises(KgnavError, match="does not apply noise"):
        EvalConfig(env="grid-test", actuation_noise=1.0)
    code, _out, err = _kgnav(["eval", "--env", "tests.test_envs:GridSuite", "--noise", "locobot",
                              "--quiet"], capsys)
    assert code != 0 and "does not apply noise" in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize(("env", "expected"), [
    ("nope", "unknown environment 'nope' (known: "),
    ("tests.test_envs:Nothing", "cannot be imported: AttributeError"),
    ("no_such_module_xyz:Env", "cannot be imported: ModuleNotFoundError"),
])
def test_cli_eval_refuses_unknown_environments_in_one_line(env, expected, capsys):
    code, _out, err = _kgnav(["eval", "--env", env, "--quiet"], capsys)
    assert code == 2 and expected in err and len(err.strip().splitlines()) == 1


# ---------------------------------------------------------------------- the README's adapter
README_NAMES = {"crate": "chair", "cone": "desk", "barrel": "barrel"}  # room -> README class
README_CLASSES = ("chair", "desk", "barrel")


class FakeMySim:
    """The hypothetical ``mysim`` simulator of the README's adapter, played by a GridRoom with
    the README's camera and kgnav's action geometry."""

    last = None  # the simulator that rendered last, for the ground-truth segmenter

    def __init__(self, scene: str):
        cam = CameraSpec(128, 96, vfov_deg=60.0, height_m=1.5, max_depth=10.0)
        self.room = GridRoom(int(scene[-1]), camera=cam, actions=ActionSpec())
        self.room.start = (0.0, 0.0, 0.0)

    @property
    def steps(self):
        return self.room.steps

    def place_agent(self, x, y, t):
        self.room.pose, self.room.steps, self.room.path = (x, y, t), 0, 0.0

    def agent_pose(self):
        return self.room.pose

    def act(self, name):
        self.room.move(name)

    def distance_to(self, goal):
        x, y, _ = self.room.pose
        return min(b.l2(x, y) for b in self.room.boxes if README_NAMES[b.cls] == goal)

    def render(self):
        rgb, depth, cls, inst = self.room.render()
        ids = np.array([0] + [README_CLASSES.index(README_NAMES[c]) + 1 for c in CLASSES])
        self.truth = np.stack([ids[cls], inst], -1)
        FakeMySim.last = self
        return rgb, depth


class MySimTruth:
    """Ground-truth segmentation of the fake simulator's last frame, in the README's
    vocabulary (the README's adapter gives no semantic frame)."""

    classes = README_CLASSES
    name = "mysim-truth"

    def __init__(self, seed=0):
        cam = Camera.from_intrinsics(128, 96, vfov_deg=60.0, max_depth=10.0)
        self.inner = make_segmenter("clean", seed, classes=README_CLASSES,
                                    hfov_deg=cam.hfov_deg, max_depth=10.0)

    def reset(self, seed, scene=""):
        self.inner.reset(seed, scene)

    def __call__(self, rgb, depth, semantic=None):
        return self.inner(rgb, depth, FakeMySim.last.truth)


def test_the_readme_adapter_runs(monkeypatch):
    import types
    from pathlib import Path

    from kgnav.agent.segmentation import SEGMENTERS

    doc = Path(__file__).resolve().parents[1] / "docs" / "bring-your-own-simulator.md"
    text = doc.read_text()
    section = text[text.index("# Bring your own simulator"):]
    code = section[section.index("```python\n") + 10:]
    code = code[:code.index("```")]
    mysim = types.ModuleType("mysim")
    mysim.load = FakeMySim
    mysim.scenes = lambda split: ["room0", "room1"]
    mysim.episodes = lambda scene: [types.SimpleNamespace(start=s, goal=README_NAMES[g])
                                    for s, g in EPISODES]
    monkeypatch.setitem(sys.modules, "mysim", mysim)
    monkeypatch.setitem(SEGMENTERS, "mysim-truth", MySimTruth)
    try:
        exec(compile(code, "README.md", "exec"), {"__name__": "readme_adapter"})
        cfg = EvalConfig(env="mysim", variants=("ans",), segmenter="mysim-truth",
                         extractor="opencv-gist", scenes=1, episodes=2)
        records, summary = run_eval(cfg, None, progress=False)
    finally:
        ENVS.pop("mysim", None)
    assert [(r["scene"], r["goal"]) for r in records] == [("room0", "chair"), ("room0", "desk")]
    assert all(r["success"] for r in records) and summary["ans"]["spl"] is None
