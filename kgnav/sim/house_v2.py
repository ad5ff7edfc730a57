"""Matterport3D-scale houses (generator ``house-v2``): 8-30 rooms, corridors, clutter, sparse goals.

The benchmark's question — does a reusable memory find goals faster? — needs houses where the
goal is usually far and not in sight: the first generator (``house-v1``, 4-12 rooms on at most
20 m × 20 m, several instances of every goal class) makes a memory-less agent succeed 80 % of the
time. This one builds what an ObjectNav episode in Matterport3D looks like:

* **Floors up to about 40 m × 40 m** split by binary space partition into 8-30 rooms; a large
  partition cell is often split with a **corridor** (1.3-2 m wide, the whole cell's length)
  between its halves, so rooms open on hallways as in real houses.
* **Doors** on a random spanning tree of adjacent rooms, preferring corridors, plus a few loops;
  some doors between living areas are wide openings (1.4-2.4 m).
* **More room kinds without goal objects** (office, storage, laundry, dining) and a **goal
  budget**: each of the six ObjectNav classes stands in only 1-3 rooms of the house, so the
  nearest instance is often rooms away.
* **Clutter**: free-standing furniture (tables, stools, shelves, cabinets, lamps, ...) in the
  middle of rooms and along corridors, which blocks straight paths while keeping every room's
  floor connected (the same placement checks as ``house-v1``).

The same seed gives the same house. ``house-v1`` stays available (:func:`generate_house`).

>>> scene = generate_large_house(4001)
>>> 8 <= len(scene.rooms) <= 30, scene.generator
(True, 'house-v2')
"""

from __future__ import annotations

import math

import numpy as np

from kgnav.common.classes import OBJECTNAV_CLASSES
from kgnav.sim.house import (
    _CLASS_HUE,
    _PRIORS,
    _SIZES,
    DOOR_WIDTH,
    Door,
    ObjectInstance,
    Room,
    Scene,
    _against_wall,
    _all_rooms_connected,
    _area,
    _free_spot,
    _hsv,
    _Placer,
    _room_style,
    _wall_boxes,
    cut_doors,
    door_tree,
)

GENERATOR_V2 = "house-v2"
MIN_ROOMS, MAX_ROOMS = 8, 30
MAX_SIDE = 40.0  # m
MIN_SIDE = 2.6  # m, smallest room side
CORRIDOR_WIDTH = (1.3, 2.0)  # m
WIDE_OPENING = (1.4, 2.4)  # m, between living areas

#: Rooms each goal class may stand in, per house (drawn uniformly in the range).
GOAL_ROOM_BUDGET: dict[str, tuple[int, int]] = {
    "chair": (1, 3),
    "bed": (1, 2),
    "plant": (1, 3),
    "toilet": (1, 1),
    "tv_monitor": (1, 1),
    "sofa": (1, 1),
}

#: Room kinds beyond the four every house has, with their weights.
_EXTRA_KINDS: tuple[tuple[str, float], ...] = (
    ("bedroom", 0.20),
    ("bathroom", 0.12),
    ("office", 0.16),
    ("storage", 0.16),
    ("laundry", 0.10),
    ("dining_room", 0.10),
    ("hallway", 0.04),
)

#: Object priors of the room kinds ``house-v1`` does not have.
PRIORS_V2: dict[str, tuple[tuple[str, float, tuple[int, int]], ...]] = {
    **_PRIORS,
    "storage": (
        ("cabinet", 0.9, (1, 3)),
        ("bookshelf", 0.6, (1, 2)),
        ("chest_of_drawers", 0.5, (1, 2)),
        ("wardrobe", 0.4, (1, 1)),
    ),
    "laundry": (
        ("washing_machine", 1.0, (1, 2)),
        ("sink", 0.6, (1, 1)),
        ("cabinet", 0.7, (1, 2)),
        ("counter", 0.4, (1, 1)),
    ),
}

#: Free-standing clutter per room kind: classes drawn for the middle of the floor.
CLUTTER: dict[str, tuple[str, ...]] = {
    "bedroom": ("chest_of_drawers", "lamp", "stool", "desk", "bookshelf"),
    "bathroom": ("cabinet", "stool"),
    "kitchen": ("counter", "table", "stool", "cabinet"),
    "living_room": ("table", "lamp", "bookshelf", "stool", "piano", "cabinet"),
    "dining_room": ("cabinet", "lamp", "chest_of_drawers", "table"),
    "office": ("desk", "bookshelf", "cabinet", "lamp"),
    "hallway": ("cabinet", "chest_of_drawers", "lamp", "bookshelf"),
    "storage": ("cabinet", "bookshelf", "chest_of_drawers", "wardrobe"),
    "laundry": ("cabinet", "counter", "washing_machine"),
}
CLUTTER_PER_M2 = 1 / 10.0  # mean free-standing items per square metre of floor


def generate_large_house(seed: int, name: str | None = None, n_rooms: int | None = None,
                         max_side: float = MAX_SIDE) -> Scene:
    """A ``house-v2`` house from ``seed``: ``n_rooms`` rooms (default drawn in 8..30, corridors
    included), floor at most ``max_side`` metres a side. The same arguments give an identical
    :class:`Scene`."""
    rng = np.random.default_rng([seed, 2])
    n = int(rng.integers(MIN_ROOMS, MAX_ROOMS + 1)) if n_rooms is None else int(n_rooms)
    if not MIN_ROOMS <= n <= MAX_ROOMS:
        raise ValueError(f"n_rooms must be in {MIN_ROOMS}..{MAX_ROOMS}, got {n}")
    if not 2 * MIN_SIDE <= max_side <= 100.0:
        raise ValueError(f"max_side must be in {2 * MIN_SIDE}..100 m, got {max_side}")
    scene = None
    for _attempt in range(50):
        scene = _generate(rng, seed, name, n, float(max_side))
        if scene is not None and _all_rooms_connected(scene):
            return scene
    if scene is None:  # pragma: no cover - a floor too small for n rooms every time
        raise ValueError(f"cannot fit {n} rooms on a floor of at most {max_side} m a side")
    return scene  # pragma: no cover - the layout retries practically always succeed


def _generate(rng: np.random.Generator, seed: int, name: str | None, n: int,
              max_side: float) -> Scene | None:
    area = n * rng.uniform(14.0, 30.0)
    aspect = rng.uniform(0.6, 1.7)
    w = min(max(math.sqrt(area * aspect), 3 * MIN_SIDE), max_side)
    d = min(max(area / w, 3 * MIN_SIDE), max_side)
    w, d = round(w * 4) / 4, round(d * 4) / 4
    rects, corridor = _partition(rng, w, d, n)
    if len(rects) < min(n, 4 + sum(corridor)):
        return None
    kinds = _assign_kinds(rng, rects, corridor)
    doors, door_lines = _doors(rng, rects, kinds)
    walls = _wall_boxes(rects, door_lines, rng)
    rooms = []
    for i, (r, k) in enumerate(zip(rects, kinds, strict=True)):
        wall_c, floor_c, wtex, ftex = _room_style(rng, k)
        rooms.append(Room(i, k, *[float(v) for v in r], wall_c, floor_c, wtex, ftex))
    objects = _place_objects(rng, rects, kinds, doors)
    return Scene(name=name or f"house2_{seed}", seed=int(seed), width=float(w), depth=float(d),
                 rooms=tuple(rooms), doors=tuple(doors), walls=tuple(walls),
                 objects=tuple(objects), generator=GENERATOR_V2)


# --------------------------------------------------------------------------- layout
def _partition(rng, w: float, d: float, n: int) -> tuple[list[list[float]], list[bool]]:
    """Split ``[0,w]×[0,d]`` into ``n`` rectangles (corridors included); large cells are often
    split with a corridor band between their halves. Returns (rects, is_corridor)."""
    rects: list[list[float]] = [[0.0, 0.0, w, d]]
    corridor = [False]
    big = 6.0 * MIN_SIDE * MIN_SIDE
    for _ in range(400):
        if len(rects) >= n:
            break
        order = sorted((i for i in range(len(rects)) if not corridor[i]),
                       key=lambda i: -_area(rects[i]) * rng.uniform(0.8, 1.25))
        for i in order:
            x0, y0, x1, y1 = rects[i]
            horiz = (x1 - x0) >= (y1 - y0)
            length = (x1 - x0) if horiz else (y1 - y0)
            if length < 2 * MIN_SIDE:
                continue
            cw = 0.0
            if (_area(rects[i]) > big and length >= 2 * MIN_SIDE + CORRIDOR_WIDTH[1]
                    and len(rects) + 2 <= n and rng.uniform() < 0.6):
                cw = round(float(rng.uniform(*CORRIDOR_WIDTH)) * 20) / 20
            span = length - cw
            cut = min(max(rng.uniform(0.35, 0.65) * span, MIN_SIDE), span - MIN_SIDE)
            cut = round(cut * 4) / 4
            if horiz:
                parts = [[x0, y0, x0 + cut, y1], [x0 + cut, y0, x0 + cut + cw, y1],
                         [x0 + cut + cw, y0, x1, y1]]
            else:
                parts = [[x0, y0, x1, y0 + cut], [x0, y0 + cut, x1, y0 + cut + cw],
                         [x0, y0 + cut + cw, x1, y1]]
            flags = [False, True, False]
            if cw == 0.0:
                parts, flags = [parts[0], parts[2]], [False, False]
            rects[i:i + 1] = parts
            corridor[i:i + 1] = flags
            break
        else:
            break
    return rects, corridor


def _assign_kinds(rng, rects, corridor) -> list[str]:
    """Corridors are hallways; the largest room is the living room, the smallest a bathroom;
    the rest are drawn from :data:`_EXTRA_KINDS` (plus a kitchen and a bedroom) and given out
    by size, with some shuffling: bathrooms and storage rooms tend to be small."""
    n = len(rects)
    kinds = ["hallway" if c else "" for c in corridor]
    rest = sorted((i for i in range(n) if not corridor[i]), key=lambda i: -_area(rects[i]))
    kinds[rest[0]] = "living_room"
    kinds[rest[-1]] = "bathroom"
    middle = rest[1:-1]  # largest first
    names = [k for k, _ in _EXTRA_KINDS]
    p = np.array([wt for _, wt in _EXTRA_KINDS])
    todo = ["kitchen", "bedroom"] + [str(k) for k in rng.choice(names, size=n, p=p / p.sum())]
    todo = todo[:len(middle)]
    todo.sort(key=lambda k: _SIZE_RANK[k] + rng.uniform(0.0, 2.5))
    for i, k in zip(middle, todo, strict=True):
        kinds[i] = k
    return kinds


#: Typical size order of room kinds (smaller rank: larger room).
_SIZE_RANK = {"living_room": 0, "dining_room": 1, "kitchen": 2, "bedroom": 2, "office": 3,
              "hallway": 3, "storage": 4, "laundry": 5, "bathroom": 5}


def _doors(rng, rects, kinds) -> tuple[list[Door], list[tuple]]:
    """A spanning tree of adjacent rooms (corridor links first), a few loops, door openings
    (some wide between living areas)."""
    living = {"living_room", "dining_room", "kitchen", "hallway"}

    def weight(i, j):
        return 0.3 if "hallway" in (kinds[i], kinds[j]) else 1.0

    def width(i, j, span):
        if kinds[i] in living and kinds[j] in living and rng.uniform() < 0.5:
            return min(float(rng.uniform(*WIDE_OPENING)), span - 0.5)
        return DOOR_WIDTH

    return cut_doors(rng, door_tree(rng, rects, weight, loops=0.15), width)


# --------------------------------------------------------------------------- objects
def _door_zones(ri: int, doors) -> list[tuple[float, float, float, float]]:
    zones = []
    for dr in doors:
        if ri in (dr.a, dr.b):  # keep 1 m in front of and behind each doorway clear
            if dr.x1 - dr.x0 < dr.y1 - dr.y0:
                zones.append((dr.x0 - 1.0, dr.y0 - 0.1, dr.x1 + 1.0, dr.y1 + 0.1))
            else:
                zones.append((dr.x0 - 0.1, dr.y0 - 1.0, dr.x1 + 0.1, dr.y1 + 1.0))
    return zones


def _place_objects(rng, rects, kinds, doors) -> list[ObjectInstance]:
    """Room priors under the house's goal budget, then free-standing clutter."""
    budget = {c: int(rng.integers(lo, hi + 1)) for c, (lo, hi) in GOAL_ROOM_BUDGET.items()}
    objects: list[ObjectInstance] = []
    order = [int(i) for i in rng.permutation(len(rects))]  # who gets the goal budget first
    placers = {}
    for ri in order:
        placer = placers[ri] = _Placer(rects[ri], _door_zones(ri, doors), [])
        table = None
        for cls, p, (lo, hi) in PRIORS_V2[kinds[ri]]:
            if rng.uniform() >= p:
                continue
            if budget.get(cls, 1) <= 0:
                continue
            placed = 0
            for _ in range(int(rng.integers(lo, hi + 1))):
                b = _try_place(rng, placer, cls, table)
                if b is not None:
                    objects.append(_instance(rng, len(objects) + 1, cls, ri, b))
                    table = b if cls == "table" else table
                    placed += 1
            if placed and cls in budget:
                budget[cls] -= 1
    # every goal class somewhere: a class whose rooms all failed to fit it gets another room
    homes = {c: [k for k, pri in PRIORS_V2.items() if any(q[0] == c for q in pri)]
             for c in GOAL_ROOM_BUDGET}
    for cls in GOAL_ROOM_BUDGET:
        if any(o.cls == cls for o in objects):
            continue
        for ri in sorted(order, key=lambda r: kinds[r] not in homes[cls]):
            b = _try_place(rng, placers[ri], cls, None)
            if b is not None:
                objects.append(_instance(rng, len(objects) + 1, cls, ri, b))
                break
    for ri in order:
        placer, kind = placers[ri], kinds[ri]
        area = _area(rects[ri])
        for _ in range(int(rng.poisson(area * CLUTTER_PER_M2))):
            cls = str(rng.choice(CLUTTER[kind]))
            b = _try_place(rng, placer, cls, None, free_standing=kind != "hallway")
            if b is not None:
                objects.append(_instance(rng, len(objects) + 1, cls, ri, b))
    assert not set(OBJECTNAV_CLASSES) & {c for k in CLUTTER.values() for c in k}
    return objects


def _try_place(rng, placer: _Placer, cls: str, table, free_standing: bool = False):
    w0, d0, _h0, _bottom, wall = _SIZES[cls]
    s = rng.uniform(0.88, 1.12, size=2)
    w, d = w0 * s[0], d0 * s[1]
    for _attempt in range(25):
        if wall and not free_standing:
            b = _against_wall(rng, placer, w, d)
        else:
            near = table if cls in ("chair", "stool") and table is not None else None
            b = _free_spot(rng, placer, w, d, near)
        b = tuple(round(float(v), 3) for v in b)
        if placer.fits(b):
            placer.add(b)
            return b
    return None


def _instance(rng, oid: int, cls: str, room: int, b) -> ObjectInstance:
    _w0, _d0, h0, bottom, _wall = _SIZES[cls]
    sh = float(rng.uniform(0.88, 1.12))
    hue = _CLASS_HUE[cls] + rng.normal(0, 0.06)
    color = _hsv(hue, rng.uniform(0.35, 0.85), rng.uniform(0.35, 0.95))
    # mounted objects (bottom > 0) keep the bottom and jitter the top
    top = h0 * sh if bottom == 0 else bottom + (h0 - bottom) * sh
    return ObjectInstance(oid, cls, room, *b, float(bottom), round(float(top), 3), color)
