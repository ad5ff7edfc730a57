"""Verified relocation on constructed rooms: right matches accepted (and refined), wrong-house and
rotated-twin matches refused, landmark checks undo refuted matches, bridges found."""

from __future__ import annotations

import math

import numpy as np
import pytest

from kgnav.agent.memory import Memory
from kgnav.agent.relocation import HYPOTHESIS_OUTCOMES, Relocalizer, RelocationConfig
from kgnav.agent.state_creator import AbstractState
from kgnav.common import se2
from kgnav.memory.geometry import ScanGeometry
from kgnav.memory.model import AbstractModel, Detection

SCAN = ScanGeometry(79.0, 40, 5.0)
DIM = 8

# Room A: 6 x 4 m with a 1.5 m wall stub from the north wall at x = 2 (not symmetric).
ROOM_A = [((0, 0), (6, 0)), ((6, 0), (6, 4)), ((6, 4), (0, 4)), ((0, 4), (0, 0)),
          ((2, 4), (2, 2.5))]
# Room B (another house): 5 x 5 m, a stub from the east wall.
ROOM_B = [((0, 0), (5, 0)), ((5, 0), (5, 5)), ((5, 5), (0, 5)), ((0, 5), (0, 0)),
          ((5, 2), (3.5, 2))]


def cast(walls, pose) -> np.ndarray:
    """The range profile (z-depth per bin) seen from ``pose`` in a room of wall segments."""
    x, y, t = pose
    c, s = math.cos(t), math.sin(t)
    out = np.full(SCAN.bins, SCAN.max_range, np.float32)
    for b, slope in enumerate(SCAN.slopes):
        dx, dy = c + s * slope, s - c * slope  # forward 1, left -slope, in the world
        for (ax, ay), (bx, by) in walls:
            ex, ey = bx - ax, by - ay
            den = dx * ey - dy * ex
            if abs(den) < 1e-12:
                continue
            tt = ((ax - x) * ey - (ay - y) * ex) / den
            u = ((ax - x) * dy - (ay - y) * dx) / den
            if tt > 1e-6 and 0 <= u <= 1 and tt < out[b]:
                out[b] = tt
    return out


#: Features that match no stored state (cosine distance 0.65 to every unit vector).
NO_MATCH = np.full(DIM, 1 / math.sqrt(DIM), np.float32)


def unit(i: int) -> np.ndarray:
    v = np.zeros(DIM, np.float32)
    v[i % DIM] = 1.0
    return v


WALK = [(1.0, 1.0, 0.0), (3.0, 1.0, 0.0), (5.0, 1.0, 1.2), (5.0, 3.0, 2.6), (3.5, 3.0, math.pi),
        (1.0, 2.0, -1.2), (1.0, 1.0, 0.6), (4.0, 2.0, -2.0)]


def stored_model(walls=ROOM_A, model_id="a-e000", objects=()) -> AbstractModel:
    m = AbstractModel(DIM, model_id=model_id, extractor="toy", scan=SCAN)
    for k, pose in enumerate(WALK):
        m.add_state(unit(k), pose, objects, step=k, ranges=cast(walls, pose))
    return m


def episode_states(walls, T_true, start=0):
    """The walk seen in an episode whose frame maps into the room's frame by ``T_true``:
    states with poses in the episode frame and the room's true profiles."""
    inv = se2.inverse(T_true)
    out = []
    for k, world in enumerate(WALK[start:] + WALK[:start]):
        out.append(AbstractState(unit(k + start), se2.compose(inv, world), (),
                                 cast(walls, world)))
    return out


def run(relocalizer: Relocalizer, states):
    got = None
    for step, s in enumerate(states):
        got = relocalizer.observe(step, s, SCAN) or got
    return got


def test_a_right_match_is_verified_and_refined():
    T_true = (2.0, -1.0, 0.7)
    memory = Memory({"a-e000": stored_model()}, threshold=0.05)
    rel = Relocalizer(memory)
    r = run(rel, episode_states(ROOM_A, T_true))
    assert r is not None and r.model_id == "a-e000"
    assert r.inliers >= 0.8 and r.conflicts <= 0.05
    assert math.dist(r.transform[:2], T_true[:2]) < 0.05
    assert se2.angle_diff(r.transform[2], T_true[2]) < math.radians(2)
    assert rel.decisions["verified"] >= 1


def test_icp_corrects_an_imperfect_anchor():
    """The features match the right place, but the episode's pose there is 30 cm / 8 degrees
    off (the paper's "imperfect match"): ICP on the scans brings the transform back."""
    T_true = (0.0, 0.0, 0.0)
    memory = Memory({"a-e000": stored_model()}, threshold=0.05)
    rel = Relocalizer(memory)
    geo = memory.geometry("a-e000")
    assert geo is not None
    states = episode_states(ROOM_A, T_true)
    for s in states[:6]:
        rel._recent.append((s.pose, np.asarray(s.ranges, np.float32), SCAN))
    v = rel.verify("a-e000", (0.3, -0.2, math.radians(8)))
    assert v.ok
    assert math.dist(v.transform[:2], (0, 0)) < 0.05 and abs(v.transform[2]) < math.radians(1)


def test_a_wrong_house_match_is_refused():
    """Room B's views match room A's in feature space (same feature ids): geometry refuses."""
    memory = Memory({"a-e000": stored_model()}, threshold=0.05)
    rel = Relocalizer(memory)
    assert run(rel, episode_states(ROOM_B, (0.5, 0.0, 0.3))) is None
    assert rel.decisions["verified"] == 0
    assert rel.decisions["geometry"] + rel.decisions["conflict"] > 0


def test_a_rotated_twin_is_refused():
    """The right room, but matched to the state half a turn away about the room's centre
    (what a look-alike view on the other side proposes): the stub gives it away."""
    memory = Memory({"a-e000": stored_model()}, threshold=0.05)
    half_turn = se2.compose((3.0, 2.0, math.pi), (-3.0, -2.0, 0.0))  # about (3, 2)
    rel = Relocalizer(memory)
    for k, s in enumerate(episode_states(ROOM_A, (0.0, 0.0, 0.0))):
        rel._recent.append((s.pose, np.asarray(s.ranges, np.float32), SCAN))
        assert k >= 0
    v = rel.verify("a-e000", half_turn)
    assert not v.ok and v.reason in ("geometry", "conflict")
    assert rel.verify("a-e000", (0.0, 0.0, 0.0)).ok


def test_without_geometry_the_first_match_is_taken():
    memory = Memory({"a-e000": stored_model()}, threshold=0.05)
    rel = Relocalizer(memory, RelocationConfig(geometry=False, confirm_matches=1))
    r = run(rel, episode_states(ROOM_B, (0.5, 0.0, 0.3)))
    assert r is not None and r.step == 0  # the paper's behaviour: a wrong match, accepted


def test_landmarks_undo_a_refuted_relocation_and_block_it():
    chair, bed = Detection("chair", (1.0, 3.0, 0.5)), Detection("bed", (5.0, 3.0, 0.5))
    memory = Memory({"a-e000": stored_model(objects=(chair, bed))}, threshold=0.05)
    rel = Relocalizer(memory, RelocationConfig(verify_checks=5))
    states = episode_states(ROOM_A, (0.0, 0.0, 0.0))
    assert run(rel, states) is not None
    wrong = AbstractState(unit(1), (3.0, 1.0, 0.0), (Detection("toilet", (1.0, 3.0, 0.5)),
                                                     Detection("sink", (5.0, 3.0, 0.5))))
    assert rel.check(wrong) and rel.check(wrong)
    assert not rel.check(wrong)  # 6 checks, none supported
    assert rel.relocation is None and [u.model_id for u in rel.undone] == ["a-e000"]
    assert rel.mergeable() is None
    assert run(rel, states) is None  # the same match is not accepted again
    assert rel.decisions["refuted before"] > 0


def test_weak_support_keeps_the_relocation_but_does_not_merge():
    chair, bed = Detection("chair", (1.0, 3.0, 0.5)), Detection("bed", (5.0, 3.0, 0.5))
    memory = Memory({"a-e000": stored_model(objects=(chair, bed))}, threshold=0.05)
    rel = Relocalizer(memory, RelocationConfig(verify_checks=4, verify_support=0.25,
                                               merge_support=0.5))
    run(rel, episode_states(ROOM_A, (0.0, 0.0, 0.0)))
    mixed = AbstractState(unit(1), (3.0, 1.0, 0.0),
                          (Detection("chair", (1.0, 3.0, 0.5)), Detection("sink", (5.0, 3.0, 0.5)),
                           Detection("toilet", (5.0, 3.0, 0.5))))
    for _ in range(3):
        assert rel.check(mixed)
    r = rel.relocation
    assert r is not None and r.supported * 3 == r.checked
    assert rel.mergeable() is None


def test_a_second_model_of_the_same_room_is_found_as_a_bridge():
    a = stored_model(model_id="a-e000")
    b = stored_model(model_id="a-e001").transform((1.0, 2.0, 0.5))  # same room, other frame
    b.graph.graph["model_id"] = "a-e001"
    memory = Memory({"a-e000": a, "a-e001": b}, threshold=0.05)
    rel = Relocalizer(memory, RelocationConfig(bridge_interval=1))
    run(rel, episode_states(ROOM_A, (0.0, 0.0, 0.0)) * 2)
    assert rel.relocation is not None
    other = "a-e001" if rel.relocation.model_id == "a-e000" else "a-e000"
    assert other in rel.bridges
    T = rel.bridges[other].transform
    want = (1.0, 2.0, 0.5) if other == "a-e001" else (0.0, 0.0, 0.0)  # episode -> model
    assert math.dist(T[:2], want[:2]) < 0.1 and se2.angle_diff(T[2], want[2]) < 0.05


# A corridor 1.6 m wide and 24 m long, with doorways (gaps) every 6 m: along it the side
# walls fit any shift, and a profile sees no end.
CORRIDOR = [((0, 0), (2.5, 0)), ((3.5, 0), (8.5, 0)), ((9.5, 0), (14.5, 0)),
            ((15.5, 0), (24, 0)), ((0, 1.6), (24, 1.6))]
CORRIDOR_WALK = [(6.0 + 0.5 * k, 0.8, a) for k in range(10) for a in (0.0, 1.2, -1.2)]


def test_a_match_shifted_along_a_corridor_is_ambiguous():
    """The features point 1.5 m down the corridor from where the agent is: the side walls fit
    perfectly there too (the old check accepted it, inliers 1.0); the ambiguity test sees that
    shifted starts fit as well and refuses it."""
    m = AbstractModel(DIM, model_id="c-e000", extractor="toy", scan=SCAN)
    for k, pose in enumerate(CORRIDOR_WALK):
        m.add_state(unit(k), pose, (), step=k, ranges=cast(CORRIDOR, pose))
    memory = Memory({"c-e000": m}, threshold=0.05)
    shift = (1.5, 0.0, 0.0)  # the true frame is 1.5 m further along than the match says
    states = [AbstractState(unit(k), se2.compose(shift, pose), (), cast(CORRIDOR, pose))
              for k, pose in enumerate(CORRIDOR_WALK)]
    old = Relocalizer(memory, RelocationConfig(unique=False))
    r = run(old, states)
    assert r is not None and math.dist(r.transform[:2], (-1.5, 0.0)) < 0.2  # wrong, accepted
    new = Relocalizer(memory)
    assert run(new, states) is None
    assert new.decisions["ambiguous"] > 0


def test_a_distinct_room_is_not_ambiguous():
    memory = Memory({"a-e000": stored_model()}, threshold=0.05)
    rel = Relocalizer(memory)
    r = run(rel, episode_states(ROOM_A, (2.0, -1.0, 0.7)))
    assert r is not None and rel.decisions["ambiguous"] == 0
    v = rel.verify("a-e000", r.transform)
    assert v.ok and rel.ambiguity("a-e000", v) is None


# House 1: room A and, east of it through a door, a 5 x 4 m room with a pillar. House 2: the
# same room A (a look-alike) next to a narrow 3 m room.
HOUSE_1 = ROOM_A[:1] + [((6, 0), (6, 1.5)), ((6, 2.5), (6, 4))] + ROOM_A[2:] + [
    ((6, 0), (11, 0)), ((11, 0), (11, 4)), ((11, 4), (6, 4)),
    ((8, 1.5), (9, 1.5)), ((9, 1.5), (9, 2.5)), ((9, 2.5), (8, 2.5)), ((8, 2.5), (8, 1.5))]
HOUSE_2 = HOUSE_1[:7] + [((6, 0), (9, 0)), ((9, 0), (9, 4)), ((9, 4), (6, 4))]
EAST_WALK = [(7.0, 1.0, 0.0), (7.0, 3.0, -0.6), (7.5, 2.0, 0.3), (8.5, 0.7, 1.5),
             (7.0, 2.0, -0.2), (8.0, 3.3, -1.3), (6.8, 1.2, 0.8), (7.6, 3.0, -0.5)]


def test_the_whole_episode_refuses_a_look_alike_room_of_another_house():
    """The episode (house 2) explored its narrow room, then walked into its copy of room A,
    where the last scans match house 1's room A perfectly and the relocation is accepted. The
    whole episode does not fit house 1: its east wall stands in house 1's open floor. The
    merge is refused; without the whole-episode check it would have been merged."""
    m = AbstractModel(DIM, model_id="h1-e000", extractor="toy", scan=SCAN)
    for k, pose in enumerate(WALK + EAST_WALK):
        m.add_state(unit(k), pose, (), step=k, ranges=cast(HOUSE_1, pose))
    memory = Memory({"h1-e000": m}, threshold=0.05)
    states = [AbstractState(NO_MATCH, pose, (), cast(HOUSE_2, pose))  # no match in there
              for pose in EAST_WALK * 2]
    states += [AbstractState(unit(k), pose, (), cast(HOUSE_2, pose))
               for k, pose in enumerate(WALK)]
    for check, merged in ((False, True), (True, False)):
        rel = Relocalizer(memory, RelocationConfig(merge_check=check, recent_scans=8))
        assert run(rel, states) is not None
        assert (rel.mergeable() is not None) is merged
    assert rel.final["h1-e000"].reason in ("geometry", "conflict")
    assert any(k.startswith("merge refused") for k in rel.decisions)


def test_the_whole_episode_confirms_a_right_match_and_refines_it():
    T_true = (2.0, -1.0, 0.7)
    memory = Memory({"a-e000": stored_model()}, threshold=0.05)
    rel = Relocalizer(memory)
    assert run(rel, episode_states(ROOM_A, T_true)) is not None
    r = rel.mergeable()
    assert r is not None and rel.final["a-e000"].ok
    assert math.dist(r.transform[:2], T_true[:2]) < 0.05


def _episode_model(states, model_id="a-e001") -> AbstractModel:
    m = AbstractModel(DIM, model_id=model_id, extractor="toy", scan=SCAN)
    for k, st in enumerate(states):
        m.add_state(st.features, st.pose, (), step=k, ranges=st.ranges)
    return m


def test_an_episode_that_never_relocated_is_merged_if_the_whole_episode_fits():
    """Only one state of the episode matches a stored one (one match never confirms a
    relocation while navigating); at its end the whole episode is judged against the match's
    transform, fits, and is merged (a late match) in the right frame."""
    T_true = (2.0, -1.0, 0.7)
    memory = Memory({"a-e000": stored_model()}, threshold=0.05)
    states = episode_states(ROOM_A, T_true)
    states = [AbstractState(s.features if k == 3 else NO_MATCH, s.pose, (), s.ranges)
              for k, s in enumerate(states)]
    rel = Relocalizer(memory)
    assert run(rel, states) is None
    assert rel.mergeable() is None  # without the episode's model: nothing to look at
    r = rel.mergeable(_episode_model(states))
    assert r is not None and r.late and r.model_id == "a-e000"
    assert math.dist(r.transform[:2], T_true[:2]) < 0.05
    assert rel.decisions["late match"] == 1
    off = Relocalizer(memory, RelocationConfig(late_match=False))
    run(off, states)
    assert off.mergeable(_episode_model(states)) is None


def test_a_late_match_into_another_house_is_refused():
    """The look-alike room of another house, matched from the whole episode: refused too."""
    m = AbstractModel(DIM, model_id="h1-e000", extractor="toy", scan=SCAN)
    for k, pose in enumerate(WALK + EAST_WALK):
        m.add_state(unit(k), pose, (), step=k, ranges=cast(HOUSE_1, pose))
    memory = Memory({"h1-e000": m}, threshold=0.05)
    states = [AbstractState(NO_MATCH, pose, (), cast(HOUSE_2, pose)) for pose in EAST_WALK * 2]
    states += [AbstractState(unit(k) if k == 2 else NO_MATCH, pose, (), cast(HOUSE_2, pose))
               for k, pose in enumerate(WALK)]
    rel = Relocalizer(memory)
    assert run(rel, states) is None
    assert rel.mergeable(_episode_model(states)) is None
    assert rel.decisions["late match"] == 0
    assert sum(n for k, n in rel.decisions.items() if k.startswith("episode match refused"))


def test_a_room_of_the_same_shape_with_other_furniture_is_not_merged():
    """Another house's room of exactly room A's shape: the geometry fits the whole episode, but
    where the memory has a chair and a bed the episode saw a toilet and a sink (each twice):
    not merged. The same episode with room A's furniture is."""
    chair, bed = Detection("chair", (1.0, 3.0, 0.5)), Detection("bed", (5.0, 3.0, 0.5))
    memory = Memory({"a-e000": stored_model(objects=(chair, bed, Detection("sofa", (3, 1, 0.4))))},
                    threshold=0.05)
    T_true = (2.0, -1.0, 0.7)
    inv = se2.inverse(T_true)
    for furniture, merged in ((("toilet", "sink", "bathtub"), False),
                              (("chair", "bed", "sofa"), True)):
        where = [(1.0, 3.0), (5.0, 3.0), (3.0, 1.0)]
        dets = tuple(Detection(c, (*se2.apply_to_point(inv, *p), 0.5))
                     for c, p in zip(furniture, where, strict=True))
        states = [AbstractState(st.features, st.pose, dets, st.ranges)
                  for st in episode_states(ROOM_A, T_true)]
        rel = Relocalizer(memory, RelocationConfig(verify_checks=0))  # no undo on the way
        assert run(rel, states) is not None
        episode = AbstractModel(DIM, model_id="b-e000", extractor="toy", scan=SCAN)
        for k, st in enumerate(states):
            episode.add_state(st.features, st.pose, st.detections, step=k, ranges=st.ranges)
        assert rel.object_support(episode, "a-e000", T_true) == (3, 3 if merged else 0)
        assert (rel.mergeable(episode) is not None) is merged
        if not merged:
            assert rel.decisions["merge refused: objects"] == 1
            off = Relocalizer(memory, RelocationConfig(verify_checks=0, merge_objects=0,
                                                       absence_views=0))
            run(off, states)
            assert off.mergeable(episode) is not None  # geometry alone would merge it


def test_walls_alone_must_fit_better_than_walls_with_furniture():
    """A room 0.4 m narrower than room A (another house's, of nearly its shape) fits the
    whole episode at about 0.85 inliers: with no object to weigh, that is below
    ``bare_inliers`` and not merged (look-alike rooms of two houses fit so); the same fit with
    three objects each finding its class where the memory has it is merged."""
    narrow = [((0, 0), (5.6, 0)), ((5.6, 0), (5.6, 4)), ((5.6, 4), (0, 4)), ((0, 4), (0, 0)),
              ((2, 4), (2, 2.5))]
    furniture = [("chair", (1.0, 3.0)), ("bed", (5.0, 3.0)), ("sofa", (3.0, 1.0))]
    T_true = (2.0, -1.0, 0.7)
    inv = se2.inverse(T_true)
    for furnished in (False, True):
        stored = tuple(Detection(c, (*p, 0.5)) for c, p in furniture) if furnished else ()
        memory = Memory({"a-e000": stored_model(objects=stored)}, threshold=0.05)
        dets = tuple(Detection(c, (*se2.apply_to_point(inv, *p), 0.5))
                     for c, p in furniture) if furnished else ()
        states, episode = _furnished([AbstractState(unit(k), se2.compose(inv, w), (),
                                                    cast(narrow, w))
                                      for k, w in enumerate(WALK)], dets, "b-e000")
        rel = Relocalizer(memory, RelocationConfig(verify_checks=0))
        assert run(rel, states) is not None
        r = rel.mergeable(episode)
        fit = rel.final["a-e000"]
        assert 0.75 < fit.inliers < RelocationConfig().bare_inliers
        assert (r is not None) is furnished
        if not furnished:
            assert rel.decisions["merge refused: walls only"] == 1
            lax = Relocalizer(memory, RelocationConfig(verify_checks=0, bare_inliers=0.0))
            run(lax, states)
            assert lax.mergeable(episode) is not None


def _furnished(states, dets, model_id):
    states = [AbstractState(st.features, st.pose, dets, st.ranges) for st in states]
    episode = AbstractModel(DIM, model_id=model_id, extractor="toy", scan=SCAN)
    for k, st in enumerate(states):
        episode.add_state(st.features, st.pose, st.detections, step=k, ranges=st.ranges)
    return states, episode


def test_furniture_where_the_memory_saw_the_floor_empty_is_evidence_of_absence():
    """Another house's room of room A's shape, its chair and bed standing where the memory's
    states looked and saw nothing (and the memory's own chair and bed where the episode looked
    and saw nothing): too few objects land near a stored one for the class check to judge,
    but the objects absent on both sides refuse the merge. The same room with the
    memory's furniture in place is merged, and without the check the other would be."""
    # each place below is in view of at least three of the walk's states
    chair, bed = Detection("chair", (3.0, 1.0, 0.5)), Detection("bed", (1.5, 1.5, 0.5))
    memory = Memory({"a-e000": stored_model(objects=(chair, bed))}, threshold=0.05)
    T_true = (2.0, -1.0, 0.7)
    inv = se2.inverse(T_true)
    for where, merged in (([(3.0, 3.0), (4.2, 1.2)], False), ([(3.0, 1.0), (1.5, 1.5)], True)):
        dets = tuple(Detection(c, (*se2.apply_to_point(inv, *p), 0.5))
                     for c, p in zip(("chair", "bed"), where, strict=True))
        states, episode = _furnished(episode_states(ROOM_A, T_true), dets, "b-e000")
        rel = Relocalizer(memory, RelocationConfig(verify_checks=0))
        assert run(rel, states) is not None
        checked, supported = rel.object_support(episode, "a-e000", T_true)
        absent = rel.object_absence(episode, "a-e000", T_true)
        if merged:
            assert (checked, supported, absent) == (2, 2, 0)
            assert rel.mergeable(episode) is not None
            continue
        # too few land near a stored object for the class check; absent: two of the
        # episode's objects and two of the memory's ...
        assert checked < RelocationConfig().merge_objects and supported == 0 and absent == 4
        # ... and with absent_if="empty" only the episode's chair and the memory's bed: the
        # episode's bed lands 1.2 m from the memory's chair, so each side saw something there
        empty = Relocalizer(memory, RelocationConfig(verify_checks=0, absent_if="empty"))
        assert empty.object_absence(episode, "a-e000", T_true) == 2
        assert rel.mergeable(episode) is None
        assert rel.decisions["merge refused: objects absent"] == 1
        off = Relocalizer(memory, RelocationConfig(verify_checks=0, absence_views=0))
        run(off, states)
        assert off.mergeable(episode) is not None
        # a place seen from fewer states than absence_views says nothing
        few = Relocalizer(memory, RelocationConfig(verify_checks=0, absence_views=10_000))
        assert few.object_absence(episode, "a-e000", T_true) == 0


@pytest.mark.parametrize("elsewhere", [True, False])
def test_a_relocation_is_undone_when_its_objects_are_absent(elsewhere):
    """While navigating, the re-verification every reverify_interval steps also weighs the
    evidence of absence with the episode's model so far: furniture standing where the
    memory saw none undoes the relocation (a wrong house's goals are not there); furniture
    where the memory has it keeps it."""
    chair, bed = Detection("chair", (3.0, 1.0, 0.5)), Detection("bed", (1.5, 1.5, 0.5))
    memory = Memory({"a-e000": stored_model(objects=(chair, bed))}, threshold=0.05)
    T_true = (2.0, -1.0, 0.7)
    inv = se2.inverse(T_true)
    where = [(3.0, 3.0), (4.2, 1.2)] if elsewhere else [(3.0, 1.0), (1.5, 1.5)]
    dets = tuple(Detection(c, (*se2.apply_to_point(inv, *p), 0.5))
                 for c, p in zip(("chair", "bed"), where, strict=True))
    states, episode = _furnished(episode_states(ROOM_A, T_true), dets, "b-e000")
    rel = Relocalizer(memory, RelocationConfig(verify_checks=0))
    r = run(rel, states)
    assert r is not None
    step = r.step + rel.config.reverify_interval
    quiet = AbstractState(states[-1].features, states[-1].pose, (), states[-1].ranges)
    assert rel.check(quiet, step) is True  # without the episode's model: nothing to weigh
    assert rel.check(quiet, step, episode) is not elsewhere
    assert rel.decisions["undone by absence"] == int(elsewhere)


@pytest.mark.parametrize("absent_if", ["empty", "class"])
def test_a_confusion_where_the_memory_has_furniture_is_no_absence(absent_if):
    """The right relocation, but the segmenter names the furniture differently from the
    memory (its chair a stool, its bed a sofa, as a segmenter's confusions do). With
    ``absent_if="empty"`` the memory saw furniture right there, no evidence that the alignment
    is wrong, and the standing relocation stays; with the default ``"class"`` the confusions
    are absences and undo it (as they undid right relocations on kgnav's train houses)."""
    chair, bed = Detection("chair", (3.0, 1.0, 0.5)), Detection("bed", (1.5, 1.5, 0.5))
    memory = Memory({"a-e000": stored_model(objects=(chair, bed))}, threshold=0.05)
    T_true = (2.0, -1.0, 0.7)
    inv = se2.inverse(T_true)
    dets = tuple(Detection(c, (*se2.apply_to_point(inv, *p), 0.5))
                 for c, p in (("stool", (3.1, 1.1)), ("sofa", (1.6, 1.4))))
    states, episode = _furnished(episode_states(ROOM_A, T_true), dets, "b-e000")
    config = RelocationConfig(verify_checks=0, absent_if=absent_if)
    rel = Relocalizer(memory, config)
    r = run(rel, states)
    assert r is not None
    assert rel.object_absence(episode, "a-e000", T_true) == (0 if absent_if == "empty" else 4)
    step = r.step + config.reverify_interval
    quiet = AbstractState(states[-1].features, states[-1].pose, (), states[-1].ranges)
    assert rel.check(quiet, step, episode) is (absent_if == "empty")
    assert rel.decisions["undone by absence"] == int(absent_if == "class")


def test_absent_if_takes_a_known_rule():
    with pytest.raises(ValueError, match="absent_if must be one of"):
        RelocationConfig(absent_if="anything")


@pytest.mark.parametrize("walls", [ROOM_A, ROOM_B])
def test_cast_profiles_see_the_walls(walls):
    r = cast(walls, (2.5, 1.0, 0.0))
    assert (r < SCAN.max_range).all() and r.min() > 0.5


@pytest.mark.parametrize("per_model", [1, 2])
def test_a_look_alike_place_nearer_in_feature_space_does_not_hide_the_right_one(per_model):
    """Each place of the stored room has a look-alike elsewhere in the same model, nearer in
    feature space to what the episode sees than the right place is. With one hypothesis per
    model a step, the look-alike is all the relocalizer ever judges (and refuses); with two,
    the right place is judged too and the episode relocates where it truly is."""
    def mix(k: int, w: float) -> np.ndarray:
        v = unit(k) + w * unit(k + 1)
        return (v / np.linalg.norm(v)).astype(np.float32)

    T_true = (2.0, -1.0, 0.7)
    m = stored_model()
    for k, (x, y, t) in enumerate(WALK):  # the look-alikes: 1.5 m along the room, same heading
        decoy = (x + 1.5 if x < 3 else x - 1.5, 4.0 - y, t)
        m.add_state(mix(k, 0.12), decoy, (), step=100 + k, ranges=cast(ROOM_A, decoy))
    memory = Memory({"a-e000": m}, threshold=0.05)
    inv = se2.inverse(T_true)
    states = [AbstractState(mix(k, 0.1), se2.compose(inv, w), (), cast(ROOM_A, w))
              for k, w in enumerate(WALK)]
    for s in states:  # the look-alike is the nearest stored state, the right one the next
        near = [m.graph.nodes[n.state_id]["step"] for n in memory.nearest(s.features, 2)]
        assert near[0] >= 100 > near[1]
    rel = Relocalizer(memory, RelocationConfig(per_model=per_model))
    r = run(rel, states)
    if per_model == 1:
        assert r is None and rel.decisions["verified"] == 0
        return
    assert r is not None and r.model_id == "a-e000"
    assert math.dist(r.transform[:2], T_true[:2]) < 0.05


def test_per_model_takes_at_least_one():
    with pytest.raises(ValueError, match="per_model"):
        RelocationConfig(per_model=0)


# ---------------------------------------------------------------------- the scan search
def _walls_points(walls, step=0.05) -> np.ndarray:
    pts = []
    for (ax, ay), (bx, by) in walls:
        n = max(int(math.hypot(bx - ax, by - ay) / step), 1)
        t = np.linspace(0, 1, n + 1)[:, None]
        pts.append(np.array([ax, ay]) + t * np.array([bx - ax, by - ay]))
    return np.concatenate(pts)


@pytest.mark.parametrize("T_true", [(2.0, -1.0, 0.7), (-3.0, 4.0, -2.5), (0.3, 0.2, 3.0)])
def test_the_scan_search_places_the_walls_where_they_are(T_true):
    """The stored room's own walls, seen from a frame turned and shifted by ``T_true``, are
    placed back by the coarse search within a cell and a heading step."""
    from kgnav.agent.scan_search import distinct, search

    memory = Memory({"a-e000": stored_model()}, threshold=0.05)
    geo = memory.geometry("a-e000")
    ends = se2.apply_to_points(se2.inverse(T_true), _walls_points(ROOM_A))
    found = distinct(search(geo, ends))
    best = found[0].transform
    off = se2.apply_to_points(best, ends) - se2.apply_to_points(T_true, ends)
    assert np.hypot(off[:, 0], off[:, 1]).max() < 0.35  # where the walls land, not T itself:
    assert se2.angle_diff(best[2], T_true[2]) < math.radians(6)  # a turn far from the frame's
    # origin moves T a lot
    assert found[0].score > 0.6
    assert all(q.score < found[0].score for q in found[1:])  # the stub tells the turn apart


def test_distinct_keeps_only_placements_elsewhere():
    from kgnav.agent.scan_search import Placement, distinct

    qs = [Placement((0.0, 0.0, 0.0), 0.9), Placement((0.5, 0.0, 0.1), 0.8),
          Placement((0.0, 0.0, 1.0), 0.7), Placement((2.0, 0.0, 0.0), 0.6)]
    assert [q.score for q in distinct(qs)] == [0.9, 0.7, 0.6]


def test_the_scan_search_of_an_empty_model_finds_nothing():
    from kgnav.agent.relocation import StoredGeometry
    from kgnav.agent.scan_search import search
    from kgnav.memory.geometry import OccupancyGrid

    grid = OccupancyGrid(np.ones((20, 20), np.uint16), np.zeros((20, 20), np.uint16),
                         0.0, 0.0, 0.05)
    assert search(StoredGeometry(grid), np.ones((10, 2))) == []
    assert search(StoredGeometry(grid), np.zeros((0, 2))) == []


SEARCH = dict(scan_search=4, search_scans=6)


def _unmatched_walk(walls, T_true, laps=3):
    """The walk ``laps`` times over, with features that match no stored state: only the
    walls can tell where the episode is."""
    inv = se2.inverse(T_true)
    return [AbstractState(NO_MATCH, se2.compose(inv, w), (), cast(walls, w))
            for _ in range(laps) for w in WALK]


@pytest.mark.parametrize("interval", [0, 4])
def test_the_scan_search_relocates_where_no_stored_state_looks_alike(interval):
    T_true = (2.0, -1.0, 0.7)
    memory = Memory({"a-e000": stored_model()}, threshold=0.05)
    rel = Relocalizer(memory, RelocationConfig(**{**SEARCH, "scan_search": interval}))
    r = run(rel, _unmatched_walk(ROOM_A, T_true))
    if interval == 0:  # feature matching alone never proposes anything
        assert r is None and rel.decisions["verified"] == 0
        return
    assert r is not None and r.model_id == "a-e000" and r.source == "scan search"
    assert r.state_id == "" and math.isnan(r.distance)
    assert math.dist(r.transform[:2], T_true[:2]) < 0.05
    assert se2.angle_diff(r.transform[2], T_true[2]) < math.radians(2)
    assert rel.decisions["scan search accepted"] == 1


def test_the_scan_search_does_not_relocate_into_another_house():
    memory = Memory({"a-e000": stored_model()}, threshold=0.05)
    rel = Relocalizer(memory, RelocationConfig(**SEARCH))
    assert run(rel, _unmatched_walk(ROOM_B, (0.5, 0.0, 0.3))) is None
    assert rel.decisions["scan search"] >= 1 and rel.decisions["scan search accepted"] == 0


def test_the_scan_search_proposes_nothing_in_a_symmetric_room():
    """A bare rectangle fits its walls turned half round as well as the right way: two
    placements fit about as well, so no hypothesis (a rotated twin must not be merged)."""
    bare = ROOM_A[:4]
    memory = Memory({"a-e000": stored_model(walls=bare)}, threshold=0.05)
    rel = Relocalizer(memory, RelocationConfig(**SEARCH))
    assert run(rel, _unmatched_walk(bare, (2.0, -1.0, 0.7))) is None
    assert rel.decisions["scan search ambiguous"] >= 1
    assert rel.decisions["scan search accepted"] == 0


@pytest.mark.parametrize("late_search", [0, 2])
def test_the_late_search_merges_an_episode_no_state_matched(late_search):
    """No state of the episode matches a stored one, so neither navigation nor the late
    match's feature votes propose anything; the search of the whole episode's walls does."""
    T_true = (2.0, -1.0, 0.7)
    memory = Memory({"a-e000": stored_model()}, threshold=0.05)
    states = _unmatched_walk(ROOM_A, T_true, laps=1)
    rel = Relocalizer(memory, RelocationConfig(late_search=late_search))
    assert run(rel, states) is None
    r = rel.mergeable(_episode_model(states))
    if late_search == 0:
        assert r is None
        return
    assert r is not None and r.late and r.model_id == "a-e000"
    assert math.dist(r.transform[:2], T_true[:2]) < 0.05
    assert rel.decisions["late search"] == 1 and rel.decisions["late match"] == 1


def _furnished_room(T_true, furnished: bool):
    """The stored room with a bed, a chair and a monitor (or bare), and those three objects
    as an episode whose frame maps into the room's by ``T_true`` sees them (or none)."""
    spots = [(1.0, 1.0, 0.5), (5.0, 1.0, 0.5), (5.0, 3.0, 0.5)]
    classes = ("bed", "chair", "tv_monitor")
    inv = se2.inverse(T_true)
    seen = tuple(Detection(c, (*se2.apply_to_point(inv, x, y), z))
                 for c, (x, y, z) in zip(classes, spots, strict=True))
    stored = stored_model(objects=tuple(
        Detection(c, p) for c, p in zip(classes, spots, strict=True)) if furnished else ())
    return Memory({"a-e000": stored}, threshold=0.05), seen if furnished else ()


@pytest.mark.parametrize("support", [0, 3, 4])
def test_search_support_holds_for_the_late_search_too(support):
    """The late search's placements are the walls' alone, as a live scan search's are:
    with ``search_support`` the merge asks as many of the episode's objects to find their
    class there (three do in the furnished room, none in the bare one)."""
    T_true = (2.0, -1.0, 0.7)
    for furnished in (True, False):
        memory, seen = _furnished_room(T_true, furnished)
        states = _unmatched_walk(ROOM_A, T_true, laps=1)
        episode = AbstractModel(DIM, model_id="a-e001", extractor="toy", scan=SCAN)
        for k, s in enumerate(states):
            episode.add_state(s.features, s.pose, seen, step=k,
                              ranges=s.ranges)
        rel = Relocalizer(memory, RelocationConfig(late_search=2, search_support=support))
        assert run(rel, states) is None
        r = rel.mergeable(episode)
        stands = support <= (3 if furnished else 0)
        assert (r is not None) is stands, (furnished, support)
        if stands:
            assert r.late and math.dist(r.transform[:2], T_true[:2]) < 0.05
        else:
            assert rel.decisions["episode match refused: search unsupported"] >= 1


@pytest.mark.parametrize("search_inliers", [0.0, 0.95])
def test_search_inliers_asks_the_walls_to_fit_as_a_room_fits_itself(search_inliers):
    """The episode's room is the stored one with a 0.3 m pillar the memory never saw: its
    walls fit at 0.93, verified (min_inliers 0.75) but not as well as a room fits itself,
    which is all a scan search's hypothesis has to go on. With search_inliers 0.95 it is
    refused."""
    T_true = (2.0, -1.0, 0.7)
    x, y, a = 4.3, 1.8, 0.3
    pillar = [((x, y), (x + a, y)), ((x + a, y), (x + a, y + a)),
              ((x + a, y + a), (x, y + a)), ((x, y + a), (x, y))]
    memory = Memory({"a-e000": stored_model()}, threshold=0.05)
    rel = Relocalizer(memory, RelocationConfig(search_inliers=search_inliers, **SEARCH))
    r = run(rel, _unmatched_walk(ROOM_A + pillar, T_true))
    if search_inliers == 0:
        assert r is not None and r.source == "scan search" and 0.9 < r.inliers < 0.95
        assert math.dist(r.transform[:2], T_true[:2]) < 0.05
    else:
        assert r is None and rel.decisions["scan search walls only"] >= 1
    states = _unmatched_walk(ROOM_A + pillar, T_true, laps=1)  # the late search's, too
    late = Relocalizer(memory, RelocationConfig(late_search=2, search_inliers=search_inliers))
    assert run(late, states) is None
    r = late.mergeable(_episode_model(states))
    assert (r is not None) is (search_inliers == 0)
    if r is None:
        assert late.decisions["episode match refused: search walls only"] >= 1


def _look_alike_walk(walls, T_true, w: float | None, laps=3):
    """The walk ``laps`` times over, each view looking like the stored state where it stands
    at cosine distance ``1 - 1/sqrt(1 + w**2)`` (0.106 for w = 0.5: beyond the threshold,
    so no feature match), or (``w`` None) like none of them (0.646)."""
    inv = se2.inverse(T_true)
    out = []
    for _ in range(laps):
        for k, pose in enumerate(WALK):
            f = NO_MATCH if w is None else unit(k) + w * unit(k + 1)
            f = (f / np.linalg.norm(f)).astype(np.float32)
            out.append(AbstractState(f, se2.compose(inv, pose), (), cast(walls, pose)))
    return out


def test_appearance_compares_each_view_with_the_stored_states_where_it_stands():
    T_true = (2.0, -1.0, 0.7)
    memory = Memory({"a-e000": stored_model()}, threshold=0.05)
    rel = Relocalizer(memory, RelocationConfig())
    run(rel, _look_alike_walk(ROOM_A, T_true, 0.5, laps=1))
    look, views = rel.appearance("a-e000", T_true)
    assert views == len(WALK) and look == pytest.approx(1 - 1 / math.sqrt(1.25), abs=1e-3)
    assert rel.appearance("a-e000", (T_true[0] + 20, T_true[1], T_true[2])) == (None, 0)
    turned = rel.appearance("a-e000", (*T_true[:2], T_true[2] + math.pi))
    assert turned[1] < views  # a view facing the other way is not compared
    far = Relocalizer(memory, RelocationConfig())
    run(far, _look_alike_walk(ROOM_A, T_true, None, laps=1))
    assert far.appearance("a-e000", T_true)[0] == pytest.approx(1 - 1 / math.sqrt(DIM), abs=1e-3)


@pytest.mark.parametrize("w, search_look, stands", [
    (0.5, 0.0, True), (0.5, 3.0, True), (None, 3.0, False), (None, 0.0, True)])
def test_search_look_asks_the_place_to_look_like_what_the_memory_saw_there(w, search_look,
                                                                           stands):
    """The walls fit in both cases; with ``search_look`` the scan search's placement must
    also look like the stored states there, within 3 x the threshold (0.15): views at
    0.106 from them do, views like none of them (0.646: a room of that shape elsewhere)
    do not. The same holds for the late search at the episode's end."""
    T_true = (2.0, -1.0, 0.7)
    memory = Memory({"a-e000": stored_model()}, threshold=0.05)
    rel = Relocalizer(memory, RelocationConfig(search_look=search_look, **SEARCH))
    r = run(rel, _look_alike_walk(ROOM_A, T_true, w))
    assert (r is not None) is stands
    if stands:
        assert r.source == "scan search" and r.look is not None and r.look_views >= 3
        assert math.dist(r.transform[:2], T_true[:2]) < 0.05
    else:
        assert rel.decisions["scan search unlike"] >= 1
    states = _look_alike_walk(ROOM_A, T_true, w, laps=1)
    late = Relocalizer(memory, RelocationConfig(late_search=2, search_look=search_look))
    assert run(late, states) is None
    r = late.mergeable(_episode_model(states))
    assert (r is not None) is stands
    if not stands:
        assert late.decisions["episode match refused: search unlike"] >= 1


def test_the_late_search_does_not_merge_another_house():
    m = AbstractModel(DIM, model_id="h1-e000", extractor="toy", scan=SCAN)
    for k, pose in enumerate(WALK + EAST_WALK):
        m.add_state(unit(k), pose, (), step=k, ranges=cast(HOUSE_1, pose))
    memory = Memory({"h1-e000": m}, threshold=0.05)
    states = [AbstractState(NO_MATCH, pose, (), cast(HOUSE_2, pose))
              for pose in EAST_WALK * 2 + WALK]
    rel = Relocalizer(memory, RelocationConfig(late_search=2, **SEARCH))
    # while navigating, the narrow room's walls fit house 1's wide one shifted (its far
    # wall and its pillar): a look-alike, accepted as feature matches in look-alikes are ...
    run(rel, states)
    # ... and refused at the end, when the whole episode is judged, however proposed
    assert rel.mergeable(_episode_model(states)) is None
    assert rel.decisions["late match"] == 0 and rel.decisions["merge refused: conflict"] == 1
    late = Relocalizer(memory, RelocationConfig(late_search=2))  # never relocated
    assert run(late, states) is None
    assert late.mergeable(_episode_model(states)) is None
    assert late.decisions["late search"] == 1 and late.decisions["late match"] == 0


@pytest.mark.parametrize("classes", [("bed", "chair", "tv_monitor"), ("sofa", "toilet", "plant")])
def test_a_scan_search_hypothesis_the_objects_contradict_is_not_accepted(classes):
    """The walls fit (the same room shape), but where the stored model has a bed, a chair and
    a monitor the episode sees a sofa, a toilet and a plant, each twice: another house's room
    of the same shape. The scan search's hypothesis is refused before it is accepted; with
    the same furniture it is accepted."""
    T_true = (2.0, -1.0, 0.7)
    spots = [(1.0, 1.0, 0.5), (5.0, 1.0, 0.5), (5.0, 3.0, 0.5)]
    stored = stored_model(objects=tuple(
        Detection(c, p) for c, p in zip(("bed", "chair", "tv_monitor"), spots, strict=True)))
    memory = Memory({"a-e000": stored}, threshold=0.05)
    inv = se2.inverse(T_true)
    seen = tuple(Detection(c, (*se2.apply_to_point(inv, x, y), z))
                 for c, (x, y, z) in zip(classes, spots, strict=True))
    states = [AbstractState(s.features, s.pose, seen, s.ranges)
              for s in _unmatched_walk(ROOM_A, T_true)]
    episode = AbstractModel(DIM, model_id="a-e001", extractor="toy", scan=SCAN)
    for k, s in enumerate(states[:2]):  # each object seen twice already
        episode.add_state(s.features, s.pose, seen, step=k, ranges=s.ranges)
    rel = Relocalizer(memory, RelocationConfig(**SEARCH))
    got = None
    for step, s in enumerate(states):
        got = rel.observe(step, s, SCAN, episode) or got
    if classes[0] == "bed":
        assert got is not None and got.source == "scan search"
        assert rel.decisions["scan search refuted by objects"] == 0
    else:
        assert got is None and rel.decisions["scan search refuted by objects"] >= 1


def test_a_model_whose_scan_search_relocation_was_undone_is_not_searched_again():
    T_true = (2.0, -1.0, 0.7)
    spots = [(1.0, 1.0, 0.5), (5.0, 1.0, 0.5), (5.0, 3.0, 0.5)]
    stored = stored_model(objects=tuple(
        Detection(c, p) for c, p in zip(("bed", "chair", "tv_monitor"), spots, strict=True)))
    memory = Memory({"a-e000": stored}, threshold=0.05)
    inv = se2.inverse(T_true)
    wrong = tuple(Detection(c, (*se2.apply_to_point(inv, x, y), z))
                  for c, (x, y, z) in zip(("sofa", "toilet", "plant"), spots, strict=True))
    states = [AbstractState(s.features, s.pose, wrong, s.ranges)
              for s in _unmatched_walk(ROOM_A, T_true, laps=6)]
    rel = Relocalizer(memory, RelocationConfig(**SEARCH))
    accepted = undone = None
    for step, s in enumerate(states):
        if rel.relocation is not None:
            if not rel.check(s, step):
                undone = step
        elif rel.observe(step, s, SCAN) is not None:
            accepted = step
        if undone is not None:
            break
    assert accepted is not None and undone is not None  # the landmarks refuted it
    assert rel.decisions["undone by landmarks"] == 1
    searches = rel.decisions["scan search"]
    for step, s in enumerate(states[undone + 1:], undone + 1):
        assert rel.observe(step, s, SCAN) is None
    assert rel.decisions["scan search"] == searches  # the refuted model is searched no more


@pytest.mark.parametrize("support", [0, 3, 4])
def test_search_support_asks_the_episode_objects_for_positive_evidence(support):
    """The same room with the same three objects (each seen twice): three support the scan
    search's hypothesis, so it stands with ``search_support`` up to 3 and waits at 4; in a
    bare room with no object it stands only with 0 (walls alone)."""
    T_true = (2.0, -1.0, 0.7)
    for furnished in (True, False):
        memory, seen = _furnished_room(T_true, furnished)
        states = [AbstractState(s.features, s.pose, seen, s.ranges)
                  for s in _unmatched_walk(ROOM_A, T_true)]
        episode = AbstractModel(DIM, model_id="a-e001", extractor="toy", scan=SCAN)
        for k, s in enumerate(states[:2]):
            episode.add_state(s.features, s.pose, s.detections, step=k, ranges=s.ranges)
        rel = Relocalizer(memory, RelocationConfig(search_support=support, **SEARCH))
        got = None
        for step, s in enumerate(states):
            got = rel.observe(step, s, SCAN, episode) or got
        stands = support <= (3 if furnished else 0)
        assert (got is not None) is stands, (furnished, support)


def test_every_hypothesis_judged_in_the_loop_is_kept_with_what_became_of_it():
    """The right room: its hypotheses are logged at the step judged, with the agent's
    position then, and the one taken says "accepted"; a wrong house's are logged refused
    for their geometry, in step with the decision counts."""
    T_true = (2.0, -1.0, 0.7)
    states = episode_states(ROOM_A, T_true)
    rel = Relocalizer(Memory({"a-e000": stored_model()}, threshold=0.05))
    r = run(rel, states)
    assert r is not None
    outcomes = [h[-1] for h in rel.hypotheses]
    assert outcomes.count("accepted") == 1 and outcomes[-1] == "accepted"
    assert len(rel.hypotheses) == sum(rel.decisions[k] for k in
                                      ("verified", "conflict", "geometry", "few points"))
    step, model_id, T, at, source, _ = rel.hypotheses[-1]
    assert (step, model_id, source) == (r.step, "a-e000", "features")
    assert at == pytest.approx(states[step].pose[:2])
    assert T == pytest.approx(r.transform)
    assert all(h[-1] in HYPOTHESIS_OUTCOMES for h in rel.hypotheses)

    wrong = Relocalizer(Memory({"a-e000": stored_model()}, threshold=0.05))
    assert run(wrong, episode_states(ROOM_B, (0.5, 0.0, 0.3))) is None
    got = [h[-1] for h in wrong.hypotheses]
    assert got and set(got) <= {"geometry", "conflict", "few points"}
    assert got.count("conflict") == wrong.decisions["conflict"]
    wrong.reset()
    assert wrong.hypotheses == []


def test_an_ambiguous_hypothesis_is_logged_as_ambiguous():
    m = AbstractModel(DIM, model_id="c-e000", extractor="toy", scan=SCAN)
    for k, pose in enumerate(CORRIDOR_WALK):
        m.add_state(unit(k), pose, (), step=k, ranges=cast(CORRIDOR, pose))
    shift = (1.5, 0.0, 0.0)
    states = [AbstractState(unit(k), se2.compose(shift, pose), (), cast(CORRIDOR, pose))
              for k, pose in enumerate(CORRIDOR_WALK)]
    rel = Relocalizer(Memory({"c-e000": m}, threshold=0.05))
    assert run(rel, states) is None
    assert [h[-1] for h in rel.hypotheses].count("ambiguous") == rel.decisions["ambiguous"] > 0
