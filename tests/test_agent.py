"""The agent's parts against the simulator's ground truth, and the loop end to end."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from kgnav import query
from kgnav.agent.camera import Camera, to_frame
from kgnav.agent.features import make_extractor
from kgnav.agent.loop import AgentConfig, ObjectNavAgent
from kgnav.agent.mapping import MapBuilder
from kgnav.agent.memory import Memory
from kgnav.agent.oracle import OracleAgent
from kgnav.agent.planner import FMMPlanner, fmm_distance, reachable
from kgnav.agent.policy import FrontierPolicy, cooccurrence, frontiers, make_policy
from kgnav.agent.segmentation import make_segmenter
from kgnav.agent.state_creator import StateCreator
from kgnav.errors import KgnavError
from kgnav.memory.evidence import MISS_RANGE
from kgnav.memory.geometry import ScanGeometry, occupancy_from_scans
from kgnav.memory.model import ACTIONS
from kgnav.sim import ObjectNavEnv

TURN_AROUND = [3] * 12  # twelve right turns of 30 degrees: a full look around


@pytest.fixture(scope="module")
def env():
    return ObjectNavEnv("val-small", 0)


def _walk(env, actions, episode=0):
    obs, _ = env.reset(options={"episode": episode})
    frames = [obs]
    for a in actions:
        obs, *_ = env.step(a)
        frames.append(obs)
    return frames


def test_camera_back_projects_object_pixels_onto_the_object(env):
    cam = Camera.from_env(env)
    checked = 0
    for obs in _walk(env, TURN_AROUND):
        fwd, left, _up = cam.points(obs["depth"])
        inst = obs["semantic"][..., 1]
        for oid in np.unique(inst[inst > 0])[:3]:
            mask = (inst == oid) & (obs["depth"] < cam.max_depth - 1e-3)
            if mask.sum() < 30:
                continue
            x, y = to_frame(obs["pose"], fwd[mask], left[mask])
            wx, wy = env.start_frame_to_world(float(np.median(x)), float(np.median(y)))
            obj = next(o for o in env.scene.objects if o.id == oid)
            assert obj.distance_to(wx, wy) < 0.15
            checked += 1
    assert checked >= 5


def test_map_obstacles_match_ground_truth(env):
    cam = Camera.from_env(env)
    mb = MapBuilder(cam)
    for obs in _walk(env, TURN_AROUND + [1, 1, 1, 2, 2, 1, 1]):
        m = mb.update(obs["depth"], obs["pose"])
    nav = env.navigable_map()
    cells = np.argwhere(m.obstacle > 0)
    assert len(cells) > 200
    near = 0
    for i, j in cells:
        wx, wy = env.start_frame_to_world(*m.to_xy(i, j))
        a, b = nav.to_cell(wx, wy)
        near += bool(nav.obstacles[max(a - 1, 0):a + 2, max(b - 1, 0):b + 2].any())
    assert near / len(cells) > 0.95
    # the start cell is explored free space
    i, j = m.to_cell(0.0, 0.0)
    assert m.explored[i, j] and not m.obstacle[i, j]


def test_map_semantic_evidence_lands_on_the_right_class(env):
    cam = Camera.from_env(env)
    mb = MapBuilder(cam)
    seg = make_segmenter("clean")
    seg.reset(0)
    for obs in _walk(env, TURN_AROUND):
        m = mb.update(obs["depth"], obs["pose"], seg(obs["rgb"], obs["depth"], obs["semantic"]))
    nav = env.navigable_map()
    hits = 0
    for c, cls in enumerate(m.classes):
        for i, j in np.argwhere(m.semantic[c] > 0)[::3]:
            wx, wy = env.start_frame_to_world(*m.to_xy(i, j))
            assert nav.l2_to_class(wx, wy, cls) < 0.2
            hits += 1
    assert hits > 20


def test_state_creator_places_detections_on_their_objects(env):
    cam = Camera.from_env(env)
    sc = StateCreator(cam)
    seg = make_segmenter("clean")
    seg.reset(0)
    ext = make_extractor("opencv-gist")
    n = 0
    for obs in _walk(env, TURN_AROUND):
        state = sc(ext(obs["rgb"]), seg(obs["rgb"], obs["depth"], obs["semantic"]),
                   obs["depth"], obs["pose"])
        assert state.features.shape == (512,)
        for d in state.detections:
            wx, wy = env.start_frame_to_world(*d.position[:2])
            assert env.navigable_map().l2_to_class(wx, wy, d.cls) < 0.3
            assert d.distance > 0 and d.pixels >= sc.min_pixels
            n += 1
    assert n >= 5


def test_fmm_distance_goes_round_walls():
    trav = np.ones((40, 40), bool)
    trav[20, :35] = False  # a wall with a gap at the right
    goal = np.zeros_like(trav)
    goal[30, 5] = True
    d = fmm_distance(trav, goal)
    assert d[30, 5] == 0
    assert d[10, 5] > 2 * 30  # must go round through the gap, not 20 cells straight down
    assert np.isinf(d[20, 5])
    trav[20, :] = False
    assert np.isinf(fmm_distance(trav, goal)[10, 5])


@settings(max_examples=150, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), h=st.integers(2, 30), w=st.integers(2, 30),
       walls=st.floats(0.1, 0.6), slow=st.booleans())
def test_reachable_is_where_fast_marching_ends_finite(seed, h, w, walls, slow):
    # the planner skips a march that reachable() says cannot reach the agent: the two must
    # agree exactly, with and without a speed map
    rng = np.random.default_rng(seed)
    trav = rng.random((h, w)) > walls
    goal = np.zeros((h, w), bool)
    for _ in range(int(rng.integers(1, 4))):
        goal[rng.integers(h), rng.integers(w)] = True
    cell = (int(rng.integers(h)), int(rng.integers(w)))
    trav[cell] = True
    speed = rng.uniform(0.25, 1.0, (h, w)) if slow else None
    finite = math.isfinite(fmm_distance(trav, goal, speed=speed)[cell])
    assert reachable(trav | goal, cell, goal) == finite


def test_planner_reaches_turns_and_stops():
    cam = Camera()
    m = MapBuilder(cam, size=120).reset()
    goal = np.zeros((120, 120), bool)
    goal[60, 100] = True  # 2 m ahead
    p = FMMPlanner()
    assert p.plan(m, (0.0, 0.0, 0.0), goal, key="a").action == "move_forward"
    assert p.plan(m, (0.0, 0.0, math.pi / 2), goal, key="a").action == "turn_right"
    assert p.plan(m, (0.0, 0.0, -math.pi / 2), goal, key="a").action == "turn_left"
    goal[60, 60] = True
    assert p.plan(m, (0.0, 0.0, 0.0), goal, key="b").action == "stop"


def test_planner_avoids_bumped_cells():
    m = MapBuilder(Camera(), size=120).reset()
    goal = np.zeros((120, 120), bool)
    goal[60, 100] = True
    p = FMMPlanner()
    p.plan(m, (0.0, 0.0, 0.0), goal, key="g")
    for _ in range(3):
        p.note_collision(m, (0.0, 0.0, 0.0))
    plan = p.plan(m, (0.0, 0.0, 0.0), goal, key="g")
    assert plan.action in ("turn_left", "turn_right")  # straight ahead is now blocked


def test_prior_inflation_opens_a_doorway_the_remembered_walls_close():
    """A remembered wall across the way with a 0.5 m doorway (10 cells) and an open end far
    off: grown by the agent's full 0.23 m the doorway closes and the plan goes round the end;
    grown by 0.1 m it stays open and the plan goes through it. The agent's own obstacles
    always grow by the full radius."""
    m = MapBuilder(Camera(), size=160).reset()
    goal = np.zeros(m.shape, bool)
    goal[80, 120] = True  # 2 m ahead of the start (cell 80, 80)
    wall = np.zeros(m.shape, np.uint8)
    wall[60:160, 100] = 1  # x = +1 m, from the map's edge to 1 m beside the start's row
    wall[75:85, 100] = 0  # the doorway, straight ahead
    m.prior_obstacle, m.prior_explored = wall, np.zeros_like(wall)
    full = FMMPlanner().plan(m, (0.0, 0.0, 0.0), goal, key="g")
    thin = FMMPlanner(prior_inflation=0.1).plan(m, (0.0, 0.0, 0.0), goal, key="g")
    assert thin.distance < 2.3 < 2.8 < full.distance  # round the wall's end: over 3 m
    m.prior_obstacle = np.zeros_like(wall)
    m.obstacle[:] = wall  # the same wall seen by the agent itself: no way through
    assert FMMPlanner(prior_inflation=0.1).plan(m, (0.0, 0.0, 0.0), goal, key="g"
                                                ).distance > 2.8
    with pytest.raises(ValueError, match="prior_inflation"):
        FMMPlanner(prior_inflation=-0.1)
    with pytest.raises(ValueError, match="prior_inflation"):
        AgentConfig(prior_inflation=-1.0)


def test_frontier_policy_picks_frontiers_and_gives_up_when_closed():
    m = MapBuilder(Camera(), size=100).reset()
    m.explored[30:70, 30:70] = 1
    pol = FrontierPolicy()
    cell = pol.select(m, (0.0, 0.0, 0.0), "chair", FMMPlanner())
    lab, _sizes = frontiers(m)
    assert cell is not None and lab[cell] > 0
    m.obstacle[30:70, 30] = m.obstacle[30:70, 69] = 1
    m.obstacle[30, 30:70] = m.obstacle[69, 30:70] = 1
    assert pol.select(m, (0.0, 0.0, 0.0), "chair", FMMPlanner()) is None


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), narrow=st.floats(1.0, 40.0), slow=st.booleans())
@example(seed=5614751, narrow=38.5, slow=True)  # a travel time's band stopped 0.15 short
def test_a_narrow_march_is_the_whole_march_cut_off(seed, narrow, slow):
    rng = np.random.default_rng(seed)
    trav = rng.random((40, 50)) > 0.2
    goal = np.zeros((40, 50), bool)
    goal[rng.integers(40), rng.integers(50)] = True
    speed = rng.uniform(0.25, 1.0, (40, 50)) if slow else None
    full = fmm_distance(trav, goal, speed=speed)
    cut = fmm_distance(trav, goal, speed=speed, narrow=narrow)
    inside = np.isfinite(cut)
    assert np.array_equal(cut[inside], full[inside])
    # (+0.5 of a cell each); a travel time's narrow band stops up to 2 short (skfmm)
    below = full < narrow - (2.0 if slow else 0.0)
    assert inside[below].all()


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), band=st.sampled_from([0.3, 1.0, 2.0]))
def test_the_policys_narrow_first_march_picks_what_the_whole_march_picks(seed, band):
    rng = np.random.default_rng(seed)
    m = MapBuilder(Camera(), size=160).reset()
    for _ in range(6):  # explored rooms of random sizes, walls with gaps
        i, j = rng.integers(20, 120, 2)
        h, w = rng.integers(8, 40, 2)
        m.explored[i:i + h, j:j + w] = 1
        if rng.random() < 0.5:
            m.obstacle[i, j:j + w] = 1
            m.obstacle[i, j + w // 2:j + w // 2 + 8] = 0
    m.explored[74:86, 74:86] = 1
    pose = (*m.to_xy(80, 80), float(rng.uniform(-3, 3)))
    whole, first = FrontierPolicy(), FrontierPolicy()
    whole.BAND = math.inf  # one march over everything, as before the narrow march
    first.BAND = band
    assert (first.select(m, pose, "chair", FMMPlanner())
            == whole.select(m, pose, "chair", FMMPlanner()))


def test_a_big_frontier_beyond_the_narrow_march_still_wins():
    """A small frontier 1.1 m away and a long one 2 m away, whose size takes 1.6 m off its
    cost: a first march of 0.3 m (+ 1.6) sees only the small one, which costs more than the
    long one could; the policy must march on and pick the long one, as one whole march does."""
    m = MapBuilder(Camera(), size=160).reset()
    m.explored[70:91, 70:91] = 1  # round the agent: nearer than min_distance
    m.explored[102:107, 78:83] = 1  # small, 1.1 m
    m.explored[40:121, 120:160] = 1  # long, 2 m
    lab, sizes = frontiers(m)
    pose = (*m.to_xy(80, 80), 0.0)
    picks = {}
    for band in (0.3, 6.0, math.inf):
        pol = FrontierPolicy()
        pol.BAND = band
        cell = pol.select(m, pose, "chair", FMMPlanner())
        picks[band] = cell
    assert sizes[lab[picks[math.inf]]] == sizes.max()
    assert picks[0.3] == picks[6.0] == picks[math.inf]


def test_an_agent_walled_in_by_its_own_inflated_marks_still_finds_a_way_out():
    """Between a wall and furniture 15 cm either side, with a bump mark ahead and one behind,
    inflation (even squeezed) seals the agent's patch: the policy once chose nothing, and the
    agent turned in place until the step limit. Planning on the bare obstacles lets it out."""
    m = MapBuilder(Camera(), size=120).reset()
    m.explored[30:90, 30:90] = 1
    m.obstacle[57, 40:80] = m.obstacle[63, 40:80] = 1
    m.bumped[60, 57] = m.bumped[60, 63] = 1
    pose = (*m.to_xy(60, 60), 0.0)
    planner, policy = FMMPlanner(), FrontierPolicy()
    for kw in ({}, {"squeeze": True}):
        trav = planner.traversable(m, (30, 90, 30, 90), (60, 60), **kw)
        assert not trav[30, 25] and not trav[30, 35]  # sealed either way
    cell = policy.select(m, pose, "chair", planner)
    assert cell is not None
    goal = np.zeros(m.shape, bool)
    goal[cell] = True
    plan = planner.plan(m, pose, goal, key="out")
    assert math.isfinite(plan.distance) and plan.distance > 0.5
    m.bumped[58:63, 57] = 1  # marks across the whole corridor: closed for good
    m.bumped[58:63, 63] = 1
    assert policy.select(m, pose, "chair", FMMPlanner()) is None


def test_the_planner_reaches_a_frontier_the_policy_took_from_the_memorys_bare_map():
    """A room the agent's own map walls in (its east doorway, 0.3 m, closed by inflation),
    whose east part only a remembered model has seen, and beyond the doorway a corridor as
    narrow that the memory saw up to its end. With the memory's knowledge nothing is left to
    explore in the room: the frontier policy takes the corridor's end from the bare obstacles.
    Without it, the room's unseen part looked like space to explore, so the planner refused
    the bare map, every plan to that frontier ended inf, and the agent turned in place to the
    step limit (train_08, episode 8: 400 steps)."""
    m = MapBuilder(Camera(), size=160).reset()
    room = (slice(60, 101), slice(50, 102))  # with its walls
    m.explored[60:101, 50:90] = 1  # the agent saw the room's west part only
    m.obstacle[60, 50:102] = m.obstacle[100, 50:102] = 1
    m.obstacle[60:101, 50] = m.obstacle[60:101, 101] = 1
    m.obstacle[78:84, 101] = 0  # the doorway, 6 cells
    prior = np.zeros_like(m.obstacle)
    prior[77, 101:126] = prior[84, 101:126] = 1  # the corridor's walls, memory only
    seen = np.zeros_like(m.obstacle)
    seen[room] = 1
    seen[77:85, 101:126] = 1
    m.prior_obstacle, m.prior_explored = prior, seen
    m.prior_searched = np.zeros_like(seen)
    pose = (*m.to_xy(80, 70), 0.0)
    # frontiers of unseen space, as when the deadlock happened (the memory searched nothing)
    planner, policy = FMMPlanner(), FrontierPolicy(search_memory=False)
    crop = planner.window(m, (80, 70), seen > 0)
    assert not planner.sealed(m, crop, (80, 70), prior=False)  # the room's unseen part
    assert planner.sealed(m, crop, (80, 70))  # ... is no space to explore to the memory
    cell = policy.select(m, pose, "chair", planner)
    assert cell is not None and cell[1] == 125  # the corridor's end
    goal = np.zeros(m.shape, bool)
    goal[cell[0] - 5:cell[0] + 6, cell[1] - 5:cell[1] + 6] = True
    plan = planner.plan(m, pose, goal, key="corridor")
    assert math.isfinite(plan.distance) and plan.distance > 2.0
    m.prior_explored[room] = 0  # the memory never saw the room: the unseen part is to explore
    assert not math.isfinite(FMMPlanner().plan(m, pose, goal, key="corridor").distance)


def test_the_planner_and_the_policy_fall_back_in_one_order():
    """passable: inflated, squeezed, (drop_prior) without the memory's walls, then the bare
    map only when sealed in; the first that reaches the targets is the one returned."""
    m = MapBuilder(Camera(), size=120).reset()
    m.explored[30:91, 30:91] = 1
    m.obstacle[30, 30:91] = m.obstacle[90, 30:91] = 1
    m.obstacle[30:91, 30] = m.obstacle[30:91, 90] = 1
    agent, crop = (60, 50), (20, 100, 20, 100)
    planner = FMMPlanner()
    same = lambda a, b: b is not None and np.array_equal(a, b)  # noqa: E731
    inside = np.zeros((80, 80), bool)
    inside[40, 55] = True  # (60, 75) on the map: in the room
    assert same(planner.traversable(m, crop, agent), planner.passable(m, crop, agent, inside))
    outside = np.zeros((80, 80), bool)
    outside[40, 78] = True  # (60, 98): beyond the east wall
    m.obstacle[55:65, 90] = 0  # a 0.5 m doorway: closed by inflation, open when squeezed
    assert same(planner.traversable(m, crop, agent, squeeze=True),
                planner.passable(m, crop, agent, outside))
    m.obstacle[55:65, 90] = 1  # closed: sealed in by its own map, only the bare map is left
    m.obstacle[59:61, 90] = 0  # a 0.1 m gap the agent does not fit
    assert planner.sealed(m, crop, agent)
    assert same(planner.traversable(m, crop, agent, bare=True),
                planner.passable(m, crop, agent, outside))
    m.explored[60, 70] = 0  # a cell left to explore: not sealed, so not the bare map
    assert planner.passable(m, crop, agent, outside) is None
    m.explored[60, 70] = 1
    m.obstacle[50:70, 90] = 0  # a 1 m doorway, closed by a memory's wall only
    m.prior_obstacle = np.zeros_like(m.obstacle)
    m.prior_obstacle[45:75, 91] = 1
    m.prior_explored = m.explored.copy()
    assert planner.passable(m, crop, agent, outside, enter_targets=True) is None
    assert same(planner.traversable(m, crop, agent, prior=False),
                planner.passable(m, crop, agent, outside, drop_prior=True, enter_targets=True))


def test_a_goal_behind_a_gap_the_agent_does_not_fit_stays_out_of_reach():
    """Not walled in (space left to explore), only facing a goal behind a 10 cm gap: the bare
    map would lead the agent to push at the gap, so the planner says unreachable (and the
    agent picks another goal)."""
    m = MapBuilder(Camera(), size=120).reset()
    m.explored[20:100, 20:110] = 1  # unexplored space beyond: the agent is not walled in
    m.obstacle[40:80, 80] = m.obstacle[40:80, 100] = 1
    m.obstacle[40, 80:101] = m.obstacle[80, 80:101] = 1
    m.obstacle[59:61, 80] = 0  # a 10 cm gap
    goal = np.zeros(m.shape, bool)
    goal[60, 90] = True
    planner = FMMPlanner()
    pose = (*m.to_xy(60, 40), 0.0)
    assert not planner.sealed(m, (10, 110, 10, 118), (60, 40))
    assert not math.isfinite(planner.plan(m, pose, goal, key="boxed").distance)
    bare = planner.traversable(m, (0, 120, 0, 120), (60, 40), bare=True)
    assert math.isfinite(fmm_distance(bare, goal)[60, 40])  # the bare map would go in


def test_remembered_walls_guide_the_planner_but_never_rule_a_goal_out():
    """A goal boxed in by walls only a remembered model saw (a doorway its coarse range
    profiles caught as closed) is still planned for; boxed in by walls the agent saw itself
    it is not."""
    m = MapBuilder(Camera(), size=120).reset()
    goal = np.zeros((120, 120), bool)
    goal[60, 100] = True
    box = np.zeros((120, 120), np.uint8)
    box[50:71, 90] = box[50:71, 110] = box[50, 90:111] = box[70, 90:111] = 1
    m.prior_obstacle, m.prior_explored = box.copy(), np.zeros_like(box)
    plan = FMMPlanner().plan(m, (0.0, 0.0, 0.0), goal, key="g")
    assert math.isfinite(plan.distance)
    m.prior_obstacle = m.prior_explored = None
    m.obstacle |= box
    assert not math.isfinite(FMMPlanner().plan(m, (0.0, 0.0, 0.0), goal, key="g").distance)


def test_with_a_remembered_prior_the_planner_prefers_the_way_the_memory_knows():
    """Goal 2 m ahead; a remembered model knows an L-shaped free corridor to it (to the left,
    ahead, back) but not the straight line. Unknown space counted as free (speed 1, the
    memory-less view) heads straight; counted slower, the plan follows the known corridor.
    Without a prior the slowdown changes nothing."""
    m = MapBuilder(Camera(), size=120).reset()
    goal = np.zeros((120, 120), bool)
    goal[60, 100] = True  # 2 m along +x; rows are y
    known = np.zeros((120, 120), np.uint8)
    known[58:63, 58:63] = 1
    known[58:82, 58:63] = known[77:82, 58:103] = known[58:82, 98:103] = 1  # left, ahead, back
    m.prior_explored, m.prior_obstacle = known, np.zeros_like(known)
    straight = FMMPlanner(unknown_speed=1.0).plan(m, (0.0, 0.0, 0.0), goal, key="g")
    around = FMMPlanner(unknown_speed=0.3).plan(m, (0.0, 0.0, 0.0), goal, key="g")
    assert straight.action == "move_forward" and abs(straight.waypoint[1]) < 0.1
    assert around.action == "turn_left" and around.waypoint[1] > 0.2
    m.prior_explored = m.prior_obstacle = None
    plain = FMMPlanner(unknown_speed=0.3).plan(m, (0.0, 0.0, 0.0), goal, key="g")
    assert plain.action == "move_forward" and plain.distance == pytest.approx(
        straight.distance, abs=0.06)
    with pytest.raises(ValueError, match="unknown_speed"):
        FMMPlanner(unknown_speed=0.0)
    with pytest.raises(ValueError, match="unknown_speed"):
        AgentConfig(unknown_speed=1.5)


def test_when_the_memory_leaves_no_frontier_the_agent_looks_again_where_it_has_not():
    """A remembered model covers the whole map, so no frontier is left with it; the policy
    then picks a frontier of what the agent itself has seen, instead of giving up."""
    m = MapBuilder(Camera(), size=100).reset()
    m.explored[45:55, 45:55] = 1
    m.prior_explored = np.ones_like(m.explored)
    m.prior_obstacle = np.zeros_like(m.explored)
    assert not frontiers(m)[1].any()
    pol = FrontierPolicy()
    cell = pol.select(m, (0.0, 0.0, 0.0), "chair", FMMPlanner())
    assert cell is not None and frontiers(m, prior=False)[0][cell] > 0


def test_the_map_marks_as_searched_only_what_it_saw_from_close_range():
    """A frame looking down an empty 5 m corridor explores all of it but searches only the
    first 3 m (where a miss counts against an object); a remembered model's close views seed
    ``prior_searched`` the same way, and a refuted memory takes them back."""
    mb = MapBuilder(Camera(), size=240)
    m = mb.update(np.full((120, 160), 5.0, np.float32), (0.0, 0.0, 0.0))
    for x, searched in ((1.0, 1), (2.5, 1), (3.5, 0), (4.5, 0)):
        assert m.explored[m.to_cell(x, 0.0)] == 1
        assert m.searched[m.to_cell(x, 0.0)] == searched, x
    assert m.searched_any().sum() == m.searched.sum()  # no memory yet
    scan = ScanGeometry(79.0, 40, 5.0)
    grid = occupancy_from_scans(scan, [(0.0, 0.0, math.pi)], [np.full(40, 5.0)],
                                near_range=MISS_RANGE)
    assert grid.searched[grid.cell(-2.0, 0.0)] and not grid.searched[grid.cell(-4.0, 0.0)]
    assert grid.known_free[grid.cell(-4.0, 0.0)]
    assert not occupancy_from_scans(scan, [(0.0, 0.0, 0.0)], [np.full(40, 5.0)]).searched.any()
    mb.seed(grid, (0.0, 0.0, 0.0))
    assert m.prior_searched[m.to_cell(-2.0, 0.0)] and not m.prior_searched[m.to_cell(-4.0, 0.0)]
    assert m.prior_explored[m.to_cell(-4.0, 0.0)]
    m.cover(-50, 300, -50, 300)  # growing keeps every layer aligned
    assert m.prior_searched.shape == m.searched.shape == m.explored.shape
    assert m.searched[m.to_cell(2.5, 0.0)] and m.prior_searched[m.to_cell(-2.0, 0.0)]
    m.forget_prior()
    assert m.prior_searched is None and m.prior_explored is None


def test_with_a_memory_that_saw_everything_the_policy_searches_where_it_looked_only_from_afar():
    """The memory has seen the whole map, but searched (from close range) only its west half:
    the goal is not believed in it, so the next frontier is one into the east half
    (``unsearched``), not one of the agent's own frontiers; without ``search_memory``, or with
    the memory searched everywhere, the agent's own frontiers (``episode``)."""
    def world():
        m = MapBuilder(Camera(), size=100).reset()
        m.explored[45:55, 45:55] = m.searched[45:55, 45:55] = 1
        m.prior_explored = np.ones_like(m.explored)
        m.prior_obstacle = np.zeros_like(m.explored)
        m.prior_searched = np.zeros_like(m.explored)
        m.prior_searched[:, :55] = 1  # west of x = 0.25 m
        return m

    m = world()
    pol = FrontierPolicy(search_memory=True)
    cell = pol.select(m, (0.0, 0.0, 0.0), "chair", FMMPlanner())
    assert pol.source_ == "unsearched"
    assert cell is not None and m.to_xy(*cell)[0] > 0.0 and m.searched_any()[cell]
    assert frontiers(m, searched=True)[0][cell] > 0
    off = FrontierPolicy(search_memory=False)  # space nobody has seen, then the episode's own
    assert not FrontierPolicy().search_memory  # the default
    cell = off.select(world(), (0.0, 0.0, 0.0), "chair", FMMPlanner())
    assert off.source_ == "episode" and cell is not None
    m = world()
    m.prior_searched[:] = 1
    pol.select(m, (0.0, 0.0, 0.0), "chair", FMMPlanner())
    assert pol.source_ == "episode"
    m.prior_explored = m.prior_obstacle = m.prior_searched = None  # no memory at all
    pol.select(m, (0.0, 0.0, 0.0), "chair", FMMPlanner())
    assert pol.source_ == "unobserved"


def test_the_semantic_policy_looks_near_what_the_memory_remembers():
    """Two frontiers as far from the agent, one east, one west; the memory believes a TV
    stands near the east one, and TVs go with sofas: with ``remembered`` the policy heads
    east for a sofa; without, or for a class the TV tells nothing of, west (ties: lowest
    index)."""
    from kgnav.agent.policy import SemanticFrontierPolicy

    def world():
        m = MapBuilder(Camera(), size=100).reset()
        m.explored[39:62, 20:81] = 1  # a 1 m corridor open at both ends, its walls seen
        m.obstacle[39, 20:81] = m.obstacle[61, 20:81] = 1
        m.prior_objects = (("tv_monitor", 1.4, 0.0, 0.9),)
        return m

    co = {"sofa": {"tv_monitor": 0.8}}
    for remembered, goal, east in ((True, "sofa", True), (False, "sofa", False),
                                   (True, "bed", False)):
        pol = SemanticFrontierPolicy(remembered=remembered)
        pol.cooccurrence_ = co
        cell = pol.select(world(), (0.0, 0.0, 0.0), goal, FMMPlanner())
        assert cell is not None and (world().to_xy(*cell)[0] > 0) is east, (remembered, goal)
    m = world()
    m.forget_prior()
    assert m.prior_objects == ()


def test_remembered_objects_come_in_the_episode_frame_if_believed():
    from kgnav import AbstractModel, Detection
    from kgnav.agent.loop import remembered_objects
    from kgnav.memory.evidence import DEFAULT_BELIEF

    m = AbstractModel(2, model_id="e", scan=ScanGeometry(90.0, 4, 5.0))
    far = np.full(4, 5.0)
    for k in range(3):  # a chair seen three times at (2, 0); a plant once, then missed twice
        dets = [Detection("chair", (2.0, 0.0, 0.4))]
        if k == 0:
            dets.append(Detection("plant", (1.0, 0.5, 0.4)))
        m.add_state([1.0, float(k)], (0.0, 0.0, 0.0), dets, ranges=far)
    # the episode frame is the model's moved 1 m along x and turned 90 degrees
    out = remembered_objects(m, (1.0, 0.0, math.pi / 2), DEFAULT_BELIEF)
    assert [o[0] for o in out] == ["chair"]
    cls, x, y, b = out[0]
    assert (x, y) == pytest.approx((0.0, -1.0)) and b >= 0.5


def test_exploring_as_if_the_memory_had_not_seen_its_space():
    """The memory saw the west half: by default the policy explores beyond it (a frontier of
    space nobody saw); with ``beyond_memory`` off (``AgentConfig.explore_beyond_memory``), a
    frontier of the agent's own map, wherever the memory looked."""
    def world():
        m = MapBuilder(Camera(), size=100).reset()
        m.explored[40:61, 44:61] = 1  # its own frontier nearest the agent lies west
        m.prior_explored = np.zeros_like(m.explored)
        m.prior_explored[:, :50] = 1
        m.prior_obstacle = np.zeros_like(m.explored)
        m.prior_searched = m.prior_explored.copy()
        return m

    on, off = FrontierPolicy(), FrontierPolicy(beyond_memory=False)
    cell = on.select(world(), (0.0, 0.0, 0.0), "chair", FMMPlanner())
    assert on.source_ == "unobserved" and frontiers(world())[0][cell] > 0
    cell = off.select(world(), (0.0, 0.0, 0.0), "chair", FMMPlanner())
    assert off.source_ == "episode" and frontiers(world(), prior=False)[0][cell] > 0
    assert not frontiers(world())[0][cell]  # the memory had seen past it
    agent = ObjectNavAgent(Camera(), make_segmenter("clean"), make_extractor("opencv-gist"),
                           config=AgentConfig(explore_beyond_memory=False, search_memory=True))
    assert agent.policy.beyond_memory is False and agent.policy.search_memory is True


def test_policy_registry_and_cooccurrence(tiny):
    assert make_policy("semantic").name == "semantic"
    with pytest.raises(KgnavError, match="unknown global policy"):
        make_policy("nope")
    co = cooccurrence([tiny])
    assert co["sofa"]["chair"] == pytest.approx(1 / 3)  # the sofa is in 1 of 3 chair views
    assert co["chair"]["sofa"] == 1.0


def _run(env, agent, episode, seed=0):
    obs, info = env.reset(seed=seed, options={"episode": episode})
    agent.reset(env.goal_class, seed=seed, scene=env.scene.name, episode=episode,
                model_id=f"m{episode}")
    actions = []
    done = False
    while not done:
        a = agent.act(obs)
        actions.append(a)
        obs, _r, term, trunc, info = env.step(a)
        done = term or trunc
    return info, actions


def _agent(env, segmenter="clean", memory=None, **cfg):
    return ObjectNavAgent(Camera.from_env(env), make_segmenter(segmenter, 0),
                          make_extractor("opencv-gist"), memory=memory,
                          config=AgentConfig(**cfg))


def test_agent_finds_goals_with_a_clean_segmenter_and_is_deterministic(env):
    agent = _agent(env)
    wins = 0
    for ep in range(3):
        info, actions = _run(env, agent, ep)
        wins += info["success"]
        assert actions[-1] == ACTIONS.index("stop") or info["steps"] == env.max_steps
    assert wins >= 2
    _info, again = _run(env, _agent(env, "default"), 1, seed=5)
    _info, third = _run(env, _agent(env, "default"), 1, seed=5)
    assert again == third
    # the model it learned holds the goal it stopped at
    assert agent.model_.n_states > 10
    assert agent.model_.n_objects > 0


def test_agent_relocates_into_a_memory_of_the_same_house(env):
    agent = _agent(env)
    _run(env, agent, 0)
    first = agent.model_
    memory = Memory({first.model_id: first}, threshold=0.3)
    reloc_agent = _agent(env, memory=memory)
    info, _ = _run(env, reloc_agent, 0)  # same start: the first views match
    r = reloc_agent.relocation_
    assert r is not None and r.model_id == first.model_id
    assert r.step <= 6  # two agreeing, geometrically verified matches
    # same start pose: the transform is (nearly) the identity
    assert math.hypot(r.transform[0], r.transform[1]) < 0.3
    assert abs(r.transform[2]) < math.radians(10)
    # the merged model now holds the goal and the agent used it
    assert reloc_agent.current_.n_states > first.n_states
    assert info["success"]


def test_empty_memory_never_relocates(env):
    agent = _agent(env, memory=Memory({}))
    _run(env, agent, 1)
    assert agent.relocation_ is None


def test_agent_config_rejects_bad_strategy():
    with pytest.raises(ValueError, match="strategy"):
        AgentConfig(strategy="reckless")


def test_oracle_succeeds_almost_always():
    env = ObjectNavEnv("val", 1)
    oracle = OracleAgent(env)
    wins = 0
    for ep in range(6):
        obs, _ = env.reset(options={"episode": ep})
        oracle.reset(env.goal_class)
        done = False
        while not done:
            obs, _r, term, trunc, info = env.step(oracle.act(obs))
            done = term or trunc
        wins += info["success"]
        assert info["spl"] > 0.5 or not info["success"]
    assert wins >= 5


def test_goal_point_skips_excluded_and_rarely_seen(tiny):
    chair = query.goal_point(tiny, "chair")
    assert chair is not None
    assert query.goal_point(tiny, "chair", exclude={chair.id}) is None
    assert query.goal_point(tiny, "sofa", min_views=2) is None
    assert query.goal_point(tiny, "sofa", min_views=1) is not None


@settings(max_examples=50)
@given(st.floats(-5, 5), st.floats(-5, 5), st.floats(-math.pi + 1e-3, math.pi - 1e-3),
       st.integers(0, 10_000))
def test_rigid_fit_recovers_a_transform(tx, ty, theta, seed):
    from kgnav.common import se2
    from kgnav.common.se2 import fit_points as _rigid_fit

    src = np.random.default_rng(seed).uniform(-4, 4, (6, 2))
    dst = se2.apply_to_points((tx, ty, theta), src)
    fx, fy, ft = _rigid_fit(src, dst)
    assert fx == pytest.approx(tx, abs=1e-6) and fy == pytest.approx(ty, abs=1e-6)
    assert se2.angle_diff(ft, theta) < 1e-6


def test_transitions_are_counted_once_per_step(env):
    agent = _agent(env)
    obs, _ = env.reset(seed=0, options={"episode": 0})
    agent.reset(env.goal_class, seed=0, scene=env.scene.name)
    for _ in range(12):
        obs, *_ = env.step(agent.act(obs))
    counts = sum(d["count"] for *_e, d in agent.model_.graph.edges(data=True)
                 if d.get("kind") == "transition")
    assert counts == 11


def test_look_around_turns_a_full_circle_before_moving(env):
    """With ``look_around`` the agent turns a full circle first (turns add no path length),
    unless a goal shows on the way; without it, it sets off at once."""
    turn = ACTIONS.index("turn_left")
    full = 0
    for ep in range(3):
        agent = _agent(env, look_around=True)
        obs, _ = env.reset(seed=0, options={"episode": ep})
        agent.reset(env.goal_class, seed=0, scene=env.scene.name, episode=ep)
        first = []
        for _ in range(env.env_spec.actions.full_turn):
            a = agent.act(obs)
            first.append(a)
            obs, *_ = env.step(a)
            if agent._target is not None and agent._target.is_object:
                break  # the goal came into view: the turn ends
        if agent._target is None or not agent._target.is_object:
            assert first == [turn] * env.env_spec.actions.full_turn
            full += 1
        _info, plain = _run(env, _agent(env, look_around=False), ep)
        assert plain[:12] != [turn] * 12
    assert full >= 1


def test_a_goal_in_view_replaces_a_remembered_one_only_if_believed_as_much(env):
    """Soft strategy on the way to a chair seen in many earlier visits, a 'chair' glimpsed
    twice elsewhere (a segmenter's false positive) does not take over with ``live_override =
    'belief'``; with the paper's ``'always'`` it does. The same place always does."""
    from kgnav.agent.loop import Target
    from kgnav.memory.evidence import ScanTable
    from kgnav.memory.model import AbstractModel, Detection

    m = AbstractModel(4, model_id="mem")
    for k in range(12):
        m.add_state(np.eye(4)[k % 4], (0.0, 0.1 * k, 0.0), [Detection("chair", (4.0, 0.0, 0.4))],
                    episode=k // 4)
    for k in range(2):
        m.add_state(np.eye(4)[k], (1.0, 0.0, 0.0), [Detection("chair", (1.0, 3.0, 0.4))])
    strong, weak = sorted(m.objects(), key=lambda o: -m.graph.nodes[o]["n_views"])
    for mode, takes in (("belief", False), ("always", True)):
        agent = _agent(env, memory=Memory({}), live_override=mode)
        agent.reset("chair")
        agent.current_, agent._scans = m, ScanTable(m)
        remembered = Target("memory", (4.0, 0.0), strong)
        assert agent._overrides(Target("live", (1.0, 3.0), weak), remembered) is takes
        assert agent._overrides(Target("live", (4.2, 0.1), strong), remembered)
    with pytest.raises(ValueError, match="live_override"):
        AgentConfig(live_override="sometimes")


@given(seed=st.integers(0, 10_000), density=st.floats(0.0, 0.05),
       at=st.tuples(st.integers(0, 59), st.integers(0, 59)))
@settings(max_examples=60, deadline=None)
def test_the_path_check_on_a_window_agrees_with_inflating_the_whole_crop(seed, density, at):
    """The planner checks the path ahead every step on a window around it; it must say what
    inflating the whole planning window would say (or it would replan differently)."""
    rng = np.random.default_rng(seed)
    m = MapBuilder(Camera(), size=80).reset()
    m.obstacle[:] = rng.random(m.shape) < density
    m.bumped[:] = rng.random(m.shape) < density / 4
    crop = (10, 70, 10, 70)
    agent = (10 + at[0], 10 + at[1])
    planner = FMMPlanner()
    trav = planner.traversable(m, crop, agent)
    for _ in range(5):
        n = int(rng.integers(1, 9))
        steps = rng.integers(-1, 2, size=(n, 2)).cumsum(axis=0)
        path = [(int(np.clip(agent[0] + di, 10, 69)), int(np.clip(agent[1] + dj, 10, 69)))
                for di, dj in steps]
        expected = any(not trav[i - 10, j - 10] for i, j in path)
        assert planner.path_blocked(m, crop, agent, path) == expected


def test_weak_views_reach_the_model_only_when_asked(env):
    """With ``weak_score`` the learned segmenter's sub-threshold segments become views of
    their objects, scored under its threshold; without it (the default) none is stored, and a
    memory-less agent that did not ask leaves the shared segmenter as it found it."""
    seg = make_segmenter("learned", 0)
    threshold = seg.min_score
    scores = {}
    for weak_score in (None, 0.3):
        agent = ObjectNavAgent(Camera.from_env(env), seg, make_extractor("opencv-gist"),
                               config=AgentConfig(weak_score=weak_score))
        assert seg.weak_score == weak_score
        _run(env, agent, 0)
        g = agent.model_.graph
        scores[weak_score] = [d["score"] for *_e, k, d in g.edges(keys=True, data=True)
                              if k == "sees"]
    assert scores[None] and min(scores[None]) >= threshold
    assert any(0.3 <= s < threshold for s in scores[0.3])
    ObjectNavAgent(Camera.from_env(env), seg, make_extractor("opencv-gist"))
    assert seg.weak_score is None


def test_a_way_round_that_keeps_growing_past_the_detour_ratio_is_given_up(env):
    """The replayed val_00 failure: a goal 2.4 m away behind a wall, each way round the map
    reveals longer than the last (23, 36, 58, 100 m). With ``detour_ratio`` the object is
    given up at the second growth past the limit; without it each longer way round restarts
    the stall clock and the agent walks them to the step limit. One long way round that then
    shortens as the agent walks it is never given up."""
    from types import SimpleNamespace

    from kgnav.agent.loop import Target
    from kgnav.agent.planner import Plan

    def walk(distances, **cfg):
        agent = _agent(env, **cfg)
        agent.reset("chair")
        target = agent._set_target(Target("episode", (2.4, 0.0), "chair_1"))
        p = SimpleNamespace(state=SimpleNamespace(pose=(0.0, 0.0, 0.0), detections=[]))
        for step, d in enumerate(distances):
            agent.step_ = step
            action = agent._approach(target, Plan("move_forward", False, d, None), p)
            if action is None:
                return step, agent.log_
        return None, agent.log_

    growing = [23.0] * 10 + [36.0] * 10 + [58.0] * 10 + [100.0] * 10
    assert walk(growing)[0] is None  # off by default: walked on
    step, log = walk(growing, detour_ratio=3.0)
    assert step == 20 and log.detour_drops == [(20, "chair_1")] and log.rejected == ["chair_1"]
    assert walk(growing, detour_ratio=50.0)[0] is None  # the limit, 122 m, is never passed
    one_long_way = [5.0, 15.0] + [15.0 - 0.25 * k for k in range(1, 40)]
    assert walk(one_long_way, detour_ratio=3.0)[0] is None
    with pytest.raises(ValueError, match="detour_ratio"):
        AgentConfig(detour_ratio=0.5)


def _stalled_approach(target, **cfg) -> list:
    """What the agent does at each step while a plan toward ``target`` makes no progress
    (pressed against furniture: the plan says forward, the pose never changes)."""
    from types import SimpleNamespace

    from kgnav.agent.planner import Plan

    env = ObjectNavEnv("val-small", 0)
    agent = ObjectNavAgent(Camera.from_env(env), make_segmenter("clean", 0),
                           make_extractor("opencv-gist"), config=AgentConfig(**cfg))
    agent.reset("chair")
    agent._target = target
    p = SimpleNamespace(state=SimpleNamespace(pose=(0.0, 0.0, 0.0)))
    plan = Plan("move_forward", False, 0.1, (0.3, 0.0))
    out = []
    for step in range(60):
        agent.step_ = step
        out.append(agent._approach(target, plan, p))
        if out[-1] != "move_forward":
            break
    return out, agent


@pytest.mark.parametrize("source, at, near_stall, last, stopped", [
    ("live", 0.9, 10, 11, True),  # within 1 m of what it saw: stops after 10 steps
    ("episode", 0.9, 0, 41, True),  # off: after stall_steps, as before
    ("live", 1.2, 10, 41, False),  # farther: given up after stall_steps
    ("memory", 0.5, 10, 41, False),  # a remembered goal is never stopped at unseen
])
def test_stalled_near_a_goal_it_saw_the_agent_stops_sooner(source, at, near_stall, last,
                                                          stopped):
    from kgnav.agent.loop import Target

    target = Target(source, (at, 0.0), "o1")
    actions, agent = _stalled_approach(target, near_stall_steps=near_stall)
    assert len(actions) == last + 1 and set(actions[:-1]) == {"move_forward"}
    if stopped:
        assert actions[-1] == "stop"
        assert agent.log_.stop_reason == f"stalled near {source} goal"
    else:
        assert actions[-1] is None and agent._target is None  # given up
        assert agent.log_.rejected == ["o1"]


def test_a_goal_seen_close_but_never_confidently_is_given_up_on_arrival(env):
    """``confirm_score``: a close view confirms a goal only when the segmenter scored it that
    high. One seen close only at lower scores gets the confirming turns and is then given
    up, however much evidence it has (a persistent mistake has plenty); a higher-scoring
    close view on the way confirms it. Off (0), any close view confirms, as before."""
    from types import SimpleNamespace

    from kgnav.agent.loop import Target

    def det(score, distance=1.5, cls="chair"):
        return SimpleNamespace(cls=cls, distance=distance, position=(2.0, 0.0, 0.4),
                               radius=0.3, score=score)

    def percept(*dets):
        return SimpleNamespace(state=SimpleNamespace(pose=(0.5, 0.0, 0.0), detections=dets))

    agent = _agent(env)  # off: any close view confirms
    agent.reset("chair")
    t = Target("episode", (2.0, 0.0), "o1")
    agent._note_close(t, percept(det(0.62)))
    assert t.seen_close and t.close_score == 0.62

    agent = _agent(env, confirm_score=0.7)
    agent.reset("chair")
    t = agent._set_target(Target("episode", (2.0, 0.0), "o1"))
    agent._note_close(t, percept(det(0.62), det(0.95, cls="sofa"), det(0.9, distance=3.0)))
    assert not t.seen_close and t.close_score == 0.62  # another class, or too far: no count
    actions = []
    for step in range(20):
        agent.step_ = step
        actions.append(agent._confirm(t, percept()))
        if actions[-1] is None:
            break
    assert len(actions) == agent.config.confirm_steps + 1 and actions[-1] is None
    assert agent.log_.unconfirmed == [(8, "o1", 0.62)] and agent.log_.rejected == ["o1"]

    t = Target("live", (2.0, 0.0), "o2")
    agent._note_close(t, percept(det(0.65)))
    agent._note_close(t, percept(det(0.81)))
    assert t.seen_close and t.close_score == 0.81

    t = agent._set_target(Target("memory", (2.0, 0.0), "o3", stage="point"))
    for step in range(20):  # never seen close: the evidence decides, as before (here: none)
        agent.step_ = 100 + step
        if agent._confirm(t, percept()) is None:
            break
    assert agent.log_.rejected[-1] == "o3" and len(agent.log_.unconfirmed) == 1
    with pytest.raises(ValueError, match="confirm_score"):
        AgentConfig(confirm_score=1.5)
