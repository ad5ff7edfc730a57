"""The learned exploration policy: the map-level environment (sensing, motion, reward), the
network input, reproducible and resumable PPO training, weight files, the registered policies,
``kgnav eval --policy`` and the train-policy / policy-bench commands."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from kgnav.agent.camera import Camera
from kgnav.agent.mapping import MapBuilder
from kgnav.agent.planner import FMMPlanner
from kgnav.agent.policy import POLICIES, make_policy, policy_names
from kgnav.benchmark.variants import VARIANTS, with_policy
from kgnav.cli import main
from kgnav.errors import KgnavError
from kgnav.nets.explore.mapenv import Feedback, MapExploreEnv
from kgnav.nets.explore.net import ExploreArch, ExploreNet, Observer
from kgnav.nets.explore.policy import LearnedPolicy, reachable_cell
from kgnav.nets.explore.train import PPOConfig, PPOTrainer
from kgnav.nets.explore.weights import DEFAULT_WEIGHTS, PolicyWeightsError, load_weights
from kgnav.nets.weights import META_KEY
from kgnav.sim.house import Room, Scene, Texture, Wall, generate_house

# training tests check mechanics, not quality: a tiny network, short episodes
TINY = dict(episodes_per_iter=1, max_steps=40, n_houses=2, episode_pool=2, minibatch=2, epochs=1,
            local_cells=120, wide_cells=240, input_size=(24, 24), channels=(4, 4, 4, 4, 4),
            hidden=8, warmup=1)
HFOV = math.radians(79.0)


def box_scene(side: float = 6.0) -> Scene:
    """One empty square room with 0.1 m walls: visibility is plain geometry."""
    grey = (128, 128, 128)
    room = Room(0, "living_room", 0.0, 0.0, side, side, grey, grey, Texture(), Texture())
    t = 0.05
    walls = (Wall(0.0, 0.0, side, t), Wall(0.0, side - t, side, side),
             Wall(0.0, 0.0, t, side), Wall(side - t, 0.0, side, side))
    return Scene("box", 0, side, side, (room,), (), walls, ())


def fan_cells(env: MapExploreEnv, pose_world, wall: float) -> set[tuple[int, int]]:
    """Cells of the agent's map whose centre the camera at ``pose_world`` sees in the box:
    inside the HFOV, nearer than the wall's inner face (x, y in (wall, side - wall))."""
    m = env.map_
    rows, cols = np.indices(m.shape)
    ex, ey = (cols - m.origin[1] + 0.5) * m.resolution, (rows - m.origin[0] + 0.5) * m.resolution
    sx, sy, st = env.start
    wx = sx + math.cos(st) * ex - math.sin(st) * ey
    wy = sy + math.sin(st) * ex + math.cos(st) * ey
    x, y, th = pose_world
    ang = np.arctan2(wy - y, wx - x) - th
    ang = np.arctan2(np.sin(ang), np.cos(ang))
    side = env.scene.width
    inside = (wx > wall) & (wx < side - wall) & (wy > wall) & (wy < side - wall)
    seen = inside & (np.abs(ang) < HFOV / 2 - 0.02) & (np.hypot(wx - x, wy - y) < 4.9)
    return set(zip(*np.nonzero(seen), strict=True))


# ---------------------------------------------------------------------- the environment
def test_reward_is_the_explored_area_gain_on_a_constructed_map():
    env = MapExploreEnv([box_scene()])
    m = env.reset(0, (3.0, 3.0, 0.0))
    first = {tuple(c) for c in np.argwhere(m.explored > 0)}
    # the first view: the fan up to the wall 2.95 m ahead, as geometry says (up to its rim)
    ref = fan_cells(env, (3.0, 3.0, 0.0), 0.05)
    assert len(ref - first) <= 0.02 * len(ref)
    assert abs(len(first) * 0.0025 - 2.95 ** 2 * math.tan(HFOV / 2)) < 0.6
    # heading for the agent's own cell: nowhere to go, so it turns left 30 degrees
    fb = env.step(m.to_cell(0.0, 0.0))
    assert fb.steps == 1 and env.world_pose[2] == pytest.approx(math.radians(30))
    after = {tuple(c) for c in np.argwhere(m.explored > 0)}
    assert fb.gain_m2 == pytest.approx(len(after - first) * 0.0025)
    new_ref = fan_cells(env, env.world_pose, 0.05) - ref
    assert abs(len(after - first) - len(new_ref)) <= 0.1 * len(new_ref)
    # the reward the trainer gives is this gain, scaled
    cfg = PPOConfig()
    assert cfg.reward(fb) == pytest.approx(cfg.area_reward * len(after - first) * 0.0025)

    # cells already explored earn nothing: pre-explore a stripe the second view would add
    env2 = MapExploreEnv([box_scene()])
    m2 = env2.reset(0, (3.0, 3.0, 0.0))
    stripe = np.zeros_like(m2.explored)
    i0, j0 = m2.to_cell(1.0, 1.0)  # episode frame: 45 degrees left, 1.4 m away
    stripe[i0:i0 + 10, j0:j0 + 20] = 1
    overlap = int((stripe.astype(bool) & (m.explored > 0) & (m2.explored == 0)).sum())
    assert overlap > 50
    m2.explored |= stripe
    fb2 = env2.step(m2.to_cell(0.0, 0.0))
    assert fb2.gain_m2 == pytest.approx(fb.gain_m2 - overlap * 0.0025)


def test_motion_follows_the_path_and_the_map_stays_navigable():
    scene = generate_house(1003)
    env = MapExploreEnv([scene], max_steps=120)
    nav_start = tuple(env._house(0)[1].navigable_cells()[500])
    x, y = env._house(0)[1].to_world(*nav_start)
    m = env.reset(0, (x, y, 0.3))
    first = env.explored_m2
    gained = 0.0
    while not env.done:
        fb = env.step(m.to_cell(4.0, -3.0))
        assert 1 <= fb.steps <= env.interval and fb.gain_m2 >= 0
        assert env.nav.is_navigable(*env.world_pose[:2])  # never through walls
        gained += fb.gain_m2
    assert env.steps == 120
    assert gained > 0 and gained == pytest.approx(env.explored_m2 - first)


def test_rays_read_like_the_depth_camera():
    env = MapExploreEnv([box_scene()])
    env.reset(0, (3.0, 3.0, 0.0))
    depth, cls = env.rays([(3.0, 3.0, 0.0), (5.7, 3.0, 0.0), (1.0, 3.0, math.pi)])
    # facing the wall 2.95 m away: z-depth is constant along a wall facing the camera
    assert np.allclose(depth[0], 2.95, atol=0.06)
    assert (depth[1] == np.float32(0.5)).all()  # closer than the minimum reads the minimum
    assert np.allclose(depth[2], 0.95, atol=0.06)
    assert (cls == 0).all()  # walls are not objects


def test_semantic_rays_label_the_goal_channel():
    scene = generate_house(1003)
    env = MapExploreEnv([scene], semantic=True, max_steps=200)
    goal = scene.objects[0]
    nav = env._house(0)[1]
    i, j = nav.snap(*goal.center, max_radius=3.0)
    x, y = nav.to_world(i, j)
    m = env.reset(0, (x, y, 0.0))  # no goal: the episode would end at once, beside it
    for _ in range(12):  # look all round
        env.step(m.to_cell(*env.pose[:2]))
    k = m.classes.index(goal.cls)
    assert m.semantic[k].any()
    arch = ExploreArch(semantic=True)
    obs = Observer(arch)(m, env.pose, goal.cls)
    assert obs.shape == (10, 60, 60) and obs[4].any()


def test_observer_channels():
    arch = ExploreArch()
    mb = MapBuilder(Camera(), size=240)
    m = mb.reset()
    m.obstacle[120, 150] = 1
    m.explored[100:140, 100:140] = 1
    obs_fn = Observer(arch)
    o = obs_fn(m, (0.0, 0.0, 0.0), None)
    assert o.shape == (8, 60, 60) and o.dtype == np.float32
    # local window: 4 cells per pixel, centred on the agent (cell 120, 120 -> pixel 30, 30)
    assert o[0, 30, 37] == 1 and o[0].sum() == 1
    assert o[1, 25:35, 25:35].min() == 1 and o[1].max() == 1 and o[1, 0, 0] == 0
    assert o[2, 29:31, 29:31].all()
    o = obs_fn(m, (1.0, 0.0, 0.0), None)  # the trajectory: 1 m (5 px) back to the first pose
    assert o[3, 30, 25:31].all() and o[3].sum() == 6
    # off the map reads unknown
    assert o[5, 0, 0] == 0


# ---------------------------------------------------------------------- training
@pytest.fixture(scope="module")
def small_houses():
    return [generate_house(1000), generate_house(1001)]


def _train(houses, steps, **kw):
    cfg = PPOConfig(seed=3, steps=steps, **{**TINY, **kw})
    return PPOTrainer(cfg, scenes=houses).fit()


def test_same_seed_same_weights_and_resume(small_houses, tmp_path):
    a = _train(small_houses, 2)
    b = _train(small_houses, 2)
    for k, v in a.net.state_dict().items():
        assert torch.equal(v, b.net.state_dict()[k]), k
    assert a.curve == b.curve and len(a.curve) == 2
    c = PPOTrainer(PPOConfig(seed=4, steps=2, **TINY), scenes=small_houses).fit()
    assert any(not torch.equal(v, c.net.state_dict()[k]) for k, v in a.net.state_dict().items())
    # stop after one iteration, resume from the checkpoint: the same weights
    ckpt = tmp_path / "p.ckpt"
    first = PPOTrainer(PPOConfig(seed=3, steps=2, **TINY), scenes=small_houses)
    first.train_step()
    first.save_checkpoint(ckpt)
    resumed = PPOTrainer(PPOConfig(seed=3, steps=2, **TINY), scenes=small_houses)
    resumed.load_checkpoint(ckpt).fit()
    for k, v in a.net.state_dict().items():
        assert torch.equal(v, resumed.net.state_dict()[k]), k
    assert resumed.curve == a.curve
    # another run's checkpoint is refused, naming the difference
    other = PPOTrainer(PPOConfig(seed=9, steps=2, **TINY), scenes=small_houses)
    with pytest.raises(PolicyWeightsError, match="seed=3"):
        other.load_checkpoint(ckpt)


def test_export_load_and_policy_on_a_map(small_houses, tmp_path):
    t = _train(small_houses, 1)
    path = t.export().save(tmp_path / "w.npz")
    w = load_weights(path, semantic=False)
    assert w.meta["policy"] == "ppo" and w.meta["curve"] == t.curve
    with pytest.raises(PolicyWeightsError, match="not ppo-semantic"):
        load_weights(path, semantic=True)
    pol = LearnedPolicy("ppo", path, device="cpu")
    env = MapExploreEnv(small_houses, max_steps=60)
    nav = env._house(0)[1]
    x, y = nav.to_world(*nav.navigable_cells()[100])
    m = env.reset(0, (x, y, 0.0))
    pol.reset(5)
    cells = []
    planner = FMMPlanner()
    while not env.done:
        cell = pol.select(m, env.pose, None, planner)
        assert m.inside(*cell)
        cells.append(cell)
        env.step(cell)
    pol.reset(5)  # the same seed, the same first goal
    env.reset(0, (x, y, 0.0))
    assert pol.select(env.map_, env.pose, None, planner) == cells[0]


def test_reachable_cell_moves_a_goal_out_of_a_wall():
    m = MapBuilder(Camera(), size=120).reset()
    m.obstacle[:, 80:84] = 1  # a wall across the map, 1 m to the right
    m.explored[:, 40:84] = 1
    cell = reachable_cell(m, (60, 60), (60, 82), FMMPlanner())
    assert cell[1] < 80 - 3 and abs(cell[0] - 60) <= 1


def test_semantic_policy_starts_as_the_ppo_policy(small_houses, tmp_path):
    from kgnav.nets.explore.train import warm_start

    t = _train(small_houses, 1)
    w = t.export()
    sem = warm_start(ExploreNet(PPOConfig(**{**TINY, "semantic": True}).arch), w)
    x = torch.rand(2, 8, 24, 24)
    goal = torch.rand(2, 1, 24, 24)
    xs = torch.cat([x[:, :4], goal, x[:, 4:], goal], dim=1)
    assert torch.allclose(sem(xs)[0], t.net(x)[0], atol=1e-5)
    with pytest.raises(PolicyWeightsError, match="another architecture"):
        warm_start(ExploreNet(ExploreArch(semantic=True)), w)


@pytest.mark.parametrize("damage", ["truncate", "foreign", "arch", "nan"])
def test_bad_weight_files_give_one_line_errors(small_houses, tmp_path, damage):
    t = _train(small_houses, 1)
    path = t.export().save(tmp_path / "w.npz")
    if damage == "truncate":
        path.write_bytes(path.read_bytes()[:200])
    else:
        with np.load(path) as z:
            arrays = {k: z[k] for k in z.files}
        meta = json.loads(bytes(arrays[META_KEY]).decode())
        if damage == "foreign":
            meta["format"] = "kgnav-encoder-weights"
        elif damage == "arch":
            meta["arch"]["channels"] = [10 ** 6] * 5
        else:
            k = next(k for k in arrays if k != META_KEY)
            arrays[k] = np.full_like(arrays[k], np.nan)
        arrays[META_KEY] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
        np.savez(path, **arrays)
    with pytest.raises(PolicyWeightsError) as exc:
        LearnedPolicy("ppo", path)
    assert "\n" not in str(exc.value) and str(path) in str(exc.value)


# ---------------------------------------------------------------------- registry and eval
def test_registry_and_variant_policies():
    assert {"frontier", "semantic", "ppo", "ppo-semantic", "random-goal"} <= set(policy_names())
    assert "ppo" in POLICIES
    with pytest.raises(KgnavError, match="unknown global policy"):
        make_policy("nope")
    assert with_policy(VARIANTS["ans"], "ppo").policy == "ppo"
    assert with_policy(VARIANTS["sem+si"], "ppo-semantic").policy == "ppo-semantic"
    assert with_policy(VARIANTS["hp"], "ppo").policy == "frontier"
    assert with_policy(VARIANTS["si"], None) is VARIANTS["si"]


def test_shipped_weights_load_offline():
    w = load_weights()
    assert w.meta["train"]["split"] == "train" and w.meta["train"]["complete"]
    assert DEFAULT_WEIGHTS["ppo"].stat().st_size < 2_000_000
    assert ExploreNet(w.arch) is not None


def test_unshipped_semantic_weights_say_how_to_train_them(monkeypatch, tmp_path):
    monkeypatch.setitem(DEFAULT_WEIGHTS, "ppo-semantic", tmp_path / "explore-semantic.npz")
    with pytest.raises(PolicyWeightsError, match="train-policy --policy ppo-semantic"):
        load_weights(semantic=True)


def test_eval_runs_with_the_learned_policy(tmp_path):
    from kgnav.benchmark.runner import EvalConfig, _env, _make_agent, run_eval

    cfg = EvalConfig(split="val", variants=("ans",), scenes=1, episodes=1, max_steps=30,
                     segmenter="clean", extractor="opencv-gist", policy="ppo")
    agent = _make_agent(cfg, with_policy(VARIANTS["ans"], cfg.policy), _env(cfg, 0), None,
                        "opencv-gist")
    assert agent.policy.name == "ppo"
    records, summary = run_eval(cfg, tmp_path, progress=False)
    assert len(records) == 1 and records[0]["steps"] <= 30
    assert json.loads((tmp_path / "config.json").read_text())["policy"] == "ppo"


# ---------------------------------------------------------------------- commands
def test_cli_usage_errors(capsys, tmp_path):
    with pytest.raises(SystemExit) as e:
        main(["eval", "--policy", "nope", "--out", str(tmp_path)])
    assert e.value.code == 2
    assert "unknown policy 'nope'" in capsys.readouterr().err
    with pytest.raises(SystemExit) as e:
        main(["train-policy", "--out", str(tmp_path / "w.npz"), "--resume"])
    assert e.value.code == 2
    with pytest.raises(SystemExit) as e:
        main(["policy-bench", "--out", str(tmp_path), "--policies", "frontier,nope"])
    assert e.value.code == 2


def test_train_policy_command(tmp_path, capsys, monkeypatch):
    from kgnav.nets.explore import train as train_mod

    small = dict(TINY, steps=1)
    small.pop("n_houses")
    orig = train_mod.PPOConfig.for_policy.__func__

    def tiny(cls, name, **kw):
        return orig(cls, name, **{**kw, **small, "n_houses": 1})

    monkeypatch.setattr(train_mod.PPOConfig, "for_policy", classmethod(tiny))
    out = tmp_path / "w.npz"
    with pytest.raises(SystemExit) as e:
        main(["train-policy", "--out", str(out), "--steps", "1", "--device", "cpu", "--quiet"])
    assert e.value.code == 0
    assert load_weights(out).meta["train"]["complete"]
    assert (tmp_path / "w.png").stat().st_size > 1000
    assert "done at step 1/1" in capsys.readouterr().out


def test_feedback_progress():
    fb = Feedback(3, 1.0, 5.0, 3.5, False, False)
    assert fb.progress_m == 1.5
    assert Feedback(3, 1.0, math.inf, math.inf, False, False).progress_m == 0.0
