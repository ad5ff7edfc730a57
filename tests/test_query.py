import numpy as np
import pytest

from kgnav import AbstractModel, Detection, UnknownClassError, UnknownStateError, query


def _chairs():
    """Six chairs: chair k seen from k+1 states; chair 0 is closest to the origin."""
    m = AbstractModel(feature_dim=8, model_id="chairs")
    rng = np.random.default_rng(0)
    positions = [(1.0, 0.0), (3.0, 0.0), (5.0, 0.0), (7.0, 0.0), (9.0, 0.0), (11.0, 0.0)]
    step = 0
    for k, (x, y) in enumerate(positions):
        for _ in range(k + 1):
            m.add_state(rng.normal(size=8), (float(step), 5.0, 0.0),
                        [Detection("chair", (x, y, 0.5), distance=5.0)])
            step += 1
    return m


def test_ranking_by_distinct_states():
    ranked = query.ranked_objects(_chairs(), "chair")
    assert [o.n_views for o in ranked] == [6, 5, 4, 3, 2, 1]
    assert [o.position[0] for o in ranked] == [11.0, 9.0, 7.0, 5.0, 3.0, 1.0]


def test_goal_is_closest_among_top_five():
    m = _chairs()
    # the least-seen chair (x=1) is closest to the origin but not in the top five
    assert query.goal_point(m, "chair", near=(0.0, 0.0)).position[0] == 3.0
    assert query.goal_point(m, "chair", near=(10.0, 0.0)).position[0] in (9.0, 11.0)
    assert query.goal_point(m, "chair", near=(12.0, 0.0)).position[0] == 11.0
    assert query.goal_point(m, "chair", near=(0.0, 0.0), top_k=6).position[0] == 1.0


def test_goal_absent_and_unknown_class(tiny):
    assert query.goal_point(tiny, "bed") is None
    assert query.ranked_objects(tiny, "bed") == []
    with pytest.raises(UnknownClassError, match="'bedd'"):
        query.goal_point(tiny, "bedd")


def test_visible_from_and_inventory(tiny):
    assert [o.cls for o in query.visible_from(tiny, "s0")] == ["chair"]
    assert query.visible_classes(tiny, "s2") == ["chair", "sofa"]
    inv = query.class_inventory(tiny)
    assert inv == {"chair": {"objects": 1, "views": 3, "max_views": 3},
                   "sofa": {"objects": 1, "views": 1, "max_views": 1}}
    with pytest.raises(UnknownStateError):
        query.visible_from(tiny, "s42")
    assert query.seen_classes(tiny) == {"chair": 3, "sofa": 1}


def test_action_path(tiny):
    assert query.action_path(tiny, "s0", "s2") == ["move_forward", "turn_left"]
    assert query.action_path(tiny, "s1", "s1") == []
    assert query.action_path(tiny, "s2", "s0") is None
    tiny.add_transition("s0", "turn_left", "s2")
    assert query.action_path(tiny, "s0", "s2") == ["turn_left"]


def test_action_path_prefers_most_frequent_action(tiny):
    tiny.add_transition("s0", "turn_right", "s1")
    tiny.add_transition("s0", "turn_right", "s1")
    assert query.action_path(tiny, "s0", "s1") == ["turn_right"]


def test_action_path_replays_in_the_world(world):
    """Following the returned actions from a state's pose reaches the goal state's pose."""
    import math

    from kgnav.common import se2
    from kgnav.memory.synthetic import FORWARD_M, TURN_RAD

    m = world.explore(150, episode=0, seed=4)
    states = list(m.states())
    path = query.action_path(m, states[0], states[-1])
    assert path is not None
    x, y, th = m.pose(states[0])
    for a in path:
        if a == "move_forward":
            x, y = x + FORWARD_M * math.cos(th), y + FORWARD_M * math.sin(th)
        elif a == "turn_left":
            th += TURN_RAD
        elif a == "turn_right":
            th -= TURN_RAD
    gx, gy, gth = m.pose(states[-1])
    # states within the dedup tolerance are one state: allow that much
    assert math.hypot(gx - x, gy - y) < 0.2 and se2.angle_diff(gth, th) < 0.1


def test_summary(tiny):
    info = query.summary(tiny)
    assert info["states"] == 3 and info["objects"] == 2 and info["transitions"] == 2
    assert info["views"] == 4
    assert info["actions"] == {"move_forward": 1, "turn_left": 1}
    assert info["extent"] == {"x": [0.0, 0.25], "y": [0.0, 0.0]}
