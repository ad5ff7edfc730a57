"""Procedural houses, scene files, splits and episodes of the embedded simulator."""

from __future__ import annotations

import json
import math

import pytest

from kgnav.common.classes import OBJECT_CLASSES, OBJECTNAV_CLASSES, STABLE_CLASSES
from kgnav.errors import SceneFileError
from kgnav.sim import (
    SPLITS,
    NavMap,
    episodes_for,
    generate_episodes,
    generate_house,
    load_episodes,
    load_scene,
    load_split,
    save_episodes,
    save_scene,
    scene_to_dict,
)


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("KGNAV_CACHE", str(tmp_path / "cache"))


def test_generation_is_deterministic():
    assert generate_house(42) == generate_house(42)
    assert generate_house(42) != generate_house(43)


@pytest.mark.parametrize("seed", range(0, 60, 3))
def test_house_constraints(seed):
    s = generate_house(seed)
    assert 4 <= len(s.rooms) <= 12
    assert s.width <= 20.0 and s.depth <= 20.0
    kinds = {r.kind for r in s.rooms}
    assert {"living_room", "kitchen", "bedroom", "bathroom"} <= kinds
    for o in s.objects:
        assert o.cls in OBJECT_CLASSES
        assert o.x0 < o.x1 and o.y0 < o.y1 and 0 <= o.bottom < o.top
        room = s.rooms[o.room]
        assert room.x0 <= o.x0 and o.x1 <= room.x1 and room.y0 <= o.y0 and o.y1 <= room.y1
    nav = NavMap.from_scene(s)
    # every room is reachable through doors: each has navigable floor in the main component
    g = s.room_id_grid()
    assert set(g[nav.grid].tolist()) == set(range(len(s.rooms)))
    # objects are placed so that the agent can get within 1 m of (nearly) all of them
    assert len(nav.reachable_objects()) >= 0.95 * len(s.objects)


@pytest.mark.parametrize("n", [4, 12])
def test_forced_room_count(n):
    assert len(generate_house(3, n_rooms=n).rooms) == n


def test_split_layout_and_classes():
    assert len(SPLITS["val-small"]) == 11 and len(SPLITS["train-small"]) == 20
    val = load_split("val-small")
    assert [s.name for s in val] == [f"val-small_{i:02d}" for i in range(11)]
    assert {s.generator for s in val} == {"house-v1"}
    present = set().union(*(s.classes_present() for s in val))
    assert len(present) >= 20
    assert set(OBJECTNAV_CLASSES) <= present and set(STABLE_CLASSES) <= present
    for s in val:  # the goal classes are in every house
        assert {"bed", "toilet", "sofa", "tv_monitor"} <= set(s.classes_present())
    # several instances of a class exist somewhere
    assert any(len(s.objects_of("chair")) > 1 for s in val)
    # the cached copy loads back identical
    assert load_split("val-small") == val


def test_save_load_round_trip(tmp_path):
    s = generate_house(9)
    p = tmp_path / "house.json"
    save_scene(s, p)
    assert load_scene(p) == s
    save_scene(s, p)  # overwriting keeps a valid file
    assert load_scene(p) == s


def _expect_error(path, fragment):
    with pytest.raises(SceneFileError) as e:
        load_scene(path)
    assert str(path) in str(e.value)
    assert fragment in e.value.reason


def test_bad_scene_files_rejected(tmp_path):
    good = scene_to_dict(generate_house(2))
    p = tmp_path / "x.json"
    _expect_error(tmp_path / "missing.json", "not found")
    p.write_bytes(b"\x00\xffgarbage{")
    _expect_error(p, "JSON")
    p.write_text(json.dumps({"format": "kgnav-model", "version": 1}))
    _expect_error(p, "not a kgnav-scene")
    p.write_text(json.dumps([1, 2, 3]))
    _expect_error(p, "not a kgnav-scene")
    p.write_text(json.dumps({**good, "version": 99}))
    _expect_error(p, "version 99")
    bad = dict(good)
    del bad["rooms"]
    p.write_text(json.dumps(bad))
    _expect_error(p, "rooms")
    bad = json.loads(json.dumps(good))
    bad["objects"][0]["cls"] = "unicorn"
    p.write_text(json.dumps(bad))
    _expect_error(p, "unicorn")
    bad = json.loads(json.dumps(good))
    bad["rooms"][0]["x1"] = bad["rooms"][0]["x0"]
    p.write_text(json.dumps(bad))
    _expect_error(p, "empty rectangle")


def test_episodes_deterministic_and_valid(tmp_path):
    s = generate_house(2000)
    eps = generate_episodes(s, 15, seed=1)
    assert eps == generate_episodes(s, 15, seed=1)
    nav = NavMap.from_scene(s)
    for e in eps:
        assert e.goal_class in OBJECTNAV_CLASSES
        assert nav.is_navigable(e.start[0], e.start[1])
        d = nav.geodesic_distance(e.start[0], e.start[1], e.goal_class)
        assert 1.0 <= d <= 30.0 and math.isclose(d, e.geodesic_distance, abs_tol=1e-3)
        # geodesic never shorter than the straight line to the region (1 m band, 5 cm grid)
        assert d >= e.euclidean_distance - 1.0 - 0.1
        assert e.max_steps == 500
    p = tmp_path / "eps.json"
    save_episodes(eps, p, "val", s.name)
    assert load_episodes(p) == eps
    p.write_text(json.dumps({"format": "kgnav-episodes", "version": 2, "episodes": []}))
    with pytest.raises(SceneFileError, match="version"):
        load_episodes(p)


def test_episodes_for_split():
    eps = episodes_for("val", 3, n=5)
    assert len(eps) == 5 and all(e.scene == "val_03" for e in eps)
    assert episodes_for("val", 3, n=5) == eps  # from the cache
    assert episodes_for("val", 3, n=5, cache=False) == eps
    with pytest.raises(ValueError):
        episodes_for("val", 11)
    with pytest.raises(ValueError):
        episodes_for("test", 0)


def test_geodesic_is_fmm_on_navigable_map():
    s = generate_house(5)
    nav = NavMap.from_scene(s)
    f = nav.distance_field("bed")
    assert (f[nav.goal_region("bed")] == 0).all()
    assert not math.isfinite(f[~nav.grid].min())
    # geodesic >= euclidean to the region, for a few cells
    cells = nav.navigable_cells()[::997]
    region = nav.goal_region("bed")
    rc = nav.navigable_cells()[region[nav.grid]]
    for i, j in cells:
        e = min(math.hypot(i - a, j - b) for a, b in rc) * nav.resolution
        assert f[i, j] >= e - 2 * nav.resolution
