"""The benchmark's world at Matterport3D scale: large houses, far goals, a map that covers the
house, an oracle that never wedges itself, splits of your own, paired intervals."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from kgnav.agent.camera import Camera
from kgnav.agent.features import make_extractor
from kgnav.agent.loop import ObjectNavAgent
from kgnav.agent.oracle import OracleAgent
from kgnav.agent.segmentation import make_segmenter
from kgnav.benchmark.stats import paired_bootstrap, paired_differences
from kgnav.common.classes import OBJECTNAV_CLASSES
from kgnav.sim import Episode, ObjectInstance, ObjectNavEnv, Room, Scene, Texture, Wall
from kgnav.sim.episodes import SPLIT_GENERATOR, SPLITS, episodes_for, generate_episodes
from kgnav.sim.house_v2 import GOAL_ROOM_BUDGET, generate_large_house
from kgnav.sim.navmesh import NavMap
from kgnav.sim.scene_dir import SceneDir, generate_split, validate_split


def box_scene(name: str, width: float, depth: float, extra_walls=(), objects=()) -> Scene:
    """One room ``width`` x ``depth`` m, walled, with extra wall boxes and objects."""
    h = 0.05
    walls = (Wall(-h, -h, width + h, h), Wall(-h, depth - h, width + h, depth + h),
             Wall(-h, -h, h, depth + h), Wall(width - h, -h, width + h, depth + h),
             *extra_walls)
    room = Room(0, "hallway", 0.0, 0.0, width, depth, (200, 200, 200), (100, 80, 60),
                Texture(), Texture(3, 0.2, 0.1))
    return Scene(name, 0, width, depth, (room,), (), walls, tuple(objects))


# --------------------------------------------------------------------------- houses
@pytest.mark.parametrize("seed", [3, 4001, 77])
def test_large_houses_have_corridors_sparse_goals_and_stay_connected(seed):
    s = generate_large_house(seed)
    assert s.generator == "house-v2" and 8 <= len(s.rooms) <= 30
    assert s.width <= 40.0 and s.depth <= 40.0
    assert any(r.kind == "hallway" for r in s.rooms)
    for cls, (_lo, hi) in GOAL_ROOM_BUDGET.items():
        rooms = {o.room for o in s.objects if o.cls == cls}
        assert 1 <= len(rooms) <= hi + 1, (cls, rooms)  # +1: the guarantee pass
    nav = NavMap.from_scene(s)
    assert len(np.unique(s.room_id_grid()[nav.grid])) == len(s.rooms)
    assert generate_large_house(seed) == s


def test_large_house_room_count_and_size_are_respected():
    s = generate_large_house(5, n_rooms=30, max_side=30.0)
    assert len(s.rooms) == 30 and max(s.width, s.depth) <= 30.0
    with pytest.raises(ValueError, match="n_rooms"):
        generate_large_house(5, n_rooms=31)


def test_splits_small_and_large():
    assert len(SPLITS["val"]) == 11 and len(SPLITS["train"]) == 20
    assert SPLIT_GENERATOR["val"] == "house-v2" and SPLIT_GENERATOR["val-small"] == "house-v1"
    # no house is in two splits
    seeds = [s for v in SPLITS.values() for s in v]
    assert len(seeds) == len(set(seeds))


def test_episodes_have_a_matterport_like_spread_of_distances():
    d = np.array([e.geodesic_distance for k in range(4) for e in episodes_for("val", k, 40)])
    assert d.mean() >= 7.0 and d.min() >= 1.0 and d.max() <= 30.0
    assert d.max() > 12.0 and np.mean(d < 4.0) > 0.05  # a spread, not one distance
    # the first k episodes do not depend on how many are asked for
    assert episodes_for("val", 0, 5) == episodes_for("val", 0, 40)[:5]


def test_small_split_episodes_are_unchanged():
    """val-small is the first generator's val split: same houses, same uniform episodes."""
    eps = episodes_for("val-small", 0, 20)
    assert np.mean([e.geodesic_distance for e in eps]) < 7.0
    assert eps[0].scene == "val-small_00"


# --------------------------------------------------------------------------- the agent's map
def test_a_goal_twenty_metres_away_is_reached_on_the_agents_map():
    """The 480-cell map covers 12 m each side of the start; the agent walks a 24 m corridor to
    a bed 21 m away: the map grows and the goal is found and reached."""
    bed = ObjectInstance(1, "bed", 0, 22.3, 0.2, 23.9, 1.8, 0.0, 0.6, (40, 40, 200))
    scene = box_scene("long", 24.0, 2.0, objects=(bed,))
    ep = Episode("l0", "long", (1.0, 1.0, 0.0), "bed", 21.0, 21.3)
    env = ObjectNavEnv(scene=scene, episodes=[ep])
    agent = ObjectNavAgent(Camera.from_env(env), make_segmenter("clean"),
                           make_extractor("opencv-gist"))
    obs, info = env.reset(seed=0)
    agent.reset("bed", seed=0)
    while True:
        obs, _r, term, trunc, info = env.step(agent.act(obs))
        if term or trunc:
            break
    assert info["success"], info["steps"]
    m = agent.map_
    assert m.generation >= 1 and m.shape[1] > 480
    i, j = m.to_cell(22.0, 0.0)  # the bed, in the episode frame
    assert m.inside(i, j) and m.explored[i, j]


def test_planner_heads_for_a_point_beyond_the_map():
    """A remembered goal rooms away is put on the map (it grows) and planned toward."""
    from kgnav.agent.loop import Target

    env = ObjectNavEnv("val-small", 0)
    agent = ObjectNavAgent(Camera.from_env(env), make_segmenter("clean"),
                           make_extractor("opencv-gist"))
    env.reset(seed=0)
    agent.reset("chair", seed=0)
    mask = agent._goal_mask(Target("episode", (30.0, 0.0)))
    m = agent.map_
    assert mask.any() and mask.shape == m.shape
    i, j = m.to_cell(30.0, 0.0)
    assert mask[i, j]
    plan = agent.planner.plan(m, (0.0, 0.0, 0.0), mask, key="far")
    assert math.isfinite(plan.distance) and plan.distance == pytest.approx(30.0, abs=1.5)


# --------------------------------------------------------------------------- the oracle
PARTITION = Wall(1.25, 0.9, 1.35, 3.1)


@pytest.mark.parametrize("y,theta", [(1.0, 0.0), (3.05, 0.0), (1.0, 0.6), (3.05, 1.0),
                                     (3.05, -0.3), (2.0, 0.0)])
def test_oracle_recovers_from_a_start_against_a_wall(y, theta):
    """Starting with a partition wall just ahead (the greedy descent used to push into its
    end until step 500), the oracle goes round it and succeeds."""
    chair = ObjectInstance(1, "chair", 0, 5.0, 1.75, 5.5, 2.25, 0.0, 0.9, (200, 30, 30))
    scene = box_scene("wall", 6.0, 4.0, extra_walls=(PARTITION,), objects=(chair,))
    env = ObjectNavEnv(scene=scene, episodes=[Episode("w", "wall", (1.05, y, theta), "chair",
                                                      0.0, 0.0)])
    oracle = OracleAgent(env)
    obs, info = env.reset(seed=0)
    oracle.reset("chair")
    bumps = 0
    while True:
        obs, _r, term, trunc, info = env.step(oracle.act(obs))
        bumps += info["collided"]
        if term or trunc:
            break
    assert info["success"] and info["steps"] < 60 and bumps <= 2


def test_oracle_succeeds_on_every_episode_of_a_large_house():
    scene = generate_large_house(4003)
    eps = generate_episodes(scene, 12, seed=5)
    env = ObjectNavEnv(scene=scene, episodes=eps)
    oracle = OracleAgent(env)
    for k in range(len(eps)):
        obs, info = env.reset(seed=k, options={"episode": k})
        oracle.reset(env.goal_class)
        while True:
            obs, _r, term, trunc, info = env.step(oracle.act(obs))
            if term or trunc:
                break
        assert info["success"], (k, info["steps"])


# --------------------------------------------------------------------------- splits of your own
def test_generate_validate_and_detect_a_broken_split(tmp_path, cli):
    d = tmp_path / "split"
    code, out, err = cli("scenes", "generate", "-o", d, "--count", "2", "--rooms", "8..9",
                         "--episodes", "3", "--seed", "9100")
    assert code == 0, err
    sd = SceneDir(d)
    assert sd.names == ["h9100", "h9101"] and len(sd.episodes(1)) == 3
    assert {sd.scene(k).generator for k in range(2)} == {"house-v2"}
    code, out, err = cli("scenes", "validate", d)
    assert code == 0 and "no problems" in out
    # an episode moved into a wall, another with a wrong recorded distance
    p = sd.episodes_path(0)
    data = json.loads(p.read_text())
    data["episodes"][0]["start"] = [-5.0, -5.0, 0.0]
    data["episodes"][1]["geodesic_distance"] += 3.0
    p.write_text(json.dumps(data))
    problems = validate_split(d)
    assert len(problems) == 2
    assert "off the navigable floor" in problems[0] and "recorded" in problems[1]
    code, out, err = cli("scenes", "validate", d)
    assert code == 1 and "2 problem(s)" in err
    code, out, err = cli("scenes", "generate", "-o", tmp_path / "x", "--rooms", "2..40")
    assert code == 2 and "rooms" in err


def test_eval_runs_a_directory_of_scenes(tmp_path, cli):
    d = tmp_path / "split"
    generate_split(d, count=1, seed=9200, rooms=(8, 8), episodes=2)
    code, out, err = cli("eval", "--scenes-dir", d, "--variants", "oracle", "--out",
                         tmp_path / "run", "--quiet")
    assert code == 0, err
    recs = [json.loads(x) for x in (tmp_path / "run" / "episodes.jsonl").read_text().split("\n")
            if x]
    assert [r["scene"] for r in recs] == ["h9200", "h9200"] and all(r["success"] for r in recs)
    code, out, err = cli("eval", "--scenes-dir", tmp_path / "nothing", "--variants", "oracle",
                         "--out", tmp_path / "run2", "--quiet")
    assert code == 1 and "not a directory" in err


def test_eval_noise_option(tmp_path, cli):
    code, out, err = cli("eval", "--split", "val-small", "--variants", "oracle", "--scenes", "1",
                         "--episodes", "2", "--noise", "actuation=1,odometry=0.01",
                         "--out", tmp_path / "n", "--quiet")
    assert code == 0, err
    cfg = json.loads((tmp_path / "n" / "config.json").read_text())
    assert cfg["noise"] == "actuation=1,odometry=0.01"
    assert cfg["noise_model"]["name"] == "custom"
    assert cfg["noise_model"]["actuation"]["forward_sigma"] == 0.025
    assert cfg["noise_model"]["odometry"]["sigma_xy"] == 0.01
    code, out, err = cli("eval", "--noise", "wobble=3", "--out", tmp_path / "m")
    assert code == 2 and "actuation=K" in err


def test_eval_relocation_option(tmp_path, cli):
    """--relocation KEY=VALUE changes the preset's RelocationConfig (recorded in config.json);
    a setting it does not have, a value of the wrong kind or one it refuses is a one-line
    usage error."""
    code, out, err = cli("eval", "--split", "val-small", "--variants", "oracle", "--scenes", "1",
                         "--episodes", "1", "--relocation", "bare_inliers=0.5",
                         "--relocation", "unique=off", "--relocation", "max_correction=2,30",
                         "--goals", "min_score=0.7", "--out", tmp_path / "r", "--quiet")
    assert code == 0, err
    rel = json.loads((tmp_path / "r" / "config.json").read_text())["agent"]["relocation"]
    assert rel["bare_inliers"] == 0.5 and rel["unique"] is False
    assert rel["max_correction"] == [2.0, 30.0] and rel["absence_views"] == 3
    assert json.loads((tmp_path / "r" / "config.json").read_text())["agent"]["goals"][
        "min_score"] == 0.7
    code, out, err = cli("eval", "--goals", "min_scor=1", "--out", tmp_path / "m")
    assert code == 2 and "unknown goal setting 'min_scor'" in err
    _one_line_usage_errors(cli, tmp_path, "--relocation", (
        ("frobs=1", "unknown relocation setting 'frobs'"),
        ("bare_inliers=high", "bare_inliers takes a value like 0.9"),
        ("max_correction=1", "max_correction takes a value like (1.0, 20.0)"),
        ("unique=maybe", "unique takes a value like True"),
        ("absent_if=nothing", "absent_if must be one of ('empty', 'class')"),
        ("top_k", "expected KEY=VALUE")))


def _one_line_usage_errors(cli, tmp_path, option: str, cases) -> None:
    """Each ``(value, needle)`` of ``cases`` given to ``kgnav eval OPTION value`` is a usage
    error (exit 2) of one line that says ``needle``."""
    for arg, needle in cases:
        code, out, err = cli("eval", option, arg, "--out", tmp_path / "m")
        assert code == 2 and needle in err and len(err.strip().splitlines()) == 1, err


def test_eval_agent_option(tmp_path, cli):
    """--agent KEY=VALUE changes the preset's AgentConfig (recorded in config.json); an
    optional number takes 'none'; an unknown setting, a value of the wrong kind or one
    AgentConfig refuses is a one-line usage error."""
    code, out, err = cli("eval", "--split", "val-small", "--variants", "oracle", "--scenes", "1",
                         "--episodes", "1", "--agent", "prior_inflation=0.1",
                         "--agent", "weak_score=none", "--agent", "detour_ratio=3",
                         "--out", tmp_path / "r", "--quiet")
    assert code == 0, err
    agent = json.loads((tmp_path / "r" / "config.json").read_text())["agent"]
    assert agent["prior_inflation"] == 0.1 and agent["weak_score"] is None
    assert agent["detour_ratio"] == 3.0
    _one_line_usage_errors(cli, tmp_path, "--agent", (
        ("prior_inflashun=1", "unknown agent setting 'prior_inflashun'"),
        ("prior_inflation=wide", "prior_inflation takes a value like a number"),
        ("prior_inflation=-1", "prior_inflation must be None or a finite length"),
        ("prior_inflation=inf", "prior_inflation must be None or a finite length"),
        ("detour_ratio=0.5", "detour_ratio must be 0 (off) or at least 1")))


def test_eval_goals_per_class_floor(tmp_path, cli):
    """--goals remembered_floor=CLASS:FLOOR,... is parsed into pairs and recorded; a malformed
    pair, a floor out of range, or a class the environment does not have is one line."""
    code, out, err = cli("eval", "--split", "val-small", "--variants", "oracle", "--scenes", "1",
                         "--episodes", "1", "--goals", "remembered_floor=sofa:0.78,bed:0.85",
                         "--out", tmp_path / "r", "--quiet")
    assert code == 0, err
    goals = json.loads((tmp_path / "r" / "config.json").read_text())["agent"]["goals"]
    assert goals["remembered_floor"] == [["sofa", 0.78], ["bed", 0.85]]
    _one_line_usage_errors(cli, tmp_path, "--goals", (
        ("remembered_floor=sofa=0.7", "NAME:NUMBER"),
        ("remembered_floor=sofa:high", "NAME:NUMBER"),
        ("remembered_floor=sofa:1.5", "remembered_floor must give")))
    code, out, err = cli("eval", "--split", "val-small", "--variants", "oracle", "--scenes", "1",
                         "--episodes", "1", "--goals", "remembered_floor=unicorn:0.5",
                         "--out", tmp_path / "u", "--quiet")
    assert code == 1 and "unknown object class 'unicorn'" in err
    assert len(err.strip().splitlines()) == 1


# --------------------------------------------------------------------------- paired intervals
def test_paired_bootstrap_is_seeded_and_centred():
    rng = np.random.default_rng(1)
    d = rng.normal(0.05, 0.3, 500)
    lo, hi = paired_bootstrap(d, seed=3)
    assert (lo, hi) == paired_bootstrap(d, seed=3)
    assert lo < d.mean() < hi and hi - lo == pytest.approx(2 * 1.96 * d.std() / math.sqrt(500),
                                                           rel=0.15)


def test_paired_differences_match_episodes_not_positions():
    recs = [{"variant": "ans", "scene": "a", "episode": 0, "success": 0, "spl": 0.0},
            {"variant": "ans", "scene": "a", "episode": 1, "success": 1, "spl": 0.5},
            {"variant": "si", "scene": "a", "episode": 1, "success": 1, "spl": 0.7},
            {"variant": "si", "scene": "a", "episode": 0, "success": 1, "spl": 0.4},
            {"variant": "si", "scene": "b", "episode": 0, "success": 1, "spl": 0.4}]
    d = paired_differences(recs, "ans")["si"]
    assert d["success"]["pairs"] == 2 and d["success"]["diff"] == 0.5
    assert d["spl"]["diff"] == pytest.approx(0.3)
    assert paired_differences(recs, "oracle") == {}


def test_goal_classes_are_the_objectnav_ones():
    assert set(GOAL_ROOM_BUDGET) == set(OBJECTNAV_CLASSES)
