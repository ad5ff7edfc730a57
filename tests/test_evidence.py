"""Range profiles, occupancy, object evidence and belief: their algebra under merging and
transforms, and brute-force checks of the vectorised computations."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from kgnav import AbstractModel, Detection, merge, query
from kgnav.common import se2
from kgnav.memory.constants import SCHEMA_VERSION
from kgnav.memory.evidence import (
    BeliefModel,
    Evidence,
    ScanTable,
    belief,
    forget,
    object_evidence,
)
from kgnav.memory.geometry import ScanGeometry, occupancy_from_scans
from kgnav.memory.model import SEES
from tests.strategies import SCAN, models

PROPS = settings(max_examples=60, suppress_health_check=[HealthCheck.function_scoped_fixture])


def brute_evidence(model: AbstractModel, oid: str, miss_range: float = 3.0,
                   weak_below: float = 0.0) -> Evidence:
    """Evidence of one object, state by state (no vectorisation, no table)."""
    g = model.graph
    d = g.nodes[oid]
    seers = {s for s, _, k in g.in_edges(oid, keys=True) if k == SEES}
    weak = sum(1 for s, _, k, e in g.in_edges(oid, keys=True, data=True)
               if k == SEES and e["score"] < weak_below)
    missed = 0
    for s in model.states():
        sd = g.nodes[s]
        if "ranges" not in sd or s in seers:
            continue
        pose = np.array([[sd["x"], sd["y"], sd["theta"]]])
        if model.scan.covers(pose, np.asarray(sd["ranges"], np.float32)[None, :],
                             (d["x"], d["y"]), miss_range)[0]:
            missed += 1
    rival = sum(g.nodes[r]["n_views"] for r in model.objects()
                if g.nodes[r]["cls"] != d["cls"]
                and math.hypot(g.nodes[r]["x"] - d["x"], g.nodes[r]["y"] - d["y"]) <= 0.4)
    return Evidence(len(seers), len({g.nodes[s]["episode"] for s in seers}), missed,
                    float(d["score"]), rival, weak)


@PROPS
@given(models(scan=True, max_states=10))
def test_evidence_equals_a_state_by_state_count(m):
    ev = object_evidence(m)
    for o in m.objects():
        assert ev[o] == brute_evidence(m, o)


@PROPS
@given(models(model_id="a", scan=True), models(model_id="b", scan=True), st.data())
def test_merging_combines_evidence_exactly(a, b, data):
    """The evidence of every object of a merge is that of the union of states and views (weak
    views included: each view keeps its score)."""
    T = data.draw(st.tuples(st.floats(-3, 3), st.floats(-3, 3),
                            st.floats(-math.pi, math.pi, exclude_max=True)))
    m = merge(a, b, transform=T)
    ev = object_evidence(m)
    for o in m.objects():
        assert ev[o] == brute_evidence(m, o)
    weak = object_evidence(m, weak_below=0.5)
    for o in m.objects():
        assert weak[o] == brute_evidence(m, o, weak_below=0.5)
    assert sum(e.n_weak for e in weak.values()) == sum(
        1 for *_e, k, d in m.graph.edges(keys=True, data=True) if k == SEES and d["score"] < 0.5)
    # views and scores are conserved: no view is lost or counted twice
    for o in m.objects():
        views = [d["score"] for _s, _o, k, d in m.graph.in_edges(o, keys=True, data=True)
                 if k == SEES]
        assert ev[o].score == pytest.approx(sum(views))
    total = sum(e.n_views for e in ev.values())
    assert total == sum(1 for *_e, k in m.graph.edges(keys=True) if k == SEES)
    assert sum(e.score for e in ev.values()) == pytest.approx(
        sum(d["score"] for *_e, k, d in m.graph.edges(keys=True, data=True) if k == SEES))


@PROPS
@given(models(scan=True), st.data())
def test_range_profiles_survive_transform_and_self_merge(m, data):
    s = data.draw(st.sampled_from(sorted(m.states())))
    assert merge(m, m, anchor=(s, s)) == m
    moved = m.copy().transform((1.0, -2.0, 0.7))
    for st_ in m.states():
        assert m.ranges(st_).tobytes() == moved.ranges(st_).tobytes()


def test_scan_table_grows_like_a_rebuilt_one():
    m = AbstractModel(2, model_id="t", scan=SCAN)
    table = ScanTable(m)
    rng = np.random.default_rng(0)
    for k in range(40):
        sid = m.add_state(rng.normal(size=2), (k * 0.3, 0.0, k * 0.1),
                          ranges=rng.uniform(0.5, 5, SCAN.bins))
        d = m.graph.nodes[sid]
        table.add(sid, (d["x"], d["y"], d["theta"]), d["ranges"])
    fresh = ScanTable(m)
    assert table.ids == fresh.ids
    assert np.array_equal(table.poses, fresh.poses)
    assert table.covering(3.0, 0.5) == fresh.covering(3.0, 0.5)


def test_a_glimpse_looked_at_again_loses_belief_and_is_forgotten():
    scan = ScanGeometry(90.0, 4, 5.0)
    far = np.full(4, 5.0)
    m = AbstractModel(2, model_id="f", scan=scan)
    m.add_state([1.0, 0.0], (0, 0, 0), [Detection("chair", (2.0, 0.0, 0.4))], ranges=far)
    m.add_state([0.0, 1.0], (0, 0.1, 0), [Detection("chair", (2.0, 0.05, 0.4))], ranges=far)
    m.add_state([1.0, 1.0], (5, 5, 0), [Detection("bed", (7.0, 5.0, 0.4))], ranges=far)
    (chair,) = [o for o in m.objects() if m.graph.nodes[o]["cls"] == "chair"]
    assert belief(object_evidence(m)[chair]) > 0.8  # two views, no miss
    for k in range(6):  # six more looks at the chair's place, nothing there
        m.add_state([0.5, k + 1.0], (0.3, -0.2 + 0.1 * k, 0.05 * k), ranges=far)
    ev = object_evidence(m)[chair]
    assert ev.n_missed == 6 and belief(ev) < 0.2
    assert forget(m, 0.2) == 1
    assert [m.graph.nodes[o]["cls"] for o in m.objects()] == ["bed"]  # unjudged glimpse stays


def test_a_wall_hides_an_object_from_negative_evidence():
    scan = ScanGeometry(90.0, 4, 5.0)
    m = AbstractModel(2, model_id="w", scan=scan)
    m.add_state([1.0, 0.0], (0, 0, 0), [Detection("chair", (2.5, 0.0, 0.4))],
                ranges=np.full(4, 5.0))
    m.add_state([0.0, 1.0], (0, 0, 0.01), ranges=np.full(4, 1.0))  # a wall at 1 m
    assert object_evidence(m)["o0"].n_missed == 0


def test_another_label_at_the_same_place_takes_the_goal_share():
    """A desk seen 6 times and called a sofa 2 times at the same place: the sofa holds a quarter
    of the place's views, so it is not a goal however often it was seen."""
    m = AbstractModel(2, model_id="r")
    for k in range(8):
        cls = "sofa" if k < 2 else "desk"
        m.add_state([math.cos(0.3 * k), math.sin(0.3 * k)], (0, 0.05 * k, 0),
                    [Detection(cls, (2.0, 0.05, 0.4))])
    ev = object_evidence(m)
    (sofa,) = [o for o in m.objects() if m.graph.nodes[o]["cls"] == "sofa"]
    assert ev[sofa].n_rival == 6 and ev[sofa].label_share == pytest.approx(0.25)
    from kgnav.agent.goals import GoalConfig, choose_goal

    assert choose_goal(m, "sofa", (0, 0), GoalConfig()) is None
    assert choose_goal(m, "sofa", (0, 0), GoalConfig(min_label_share=0.0)).id == sofa
    # consolidation forgets the minority label, keeps the majority one
    from kgnav.memory.evidence import forget

    (desk,) = [o for o in m.objects() if m.graph.nodes[o]["cls"] == "desk"]
    assert forget(m, 0.2, min_label_share=0.0) == 0
    assert forget(m, 0.2, min_label_share=0.5) == 1
    assert list(m.objects()) == [desk]


def test_repeated_weak_views_become_belief_and_one_does_not():
    """Weak views (segments under the detection threshold) add less than detections: one is
    not believed, several from different states are; misses still count against them."""
    model = BeliefModel(weak_below=0.6, weak_weight=1.0)
    one = Evidence(1, 1, 0, 0.5, n_weak=1)
    four = Evidence(4, 2, 0, 2.0, n_weak=4)
    assert belief(one, model) < 0.2 < 0.5 < belief(four, model)
    assert belief(Evidence(4, 2, 4, 2.0, n_weak=4), model) < 0.5  # looked at, unseen, 4 times
    assert belief(Evidence(1, 1, 0, 0.9), model) > belief(one, model)  # a detection: more
    m = AbstractModel(2, model_id="e", scan=ScanGeometry(90.0, 4, 5.0))
    far = np.full(4, 5.0)
    for k in range(4):
        m.add_state([1.0, float(k)], (0.3 * k, 0, 0),
                    [Detection("plant", (2.0, 0.0, 0.4), score=0.5)], ranges=far)
    ev = object_evidence(m, weak_below=0.6)["o0"]
    assert (ev.n_views, ev.n_weak, ev.n_missed) == (4, 4, 0)
    assert belief(ev, model) > 0.5
    assert object_evidence(m)["o0"].n_weak == 0  # weak_below = 0: every view a detection


def test_belief_model_weights():
    bm = BeliefModel(p_detect=0.6, p_false=0.05, prior=-3.0)
    assert bm.view_weight == pytest.approx(math.log(12))
    assert belief(Evidence(2, 1, 0, 2.0), bm) > 0.85
    assert belief(Evidence(2, 1, 10, 2.0), bm) < 0.1


def test_association_keeps_a_large_object_seen_from_two_sides_as_one():
    m = AbstractModel(2, model_id="bed")
    # a 2 m bed seen from its foot and from its side: the two surface centres 0.9 m apart
    m.add_state([1.0, 0.0], (0, 0, 0), [Detection("bed", (2.0, 0.0, 0.3), radius=0.8)])
    m.add_state([0.0, 1.0], (3, -2, 1.5), [Detection("bed", (2.6, 0.7, 0.3), radius=0.9)])
    assert m.n_objects == 1
    # two chairs 0.8 m apart stay two
    m.add_state([1.0, 1.0], (5, 5, 0), [Detection("chair", (7.0, 5.0, 0.4), radius=0.25),
                                        Detection("chair", (7.0, 5.8, 0.4), radius=0.25)])
    assert m.n_objects == 3


def test_folding_two_objects_keeps_views_and_scores_exact():
    """An object that grows until it reaches a neighbour of its class swallows it: views,
    scores and provenance are combined, never counted twice."""
    m = AbstractModel(2, model_id="fold")
    s0 = m.add_state([1.0, 0.0], (0, 0, 0), [Detection("sofa", (2.0, 0.0, 0.4), radius=0.1,
                                                       score=0.5)])
    m.add_state([0.0, 1.0], (0, 0.5, 0), [Detection("sofa", (2.0, 1.1, 0.4), radius=0.1,
                                                     score=0.25)])
    assert m.n_objects == 2
    # a view of the whole sofa: its surface spans both, so the two become one
    m.add_state([1.0, 1.0], (0, 0.2, 0), [Detection("sofa", (2.0, 0.55, 0.4), radius=1.2,
                                                    score=1.0)])
    (o,) = list(m.objects())
    d = m.graph.nodes[o]
    assert d["n_views"] == 3 and d["score"] == pytest.approx(1.75)
    assert len(d["origin"].split()) == 2 and m.known_node("fold/o1") == o
    assert s0 in m.graph.predecessors(o)


def test_occupancy_and_known_free():
    scan = ScanGeometry(90.0, 9, 5.0)
    m = AbstractModel(2, model_id="o", scan=scan)
    m.add_state([1.0, 0.0], (0, 0, 0), ranges=np.full(9, 3.0))  # a wall 3 m ahead
    grid = query.occupancy(m)
    assert query.known_free(m, 1.5, 0.0, grid) and not query.known_free(m, -1.0, 0.0, grid)
    assert grid.state_at(3.0, 0.0) == "obstacle"
    same = occupancy_from_scans(scan, [(0, 0, 0)], [np.full(9, 3.0)])
    assert np.array_equal(same.free, grid.free)
    assert query.occupancy(AbstractModel(2)) is None
    # a transformed model's floor is the same floor, moved
    moved = m.copy().transform((2.0, 1.0, math.pi / 2))
    x, y = se2.apply_to_point((2.0, 1.0, math.pi / 2), 1.5, 0.0)
    assert query.known_free(moved, x, y)


def test_trusted_objects_lists_evidence():
    m = AbstractModel(2, model_id="q")
    m.add_state([1.0, 0.0], (0, 0, 0), [Detection("chair", (1.0, 0.0, 0.4), score=0.9)])
    m.add_state([0.0, 1.0], (0.2, 0, 0), [Detection("chair", (1.0, 0.05, 0.4), score=0.7)])
    (row,) = query.trusted_objects(m, "chair")
    assert row["views"] == 2 and row["score"] == pytest.approx(1.6) and row["belief"] > 0.8


# --------------------------------------------------------------------------- files
@PROPS
@given(models(scan=True))
def test_geometry_and_evidence_survive_save_and_load(tmp_path, m):
    path = tmp_path / "m.graphml"
    m.save(path)
    back = AbstractModel.load(path)
    assert back == m
    assert back.scan == m.scan
    for s in m.states():
        assert back.ranges(s).tobytes() == m.ranges(s).tobytes()
    assert object_evidence(back) == object_evidence(m)
    assert object_evidence(back, weak_below=0.5) == object_evidence(m, weak_below=0.5)


def test_a_version_1_file_still_loads_and_saves_as_the_current_version(tmp_path):
    """A model written before range profiles and evidence (schema 1) loads with point-like
    objects, full-confidence views, no scan and no relocation threshold, and is written back
    as the current version."""
    from pathlib import Path

    v1 = Path(__file__).parent / "data" / "graphml" / "valid.graphml"
    assert '<data key="g0">1</data>' in v1.read_text()
    m = AbstractModel.load(v1)
    assert m.graph.graph["kgnav_schema"] == SCHEMA_VERSION and m.scan is None
    assert m.relocation_threshold is None
    for o in m.objects():
        d = m.graph.nodes[o]
        assert d["radius"] == 0.0 and d["score"] == float(d["n_views"])
    assert all(m.ranges(s) is None for s in m.states())
    assert {o: e.n_missed for o, e in object_evidence(m).items()} == {"o0": 0, "o1": 0}
    m.save(tmp_path / "v3.graphml")
    again = AbstractModel.load(tmp_path / "v3.graphml")
    text = (tmp_path / "v3.graphml").read_text()
    assert again == m and f'<data key="g0">{SCHEMA_VERSION}</data>' in text


def test_occupancy_never_misplaces_edge_hits_and_survives_foreign_ranges():
    """A hit just short of the sensor's range at the edge of the field of view lies farther than
    that range, outside the grid sized by it: it is dropped, never wrapped into another row of
    the grid (nor a crash, as it used to be); ranges beyond the sensor, infinite or NaN are read
    as no return."""
    from kgnav.memory.geometry import occupancy_from_scans

    scan = ScanGeometry(79.0, 40, 5.0)
    r = np.full(40, 4.99, np.float32)
    pose = (0.0, 0.0, 0.3)
    occ = occupancy_from_scans(scan, [pose], [r])
    ends = scan.endpoints(pose, r)
    h, w = occ.hits.shape
    inside = [(x, y) for x, y in ends if 0 <= occ.cell(x, y)[0] < h and 0 <= occ.cell(x, y)[1] < w]
    assert 0 < len(inside) < len(ends)  # the edge bins reach past the grid
    assert all(occ.state_at(x, y) == "obstacle" for x, y in inside)
    assert int((occ.hits > 0).sum()) <= len(inside)  # nothing landed anywhere else
    bad = np.array([np.inf, np.nan, 50.0] + [4.99] * 37, np.float32)
    occ = occupancy_from_scans(scan, [(0.0, 0.0, 0.0), (1.0, 0.0, 0.0)], [bad, r])
    assert int(occ.hits.sum()) > 0


def test_the_goal_headed_for_stays_unless_another_is_much_closer():
    """Walking toward one chair past another: the chair already headed for stays the goal
    while the other is closer by less than ``keep_margin`` (no flip-flopping between two
    remembered goals, each step re-deciding)."""
    from kgnav.agent.goals import GoalConfig, choose_goal

    m = AbstractModel(2, model_id="k")
    for k in range(3):
        m.add_state([1.0, 0.0], (0, 0.1 * k, 0), [Detection("chair", (3.0, 0.0, 0.4)),
                                                  Detection("chair", (-4.0, 0.0, 0.4))])
    near, far = sorted(m.objects(), key=lambda o: abs(m.graph.nodes[o]["x"]))
    cfg = GoalConfig(keep_margin=1.5)
    assert choose_goal(m, "chair", (0.0, 0.0), cfg).id == near
    assert choose_goal(m, "chair", (0.0, 0.0), cfg, current=far).id == far  # 4 m vs 3 m
    assert choose_goal(m, "chair", (0.0, 0.0), GoalConfig(keep_margin=0.0),
                       current=far).id == near
    assert choose_goal(m, "chair", (2.0, 0.0), cfg, current=far).id == near  # 6 m vs 1 m


def test_a_place_labelled_often_but_with_less_confidence_than_its_class_is_not_a_goal():
    """A chair 2 m away seen 5 times at confidence 0.6 (a segmenter's persistent mistake: as
    often seen as a real object, less sure) and one 5 m away at 0.9: the belief rule heads for
    the far one. Seen only twice, the near one is not yet judged by its confidence; alone, it
    is the goal however low its confidence (some classes are always detected with less); with
    the comparison off it is the goal too. Merging keeps the mean confidence."""
    from kgnav.agent.goals import GoalConfig, choose_goal

    def model(n_near, far=True):
        m = AbstractModel(2, model_id="c")
        for k in range(5):
            dets = [Detection("chair", (5.0, 0.0, 0.4), score=0.9)] if far else []
            if k < n_near:
                dets.append(Detection("chair", (-2.0, 0.0, 0.4), score=0.6))
            m.add_state([1.0, 0.05 * k], (0, 0.05 * k, 0), dets)
        return m

    m = model(5)
    near, far = sorted(m.objects(), key=lambda o: abs(m.graph.nodes[o]["x"]))
    ev = object_evidence(m)
    assert ev[near].mean_score == pytest.approx(0.6) and ev[far].mean_score == pytest.approx(0.9)
    assert choose_goal(m, "chair", (0.0, 0.0), GoalConfig()).id == far
    assert choose_goal(m, "chair", (0.0, 0.0), GoalConfig(score_margin=0.35)).id == near
    assert choose_goal(m, "chair", (0.0, 0.0), GoalConfig(score_margin=math.inf)).id == near
    assert choose_goal(model(2), "chair", (0.0, 0.0), GoalConfig()).id == near
    alone = model(5, far=False)
    assert choose_goal(alone, "chair", (0.0, 0.0), GoalConfig()).position[0] == pytest.approx(-2.0)
    both = merge(m, model(5), transform=(0.0, 0.0, 0.0))
    ev = object_evidence(both)
    assert sorted(round(e.mean_score, 6) for e in ev.values()) == [0.6, 0.9]


def test_a_floor_on_confidence_refuses_even_a_class_s_only_candidate():
    """With ``min_score`` a lone chair seen 5 times at 0.6 is no goal (a persistent phantom
    that is its class's only candidate), one at 0.9 is; seen twice, it is not judged yet."""
    from kgnav.agent.goals import GoalConfig, choose_goal

    def lone(score, n=5):
        m = AbstractModel(2, model_id="c")
        for k in range(n):
            m.add_state([1.0, 0.05 * k], (0, 0.05 * k, 0),
                        [Detection("chair", (-2.0, 0.0, 0.4), score=score)])
        return m

    floor = GoalConfig(min_score=0.72)
    assert choose_goal(lone(0.6), "chair", (0.0, 0.0), GoalConfig()) is not None
    assert choose_goal(lone(0.6), "chair", (0.0, 0.0), floor) is None
    assert choose_goal(lone(0.9), "chair", (0.0, 0.0), floor) is not None
    assert choose_goal(lone(0.6, n=2), "chair", (0.0, 0.0), floor) is not None


def test_a_per_class_floor_refuses_a_remembered_lone_candidate_not_one_seen_now():
    """``remembered_floor``: a lone sofa remembered at 0.7 is no goal under a sofa floor of
    0.78, one at 0.9 is; perceived in this episode it is spared (judged on arrival); a class
    without a floor, or no ``perceived`` set at all (the caller judges what it sees), is not
    floored."""
    from kgnav.agent.goals import GoalConfig, choose_goal

    def lone(cls, score, n=5):
        m = AbstractModel(2, model_id="c")
        for k in range(n):
            m.add_state([1.0, 0.05 * k], (0, 0.05 * k, 0),
                        [Detection(cls, (-2.0, 0.0, 0.4), score=score)])
        return m

    cfg = GoalConfig(remembered_floor=(("sofa", 0.78), ("bed", 0.85)))
    low, high = lone("sofa", 0.7), lone("sofa", 0.9)
    oid = next(iter(low.objects()))
    assert choose_goal(low, "sofa", (0.0, 0.0), cfg, perceived=set()) is None
    assert choose_goal(high, "sofa", (0.0, 0.0), cfg, perceived=set()) is not None
    assert choose_goal(low, "sofa", (0.0, 0.0), cfg, perceived={oid}) is not None
    assert choose_goal(low, "sofa", (0.0, 0.0), cfg) is not None  # perceived=None: all spared
    assert choose_goal(lone("chair", 0.6), "chair", (0.0, 0.0), cfg, perceived=set()) is not None
    assert choose_goal(lone("sofa", 0.7, n=2), "sofa", (0.0, 0.0), cfg,
                       perceived=set()) is not None  # seen twice: not judged yet
    assert choose_goal(low, "sofa", (0.0, 0.0), GoalConfig(), perceived=set()) is not None
    for bad in ((("sofa", 1.5),), (("sofa", 0.7), ("sofa", 0.8)), ((3, 0.5),)):
        with pytest.raises(ValueError, match="remembered_floor"):
            GoalConfig(remembered_floor=bad)
