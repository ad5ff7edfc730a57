"""Where success is lost (issue 28, item 4): whether the house's memory held the goal as an
episode started (ground truth, scoring only), the learning curve, the paired comparison of the
goal-not-in-memory episodes with ``ans``, and why a goal-in-memory episode did not head for the
remembered goal (decided by the agent from what it knew)."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from kgnav.agent.camera import Camera
from kgnav.agent.features import make_extractor
from kgnav.agent.loop import (
    MEMORY_GOAL_REASONS,
    AgentConfig,
    MemoryPeriod,
    ObjectNavAgent,
)
from kgnav.agent.memory import Memory
from kgnav.agent.policy import FRONTIER_SOURCES
from kgnav.agent.segmentation import make_segmenter
from kgnav.benchmark import fidelity
from kgnav.benchmark.runner import EvalConfig, _GroundTruth, goal_in_memory, run_eval, summarize
from kgnav.common import se2
from kgnav.memory.evidence import ScanTable
from kgnav.memory.model import AbstractModel, Detection
from kgnav.sim import ObjectNavEnv
from kgnav.sim.scene import ObjectInstance

CHAIR = ObjectInstance(1, "chair", 0, 4.0, 2.0, 4.5, 2.5, 0.0, 0.9, (0, 0, 0))
SOFA = ObjectInstance(2, "sofa", 0, 0.0, 5.0, 2.0, 6.0, 0.0, 0.8, (0, 0, 0))
# the house's episodes start at different places: a model lives in its first episode's frame
STARTS = {0: (0.0, 0.0, 0.0), 1: (4.0, 0.0, np.pi / 2), 2: (1.0, 1.0, 0.0)}


def _model(model_id: str, objects, views: int = 3, episode: int = 0,
           score: float = 1.0) -> AbstractModel:
    """A model whose states (in a row along x) each see ``objects`` ((class, x, y), model
    frame), ``views`` states in all."""
    m = AbstractModel(4, model_id=model_id)
    for k in range(views):
        m.add_state(np.eye(4, dtype=np.float32)[k % 4], (0.1 * k, 0.0, 0.0),
                    [Detection(c, (x, y, 0.4), score=score) for c, x, y in objects],
                    episode=episode, step=k)
    return m


def _in_frame(start, x, y):
    """A world point in the frame of an episode that started at ``start``."""
    return se2.apply_to_point(se2.inverse(start), x, y)


class _House:
    """An environment's ground-truth hooks, nothing else."""

    def __init__(self, objects=(CHAIR, SOFA)):
        self.objects = list(objects)

    def scene_objects(self):
        return self.objects

    def episode_start(self, i):
        return STARTS[i]


def _held(models, goal="chair", env=None) -> bool | None:
    gt = _GroundTruth(env or _House(), "h", 2)
    return goal_in_memory(gt, SimpleNamespace(models={m.model_id: m for m in models}), goal)


# ---------------------------------------------------------------------- the split
def test_a_true_instance_in_any_model_of_the_house_counts_a_phantom_does_not():
    # episode 1 started at (4, 0) facing +y: the chair's world (4.2, 2.2) is (2.2, -0.2) there
    on_chair = _in_frame(STARTS[1], 4.2, 2.2)
    assert on_chair == pytest.approx((2.2, -0.2))
    true = _model("h-e001", [("chair", *on_chair)])
    phantom = _model("h-e000", [("chair", 8.0, 8.0), ("sofa", 1.0, 5.5)])
    wrong_class = _model("h-e002", [("sofa", *_in_frame(STARTS[2], 4.2, 2.2))])
    assert _held([true])
    assert not _held([phantom])  # a chair where there is none
    assert not _held([wrong_class])  # an object on the chair's place, of another class
    assert not _held([_model("h-e000", [("chair", 1.0, 5.5)])])  # a sofa taken for a chair
    assert not _held([])
    assert _held([phantom, wrong_class, true])  # any of the house's models
    # the same coordinates read in the wrong frame (episode 0's) miss the chair
    assert not _held([_model("h-e000", [("chair", *on_chair)])])
    # within the fidelity tolerance of the footprint, and no further
    edge = _in_frame(STARTS[0], 4.5 + fidelity.TOLERANCE - 0.05, 2.2)
    assert _held([_model("h-e000", [("chair", *edge)])])
    assert not _held([_model("h-e000", [("chair", edge[0] + 0.1, edge[1])])])
    assert not _held([true], goal="sofa")  # the goal class decides


def test_another_houses_model_and_missing_ground_truth():
    other = _model("elsewhere-e001", [("chair", *_in_frame(STARTS[1], 4.2, 2.2))])
    assert not _held([other])  # a model of another house never counts for this one
    gt = _GroundTruth(SimpleNamespace(episode_start=STARTS.get), "h", 0)  # no scene_objects
    mem = SimpleNamespace(models={"h-e001": _model("h-e001", [("chair", 2.2, -0.2)])})
    assert goal_in_memory(gt, mem, "chair") is None
    assert goal_in_memory(_GroundTruth(_House(), "h", 0), None, "chair") is None  # no memory


def test_fidelity_scores_keep_their_matching():
    """The split reuses fidelity's matching: the scores it gave before are unchanged."""
    s = fidelity.score_objects([("chair", 4.6, 2.2, 1.0), ("chair", 4.1, 2.4, 0.9),
                                ("chair", 9.0, 9.0, 0.2), ("sofa", 1.0, 5.5, 0.7)],
                               [CHAIR, SOFA])
    assert (s["objects"], s["precision"], s["copies"], s["recall"]) == (4, 0.75, 1.5, 1.0)
    assert fidelity.stands_for_instance("chair", 4.6, 2.2, {"chair": [CHAIR]}) == 1
    assert fidelity.stands_for_instance("sofa", 4.6, 2.2, {"chair": [CHAIR]}) is None


# ---------------------------------------------------------------------- the summary
def _rec(variant, scene, episode, success, held=None, reason=None, step=None, spl=None):
    return {"variant": variant, "scene": scene, "episode": episode, "success": success,
            "spl": (1.0 if success else 0.0) if spl is None else spl, "softspl": 0.0,
            "dts": 0.0, "relocated": False, "failure": None, "goal_in_memory": held,
            "memory_goal_reason": reason, "memory_goal_step": step}


def test_the_learning_curve_indexes_each_houses_episodes_from_its_first():
    # house a: 6 episodes, given out of order; house b starts at episode 5 and runs 3
    a = [True, False, True, True, False, True]
    b = {5: False, 6: False, 7: True}
    recs = [_rec("si", "a", i, a[i]) for i in (3, 0, 5, 1, 4, 2)]
    recs += [_rec("si", "b", e, ok) for e, ok in b.items()]
    s = summarize(recs)["si"]
    assert s["success_by_episode_index"] == [0.5, 0.0, 1.0, 1.0, 0.0, 1.0]
    assert s["success_from_fifth_episode"] == 0.5  # a's episodes 4 and 5
    assert summarize(recs[:4])["si"]["success_from_fifth_episode"] is None


def test_the_split_the_reasons_and_the_pairing_with_ans():
    si = [_rec("si", "h", 0, False, held=False),
          _rec("si", "h", 1, True, held=True, step=12, spl=0.8),
          _rec("si", "h", 2, False, held=True, reason="not_relocated"),
          _rec("si", "h", 3, True, held=True, reason="goal_seen_in_episode", spl=0.4),
          _rec("si", "h", 4, True, held=False, spl=0.5),
          _rec("si", "g", 0, True, held=None)]  # unknown: in neither part
    # ans fails where si's memory held the goal and succeeds on one it did not
    ans = [_rec("ans", "h", e, ok) for e, ok in enumerate([True, False, False, False, False])]
    ans.append(_rec("ans", "g", 0, False))
    s = summarize([*ans, *si], seed=0)
    assert s["si"]["goal_in_memory"] == {"episodes": 3, "success": pytest.approx(2 / 3),
                                         "spl": pytest.approx(0.4)}
    assert s["si"]["goal_not_in_memory"] == {"episodes": 2, "success": 0.5, "spl": 0.25}
    assert s["si"]["memory_goal_headed"] == 1
    reasons = s["si"]["memory_goal_reasons"]
    assert list(reasons) == list(MEMORY_GOAL_REASONS)
    assert reasons["not_relocated"] == 1 and reasons["goal_seen_in_episode"] == 1
    assert sum(reasons.values()) == 2
    # paired over si's goal-not-in-memory episodes only (h 0: -1, h 4: +1)
    d = s["si"]["goal_not_in_memory_vs_ans"]
    assert d["success"]["pairs"] == 2 and d["success"]["diff"] == 0.0
    assert d["success"]["low"] == -1.0 and d["success"]["high"] == 1.0
    assert d["spl"]["diff"] == pytest.approx(-0.25)
    assert s["si"]["vs_ans"]["success"]["pairs"] == 6  # the overall comparison is unchanged
    # a memory-less variant has no split; without ans, no pairing; none known: empty parts
    assert "goal_in_memory" not in s["ans"] and "goal_not_in_memory_vs_ans" not in s["ans"]
    alone = summarize([*si[:1], _rec("si", "h", 9, True, held=True)])["si"]
    assert "goal_not_in_memory_vs_ans" not in alone
    unknown = summarize([_rec("sp", "h", 0, True)])["sp"]
    assert unknown["goal_in_memory"] == {"episodes": 0, "success": None, "spl": None}
    # not yet scored whether the goal was ever in view: empty parts, nothing counted
    assert s["si"]["goal_not_in_memory_seen_before"]["episodes"] == 0
    assert s["si"]["exploration_failures_goal_in_view"] == {"episodes": 0, "in_view": 0}
    none_paired = summarize([*ans, _rec("si", "h", 1, True, held=True, step=3)])["si"]
    assert none_paired["goal_not_in_memory_vs_ans"]["success"] == {
        "diff": None, "low": None, "high": None, "pairs": 0}


def test_the_goal_not_in_memory_split_by_what_the_house_had_in_view():
    def rec(e, ok, held, before, failure=None, in_view="absent"):
        r = {**_rec("si", "h", e, ok, held=held), "goal_seen_before": before,
             "failure": failure}
        if in_view != "absent":
            r["goal_in_view_step"] = in_view
        return r

    recs = [rec(0, False, False, False, "Exploration", None),   # never near, never in view
            rec(1, True, False, True, None, 40),                 # missed before, found now
            rec(2, False, False, True, "Exploration", 17),       # in view, not recognised
            rec(3, False, False, True, "Detection", 5),
            rec(4, True, True, True, None, 3),                   # held: in neither split
            rec(5, False, True, True, "Exploration")]            # in view not scored
    s = summarize(recs)["si"]
    assert s["goal_not_in_memory_seen_before"] == {"episodes": 3, "success": pytest.approx(1 / 3),
                                                   "spl": pytest.approx(1 / 3)}
    assert s["goal_not_in_memory_never_seen"] == {"episodes": 1, "success": 0.0, "spl": 0.0}
    # Exploration failures whose in-view step was scored: 0 and 2; 2 had the goal in view
    assert s["exploration_failures_goal_in_view"] == {"episodes": 2, "in_view": 1}


# ---------------------------------------------------------------------- the reasons
@pytest.fixture(scope="module")
def env():
    return ObjectNavEnv("val-small", 0)


def _agent(env, memory, **cfg) -> ObjectNavAgent:
    return ObjectNavAgent(Camera.from_env(env), make_segmenter("clean", 0),
                          make_extractor("opencv-gist"), memory=memory,
                          config=AgentConfig(**cfg))


def _relocated(agent, model_id, *, perceived=(), seen=(), reasoned=True):
    """What the loop records on a relocation into ``model_id`` (the stored model standing in
    for the merged one), as the agent would have reasoned with it."""
    m = agent.memory.model(model_id)
    agent.log_.periods.append(MemoryPeriod(0, model_id, m, set(seen), ScanTable(m),
                                           reasoned=reasoned, perceived=set(perceived)))
    agent.relocalizer.matched.add(model_id)


def _ids(model, cls="chair"):
    return sorted(o for o in model.objects() if model.graph.nodes[o]["cls"] == cls)


def test_the_reasons_decided_from_what_the_agent_knew(env):
    believed = _model("h-e000", [("chair", 2.0, 1.0), ("sofa", 0.0, 2.0)], views=6)
    once = _model("h-e001", [("chair", 2.0, 1.0), ("sofa", 0.0, 2.0)], views=1)  # seen once
    bare = _model("h-e002", [("sofa", 0.0, 2.0)], views=6)
    agent = _agent(env, Memory({m.model_id: m for m in (believed, once, bare)}))

    def reason(*relocations, matched=()):
        agent.reset("chair")
        for model_id, kw in relocations:
            _relocated(agent, model_id, **kw)
        agent.relocalizer.matched.update(matched)
        return agent.memory_goal_reason()

    chair = _ids(believed)[0]
    assert reason() == "not_relocated"
    assert reason(("h-e000", {"reasoned": False})) == "relocated_too_late"
    assert reason(("h-e000", {"perceived": {chair}, "seen": {chair}})) == "goal_seen_in_episode"
    assert reason(("h-e000", {"perceived": {"o99"}})) == "live_detection_preferred"
    assert reason(("h-e000", {})) == "other"  # trusted, never chosen: not what the loop does
    assert reason(("h-e001", {})) == "belief_below_threshold"
    assert reason(("h-e002", {})) == "goal_not_in_relocated_model"
    # the goal believed in another model the episode's views matched
    assert reason(("h-e002", {}), matched={"h-e000"}) == "goal_in_other_model"
    assert reason(("h-e001", {}), matched={"h-e000"}) == "goal_in_other_model"
    assert reason(("h-e002", {}), matched={"h-e001"}) == "goal_not_in_relocated_model"
    # several relocations: the one that came closest to the remembered goal
    assert reason(("h-e002", {}), ("h-e001", {})) == "belief_below_threshold"
    assert reason(("h-e001", {}), ("h-e000", {"perceived": {"o99"}})) == \
        "live_detection_preferred"
    # a goal taken from memory at any point: nothing to explain
    agent.reset("chair")
    _relocated(agent, "h-e001")
    agent.log_.targets.append((5, "memory", 2.0, 1.0, chair))
    assert agent.memory_goal_reason() is None
    plain = _agent(env, None)
    plain.reset("chair")
    assert plain.memory_goal_reason() is None  # no memory, nothing to say


def test_a_real_relocation_into_a_model_without_the_goal_is_explained(env):
    """The loop's own bookkeeping: an episode that relocates into its house's model from
    which every object of the goal class was removed cannot head for a remembered goal, and
    says that the model it relocated into held none; with the goal there, it heads for it
    (or for the same object seen first) and says nothing, or says it saw it first."""
    learner = _agent(env, None)
    obs, _ = env.reset(seed=0, options={"episode": 0})
    goal = env.goal_class
    learner.reset(goal, seed=0, scene=env.scene.name, episode=0, model_id="h-e000")
    _run(env, learner, obs)
    first = learner.model_
    assert _ids(first, goal), "the first episode saw its goal"
    stripped = first.copy()
    stripped.remove_objects(_ids(stripped, goal))
    for memory, allowed in ((Memory({"h-e000": stripped}, threshold=0.3),
                             {"goal_not_in_relocated_model"}),
                            (Memory({"h-e000": first}, threshold=0.3),
                             {None, "goal_seen_in_episode"})):
        agent = _agent(env, memory)
        obs, _ = env.reset(seed=0, options={"episode": 0})
        agent.reset(goal, seed=0, scene=env.scene.name, episode=1, model_id="h-e001")
        _run(env, agent, obs)
        assert agent.relocation_ is not None
        period = agent.log_.periods[-1]
        assert period.model_id == "h-e000" and period.reasoned
        assert period.model is agent.current_ and period.seen is agent._seen_here
        assert agent.memory_goal_reason() in allowed


def _run(env, agent, obs):
    done = False
    while not done:
        obs, _r, term, trunc, _info = env.step(agent.act(obs))
        done = term or trunc


# ---------------------------------------------------------------------- a tiny real run
def test_a_tiny_run_records_the_split_and_summarises_it(tmp_path):
    cfg = EvalConfig(split="val-small", scenes=2, episodes=2, max_steps=120,
                     extractor="opencv-gist", pre_explore_steps=150,
                     variants=("ans", "sp", "oracle"))
    run_eval(cfg, tmp_path, progress=False)
    recs = [json.loads(line) for line in (tmp_path / "episodes.jsonl").read_text().splitlines()]
    summary = json.loads((tmp_path / "summary.json").read_text())
    for r in recs:
        assert {"goal_in_memory", "memory_goal_reason"} <= r.keys()
        if r["variant"] != "sp":
            assert r["goal_in_memory"] is None and r["memory_goal_reason"] is None
            assert "frontier_sources" not in r  # no memory, nothing to prefer
            continue
        # every exploration target of a memory agent says where the policy found it
        assert set(r["frontier_sources"]) <= set(FRONTIER_SOURCES)
        assert all(isinstance(n, int) and n > 0 for n in r["frontier_sources"].values())
        assert isinstance(r["goal_in_memory"], bool)  # kgnav's houses give the ground truth
        explain = r["goal_in_memory"] and r["memory_goal_step"] is None
        assert (r["memory_goal_reason"] in MEMORY_GOAL_REASONS) if explain \
            else r["memory_goal_reason"] is None
        if r["memory_goal_reason"] == "not_relocated":
            assert not r["relocated"] and not r.get("undone")
    sp = summary["sp"]
    parts = [sp["goal_in_memory"], sp["goal_not_in_memory"]]
    assert all(p.keys() == {"episodes", "success", "spl"} for p in parts)
    assert sum(p["episodes"] for p in parts) == 4
    for p, held in zip(parts, (True, False), strict=True):
        mine = [r for r in recs if r["variant"] == "sp" and r["goal_in_memory"] is held]
        assert p["episodes"] == len(mine)
        assert p["success"] == (np.mean([r["success"] for r in mine]) if mine else None)
    assert len(sp["success_by_episode_index"]) == 2
    assert all(0.0 <= v <= 1.0 for v in sp["success_by_episode_index"])
    assert sp["memory_goal_reasons"].keys() == set(MEMORY_GOAL_REASONS)
    totals = {}
    for r in recs:
        if r["variant"] == "sp" and r["goal_in_memory"] is False:
            for k, n in r["frontier_sources"].items():
                totals[k] = totals.get(k, 0) + n
    assert sp["frontier_sources_goal_not_in_memory"] == totals
    assert sp["goal_not_in_memory_vs_ans"]["success"]["pairs"] == parts[1]["episodes"]
    # every hypothesis the loop judged, scored against the truth and added up
    from kgnav.agent.relocation import HYPOTHESIS_OUTCOMES
    from kgnav.benchmark.runner import HYPOTHESIS_TRUTH
    mine = [r for r in recs if r["variant"] == "sp"]
    assert all(r["hypotheses"].keys() == set(HYPOTHESIS_TRUTH) for r in mine)
    assert all(set(c) <= set(HYPOTHESIS_OUTCOMES) for r in mine for c in r["hypotheses"].values())
    assert all(r["house_models"] == 1 for r in mine)  # the pre-explored model of the house
    # scoring only: whether the pre-exploration, and the episode, had a true goal in view
    assert all(isinstance(r["goal_seen_before"], bool) for r in mine)
    assert any(r["goal_seen_before"] for r in mine)  # 150 steps of pre-exploration saw some
    # the learned segmenter needs no labels: those frames were not rendered, nothing watched
    assert all("goal_in_view_step" not in r for r in recs)
    assert all("goal_seen_before" not in r for r in recs if r["variant"] == "ans")
    assert all(0.0 <= r["memory_overlap"] <= 1.0 for r in mine)  # its states' truth is known
    for truth in HYPOTHESIS_TRUTH:
        for outcome in HYPOTHESIS_OUTCOMES:
            assert sp["hypotheses"]["judged"][truth].get(outcome, 0) == sum(
                r["hypotheses"][truth].get(outcome, 0) for r in mine)
    assert sp["hypotheses"]["not_relocated"] == sum(not r["relocated"] for r in mine)
    assert all("hypotheses" not in r for r in recs if r["variant"] == "ans")
    assert "goal_in_memory" not in summary["ans"] and "goal_in_memory" not in summary["oracle"]
    assert len(summary["oracle"]["success_by_episode_index"]) == 2


def test_a_learning_run_scores_when_the_goal_came_into_view(tmp_path):
    cfg = EvalConfig(split="val-small", scenes=1, episodes=4, max_steps=150,
                     extractor="opencv-gist", variants=("si",))
    run_eval(cfg, tmp_path, progress=False)
    recs = [json.loads(line) for line in (tmp_path / "episodes.jsonl").read_text().splitlines()]
    assert len(recs) == 4
    for r in recs:  # a learning variant renders the labels its memory is scored by
        k = r["goal_in_view_step"]
        assert k is None or 0 <= k <= r["steps"]
        if r["success"]:  # within 1 m of a goal, which came into view on the way
            assert k is not None
        earlier = [e for e in recs if e["episode"] < r["episode"] and e["goal"] == r["goal"]]
        if any(e["goal_in_view_step"] is not None for e in earlier):
            assert r["goal_seen_before"] is True  # the house's episodes had it in view
    assert recs[0]["goal_seen_before"] is False  # nothing before the house's first episode
    assert any(r["goal_in_view_step"] is not None for r in recs)
    s = json.loads((tmp_path / "summary.json").read_text())["si"]
    parts = (s["goal_not_in_memory_seen_before"]["episodes"]
             + s["goal_not_in_memory_never_seen"]["episodes"])
    assert parts == s["goal_not_in_memory"]["episodes"]


def test_the_report_prints_the_split_the_reasons_and_the_curve(capsys):
    from kgnav.cli.eval import print_summary

    recs = [_rec("ans", "h", e, ok) for e, ok in enumerate([False, False, True])]
    recs += [_rec("si", "h", 0, False, held=False),
             _rec("si", "h", 1, True, held=True, reason="goal_in_other_model"),
             _rec("si", "h", 2, True, held=True, step=4)]
    recs[3].update(goal_seen_before=True, failure="Exploration", goal_in_view_step=12)
    summary = summarize(recs)
    for s in summary.values():
        s["episodes_per_second"] = 1.0
    print_summary(summary)
    out = capsys.readouterr().out
    assert "Where success is lost" in out and "Learning curve" in out
    row = next(line for line in out.splitlines() if "other model" in line)
    si = next(line for line in out.splitlines()[out.splitlines().index(row):]
              if line.strip("│ ").startswith("si"))
    assert [c.strip() for c in si.strip("│").split("│")] == ["si", "1", "0", "0", "0", "0",
                                                             "1", "0", "0", "0"]
    assert "0.00 1.00 1.00" in out  # si's curve
    flat = " ".join(out.split())
    assert ("si: goal not in memory, though an earlier episode of the house had it in view: 1 "
            "(success 0.000); never in view: 0 (success –). Exploration failures whose goal "
            "came into view unrecognised: 1 of 1") in flat


def test_the_report_prints_the_judged_hypotheses(capsys):
    from kgnav.cli.eval import print_summary

    recs = [_rec("si", "h", e, False) for e in range(3)]
    for r, models, right, overlap in zip(recs, (0, 1, 1), ({}, {"conflict": 2}, {}),
                                         (None, 0.6, 0.5), strict=True):
        r.update(house_models=models, memory_overlap=overlap,
                 hypotheses={"right": right, "wrong": {"ambiguous": 3}, "other_house": {}})
    summary = summarize(recs)
    summary["si"]["episodes_per_second"] = 1.0
    print_summary(summary)
    out = capsys.readouterr().out
    assert "Relocation hypotheses judged in the loop" in out
    rows = [[c.strip() for c in line.strip("│").split("│")] for line in out.splitlines()
            if line.startswith("│ si") and ("right" in line or "wrong" in line)]
    assert rows == [["si", "right", "0", "0", "2", "0", "0", "0", "0", "0"],
                    ["si", "wrong", "0", "0", "0", "0", "9", "0", "0", "0"]]
    assert ("si: 2 episodes never relocated though the memory held their house; 1 of them "
            "were offered the right place (1 refused it for its geometry alone); they walked "
            "a median 0.55 of their steps within 1 m of a stored state") in " ".join(
                out.split())  # (the console wraps it)


# ---------------------------------------------------------------------- a bridged model's goal
def _bridged(env, **cfg):
    """An agent relocated into ``h-e002`` (no chair) that bridged to ``h-e000`` (a chair at
    (2, 1) of that model, seen from six states) with ``T`` (episode frame -> h-e000)."""
    from kgnav.agent.relocation import Relocation, Verdict

    believed = _model("h-e000", [("chair", 2.0, 1.0), ("sofa", 0.0, 2.0)], views=6)
    bare = _model("h-e002", [("sofa", 0.0, 2.0)], views=6)
    agent = _agent(env, Memory({m.model_id: m for m in (believed, bare)}), **cfg)
    agent.reset("chair")
    T = (1.0, 0.5, np.pi / 2)
    agent.relocalizer.relocation = Relocation(0, "h-e002", "s0", 0.0, (0.0, 0.0, 0.0),
                                              (0.0, 0.0))
    agent.relocalizer.bridges["h-e000"] = Verdict(True, "verified", T)
    return agent, T, f"h-e000/{_ids(believed)[0]}"


def test_a_goal_in_a_bridged_model_is_headed_for_through_the_bridge(env):
    agent, T, bridged_id = _bridged(env)
    t = agent._model_goal((0.0, 0.0, 0.0))
    assert t is not None and t.source == "memory" and t.object_id == bridged_id
    # the point is the chair's, mapped from the bridged model's frame into the episode's
    assert se2.apply_to_point(T, *t.point) == pytest.approx((2.0, 1.0))
    assert t.point == pytest.approx(se2.apply_to_point(se2.inverse(T), 2.0, 1.0))
    # this episode's looks at it are not in that model: not seen on arrival, it is given up
    assert not agent._still_believed(bridged_id)
    # a goal seen live replaces it (the bridged model's evidence is not weighed against it)
    from kgnav.agent.loop import Target
    assert agent._overrides(Target("live", (9.0, 9.0), "o0"), t)
    # given up once, it is not headed for again
    agent.log_.rejected.append(bridged_id)
    assert agent._model_goal((0.0, 0.0, 0.0)) is None


def test_a_bridged_goal_only_when_relocated_unambiguous_and_switched_on(env):
    agent, _, _ = _bridged(env, bridged_goals=False)
    assert agent._model_goal((0.0, 0.0, 0.0)) is None
    agent, _, _ = _bridged(env)
    agent.relocalizer.relocation = None  # no relocation stands: no bridge to go through
    assert agent._model_goal((0.0, 0.0, 0.0)) is None
    agent, _, _ = _bridged(env)
    agent.relocalizer.ambiguity = lambda mid, v, scans=None: v  # a repeated room
    assert agent._model_goal((0.0, 0.0, 0.0)) is None
    assert AgentConfig.paper().bridged_goals is False


def test_the_relocated_models_own_goal_comes_before_a_bridged_one(env):
    agent, _, bridged_id = _bridged(env)
    own = _model("h-e002", [("chair", 5.0, 5.0)], views=6)
    agent.memory = Memory({"h-e000": agent.memory.model("h-e000"), "h-e002": own})
    agent.current_ = own
    agent._scans = ScanTable(own)
    t = agent._model_goal((0.0, 0.0, 0.0))
    assert t is not None and t.object_id == _ids(own)[0] and t.object_id != bridged_id


def test_the_remembered_floor_applies_to_what_the_episode_has_not_seen(env):
    """``goals.remembered_floor`` through the loop: a remembered chair under its class's floor
    is no goal, nor is it once it is the bridged model's; seen in this episode it is one
    again; a floor for a class the agent does not know is refused when the agent is made."""
    from kgnav.agent.goals import GoalConfig
    from kgnav.errors import UnknownClassError

    floor = GoalConfig(remembered_floor=(("chair", 1.0),))  # the bridged chair's scores: 1.0
    agent, _, bridged_id = _bridged(env, goals=floor)
    assert agent._model_goal((0.0, 0.0, 0.0)).object_id == bridged_id  # at the floor: kept
    agent, _, _ = _bridged(env, goals=GoalConfig(remembered_floor=(("chair", 1.0),
                                                                   ("sofa", 0.5))))
    low = _model("h-e000", [("chair", 2.0, 1.0)], views=6, score=0.8)
    agent.memory = Memory({"h-e000": low, "h-e002": agent.memory.model("h-e002")})
    agent._bridged.clear()
    # the same chair scored under its floor: remembered only, it is no goal
    assert agent._model_goal((0.0, 0.0, 0.0)) is None
    own = _model("h-e002", [("chair", 5.0, 5.0)], views=6, score=0.8)
    agent.current_, agent._scans = own, ScanTable(own)
    assert agent._model_goal((0.0, 0.0, 0.0)) is None
    agent._seen_here = set(_ids(own))
    t = agent._model_goal((0.0, 0.0, 0.0))
    assert t is not None and t.object_id == _ids(own)[0]
    with pytest.raises(UnknownClassError, match="unicorn"):
        _agent(env, None, goals=GoalConfig(remembered_floor=(("unicorn", 0.5),)))


def test_judged_hypotheses_are_scored_against_the_true_frame():
    """Episode 2 of house h; its frame maps into model h-e000's (episode 0's) by the truth.
    A hypothesis at the truth is right, one 2 m off is wrong (as a merge that far off is),
    one 40 degrees off too, one into another house's model is other_house; each counted
    under what became of it."""
    from kgnav.benchmark.runner import judged_hypotheses

    gt = _GroundTruth(_House(), "h", 2)
    truth = se2.compose(se2.inverse(STARTS[0]), STARTS[2])
    off = se2.compose((2.0, 0.0, 0.0), truth)
    turned = (*truth[:2], truth[2] + np.radians(40))
    judged = [[5, "h-e000", truth, (0.5, 0.0), "features", "accepted"],
              [3, "h-e000", truth, (0.0, 0.0), "features", "awaiting confirmation"],
              [4, "h-e000", off, (0.0, 0.0), "features", "conflict"],
              [6, "h-e000", turned, (0.0, 0.0), "scan search", "ambiguous"],
              [7, "g-e000", truth, (0.0, 0.0), "features", "verified"]]
    got = judged_hypotheses(gt, judged)
    assert got == {"right": {"accepted": 1, "awaiting confirmation": 1},
                   "wrong": {"ambiguous": 1, "conflict": 1},
                   "other_house": {"verified": 1}}
    # an environment that cannot say where its episodes start: nothing of this house judged
    blind = _GroundTruth(SimpleNamespace(), "h", 2)
    assert judged_hypotheses(blind, judged) == {"right": {}, "wrong": {},
                                                "other_house": {"verified": 1}}


def test_the_summary_says_whether_unrelocated_episodes_were_offered_the_right_place():
    from kgnav.benchmark.runner import hypotheses_summary

    def rec(relocated, house_models, right):
        return {"relocated": relocated, "house_models": house_models,
                "hypotheses": {"right": right, "wrong": {"conflict": 2}, "other_house": {}}}

    recs = [rec(True, 1, {"accepted": 1}),
            rec(False, 0, {}),  # the house's first episode: nothing to relocate into
            rec(False, 1, {}),  # never offered the right place
            rec(False, 2, {"conflict": 1}),  # offered, refused for its geometry
            rec(False, 1, {"ambiguous": 2, "conflict": 1})]  # offered, found ambiguous
    for r, overlap in zip(recs, (0.9, None, 0.0, 0.5, 0.7), strict=True):
        r["memory_overlap"] = overlap
    s = hypotheses_summary(recs)
    assert s["not_relocated_overlap"] == 0.5  # the median over the 3 that count
    assert s["judged"] == {"right": {"accepted": 1, "ambiguous": 2, "conflict": 2},
                           "wrong": {"conflict": 10}, "other_house": {}}
    assert (s["not_relocated"], s["not_relocated_offered_right"],
            s["not_relocated_refused_geometry"]) == (3, 2, 1)


def test_memory_overlap_is_the_share_of_steps_near_a_stored_state():
    from kgnav.benchmark.runner import OVERLAP_RADIUS, memory_overlap

    stored = [(0.0, 0.0, 0.0), (10.0, 0.0, 2.0)]
    walk = [(0.0, 0.99 * OVERLAP_RADIUS, 0.0), (5.0, 0.0, 0.0), None,
            (10.0, -1.01 * OVERLAP_RADIUS, 1.0), (9.5, 0.5, 3.0)]
    assert memory_overlap(walk, stored) == 0.5  # 2 of the 4 known positions
    assert memory_overlap(walk, []) is None and memory_overlap([None], stored) is None
    many = [(0.01 * k, 50.0, 0.0) for k in range(5000)]  # more states than one chunk
    assert memory_overlap([(49.0, 50.2, 0.0), (0.0, 0.0, 0.0)], many) == 0.5
