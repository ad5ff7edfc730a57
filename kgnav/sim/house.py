"""Procedural houses: rooms, doors, walls and objects from a seed.

A house is a rectangle split into 4-12 axis-aligned rooms by binary space partition; rooms that
share a long enough wall get doors (a random spanning tree, so every room is reachable, plus a
few extra loops). Walls are thin boxes centred on room boundaries; objects are axis-aligned boxes
(footprint rectangle, bottom and top height) placed by room-type priors. Everything is drawn
from ``numpy.random.default_rng(seed)``: the same seed gives the same house.

>>> from kgnav.sim.house import generate_house
>>> scene = generate_house(7)
>>> 4 <= len(scene.rooms) <= 12
True
"""

from __future__ import annotations

import colorsys
import math

import cv2
import numpy as np

from kgnav.common.classes import OBJECT_CLASSES
from kgnav.sim.navmesh import NavMap
from kgnav.sim.scene import (  # noqa: F401 - re-exported: the scene's types were defined here
    AGENT_RADIUS,
    DOOR_WIDTH,
    GENERATOR,
    GRID_RES,
    ROOM_KINDS,
    WALL_HEIGHT,
    WALL_THICKNESS,
    Door,
    ObjectInstance,
    Room,
    Scene,
    Texture,
    Wall,
    rasterize_box,
)

# --------------------------------------------------------------------------- object priors
# size (along the wall, away from the wall, height), bottom height, placed against a wall?
_SIZES: dict[str, tuple[float, float, float, float, bool]] = {
    "chair": (0.5, 0.5, 0.9, 0.0, False),
    "bed": (1.6, 2.0, 0.6, 0.0, True),
    "plant": (0.45, 0.45, 1.1, 0.0, False),
    "toilet": (0.42, 0.68, 0.78, 0.0, True),
    "tv_monitor": (1.2, 0.12, 1.45, 0.75, True),  # wall-mounted: 0.75 to 1.45 m
    "sofa": (2.0, 0.9, 0.85, 0.0, True),
    "table": (1.4, 0.9, 0.75, 0.0, False),
    "sink": (0.6, 0.5, 0.9, 0.0, True),
    "bathtub": (1.7, 0.75, 0.6, 0.0, True),
    "shower": (0.9, 0.9, 2.0, 0.0, True),
    "cabinet": (0.8, 0.45, 1.0, 0.0, True),
    "chest_of_drawers": (1.0, 0.5, 0.9, 0.0, True),
    "wardrobe": (1.2, 0.6, 2.0, 0.0, True),
    "desk": (1.2, 0.6, 0.75, 0.0, True),
    "bookshelf": (0.9, 0.35, 1.8, 0.0, True),
    "fridge": (0.7, 0.7, 1.8, 0.0, True),
    "stove": (0.6, 0.6, 0.9, 0.0, True),
    "counter": (1.6, 0.6, 0.9, 0.0, True),
    "fireplace": (1.4, 0.4, 1.1, 0.0, True),
    "nightstand": (0.45, 0.4, 0.55, 0.0, True),
    "lamp": (0.35, 0.35, 1.5, 0.0, False),
    "washing_machine": (0.6, 0.6, 0.85, 0.0, True),
    "piano": (1.5, 0.6, 1.2, 0.0, True),
    "stool": (0.35, 0.35, 0.65, 0.0, False),
}

# Per room kind: (class, probability of placing at least one, (min, max) count if placed).
_PRIORS: dict[str, tuple[tuple[str, float, tuple[int, int]], ...]] = {
    "bedroom": (
        ("bed", 1.0, (1, 1)),
        ("nightstand", 0.8, (1, 2)),
        ("wardrobe", 0.7, (1, 1)),
        ("chest_of_drawers", 0.5, (1, 1)),
        ("tv_monitor", 0.3, (1, 1)),
        ("chair", 0.4, (1, 1)),
        ("plant", 0.35, (1, 1)),
        ("lamp", 0.4, (1, 1)),
        ("desk", 0.2, (1, 1)),
    ),
    "bathroom": (
        ("toilet", 1.0, (1, 1)),
        ("sink", 1.0, (1, 2)),
        ("bathtub", 0.5, (1, 1)),
        ("shower", 0.4, (1, 1)),
        ("cabinet", 0.3, (1, 1)),
        ("washing_machine", 0.2, (1, 1)),
        ("plant", 0.2, (1, 1)),
    ),
    "kitchen": (
        ("counter", 1.0, (1, 2)),
        ("fridge", 1.0, (1, 1)),
        ("stove", 1.0, (1, 1)),
        ("sink", 0.9, (1, 1)),
        ("cabinet", 0.6, (1, 2)),
        ("table", 0.5, (1, 1)),
        ("chair", 0.5, (1, 3)),
        ("stool", 0.4, (1, 2)),
        ("washing_machine", 0.3, (1, 1)),
        ("plant", 0.2, (1, 1)),
    ),
    "living_room": (
        ("sofa", 1.0, (1, 2)),
        ("tv_monitor", 1.0, (1, 1)),
        ("table", 0.8, (1, 1)),
        ("plant", 1.0, (1, 2)),
        ("chair", 0.6, (1, 2)),
        ("bookshelf", 0.5, (1, 2)),
        ("fireplace", 0.3, (1, 1)),
        ("lamp", 0.5, (1, 2)),
        ("piano", 0.15, (1, 1)),
        ("cabinet", 0.3, (1, 1)),
    ),
    "dining_room": (
        ("table", 1.0, (1, 1)),
        ("chair", 1.0, (3, 6)),
        ("cabinet", 0.6, (1, 1)),
        ("plant", 0.5, (1, 2)),
        ("lamp", 0.3, (1, 1)),
        ("chest_of_drawers", 0.3, (1, 1)),
    ),
    "office": (
        ("desk", 1.0, (1, 2)),
        ("chair", 1.0, (1, 2)),
        ("bookshelf", 0.8, (1, 2)),
        ("cabinet", 0.5, (1, 1)),
        ("plant", 0.5, (1, 1)),
        ("tv_monitor", 0.4, (1, 1)),
        ("lamp", 0.4, (1, 1)),
    ),
    "hallway": (
        ("plant", 0.5, (1, 2)),
        ("cabinet", 0.3, (1, 1)),
        ("chest_of_drawers", 0.3, (1, 1)),
        ("lamp", 0.3, (1, 1)),
        ("stool", 0.2, (1, 1)),
    ),
}

# Base hue of each class so a class is loosely recognisable by colour; instances vary around it.
_CLASS_HUE = {c: (i * 0.618034) % 1.0 for i, c in enumerate(OBJECT_CLASSES)}


def _hsv(h: float, s: float, v: float) -> tuple[int, int, int]:
    r, g, b = colorsys.hsv_to_rgb(h % 1.0, min(max(s, 0.0), 1.0), min(max(v, 0.0), 1.0))
    return (int(round(r * 255)), int(round(g * 255)), int(round(b * 255)))


# --------------------------------------------------------------------------- layout
def _split_rooms(rng: np.random.Generator, w: float, d: float, n: int) -> list[list[float]]:
    """Binary space partition of ``[0,w]×[0,d]`` into ``n`` rectangles at least 2.4 m wide."""
    rects = [[0.0, 0.0, w, d]]
    min_side = 2.4
    for _ in range(200):
        if len(rects) >= n:
            break
        # split the biggest splittable rectangle along its longer side
        order = sorted(range(len(rects)), key=lambda i: -_area(rects[i]))
        for i in order:
            x0, y0, x1, y1 = rects[i]
            horiz = (x1 - x0) >= (y1 - y0)
            length = (x1 - x0) if horiz else (y1 - y0)
            if length < 2 * min_side:
                continue
            f = rng.uniform(0.35, 0.65)
            cut = min(max(f * length, min_side), length - min_side)
            cut = round(cut * 4) / 4  # quarter-metre grid keeps walls tidy
            if horiz:
                a, b = [x0, y0, x0 + cut, y1], [x0 + cut, y0, x1, y1]
            else:
                a, b = [x0, y0, x1, y0 + cut], [x0, y0 + cut, x1, y1]
            rects[i : i + 1] = [a, b]
            break
        else:
            break
    return rects


def _area(r) -> float:
    return (r[2] - r[0]) * (r[3] - r[1])


def _shared_edge(a, b, eps=1e-6):
    """Shared boundary of two touching rectangles: (axis, coord, lo, hi) or None.

    axis 'x' means the shared wall is the vertical line x = coord, spanning y in [lo, hi].
    """
    if abs(a[2] - b[0]) < eps or abs(b[2] - a[0]) < eps:
        coord = a[2] if abs(a[2] - b[0]) < eps else a[0]
        lo, hi = max(a[1], b[1]), min(a[3], b[3])
        if hi - lo > eps:
            return ("x", coord, lo, hi)
    if abs(a[3] - b[1]) < eps or abs(b[3] - a[1]) < eps:
        coord = a[3] if abs(a[3] - b[1]) < eps else a[1]
        lo, hi = max(a[0], b[0]), min(a[2], b[2])
        if hi - lo > eps:
            return ("y", coord, lo, hi)
    return None


def _assign_kinds(rng: np.random.Generator, rects: list[list[float]]) -> list[str]:
    n = len(rects)
    order = sorted(range(n), key=lambda i: -_area(rects[i]))
    kinds = [""] * n
    # every house has the rooms that hold the six ObjectNav goal classes
    must = ["living_room", "kitchen", "bedroom", "bathroom"]
    extra_pool = ["bedroom", "bathroom", "dining_room", "office", "bedroom", "hallway"]
    # long thin rooms make natural hallways
    for i in range(n):
        x0, y0, x1, y1 = rects[i]
        s, lng = sorted((x1 - x0, y1 - y0))
        if n > 5 and lng / s > 2.3 and "hallway" not in kinds and i != order[0]:
            kinds[i] = "hallway"
    rest = [i for i in order if not kinds[i]]
    # the largest room is the living room; the smallest a bathroom
    kinds[rest[0]] = "living_room"
    kinds[rest[-1]] = "bathroom"
    middle = rest[1:-1]
    rng.shuffle(middle)
    todo = ["kitchen", "bedroom"] + [str(k) for k in rng.choice(extra_pool, size=n)]
    for i, k in zip(middle, todo, strict=False):
        kinds[i] = k
    assert all(k in kinds for k in must), kinds
    return kinds


def _room_style(rng: np.random.Generator, kind: str) -> tuple:
    hue = rng.uniform(0, 1)
    wall = _hsv(hue, rng.uniform(0.08, 0.45), rng.uniform(0.62, 0.95))
    if kind in ("bathroom", "kitchen"):
        floor = _hsv(rng.uniform(0, 1), rng.uniform(0.0, 0.25), rng.uniform(0.6, 0.9))
        ftex = Texture(2, float(rng.choice([0.3, 0.4, 0.6])), float(rng.uniform(0.08, 0.2)))
    else:
        floor = _hsv(rng.uniform(0.05, 0.12), rng.uniform(0.35, 0.7), rng.uniform(0.3, 0.7))
        ftex = Texture(3, float(rng.choice([0.15, 0.2, 0.25])), float(rng.uniform(0.06, 0.15)),
                       float(rng.choice([0.0, 90.0])))
    wkind = int(rng.integers(0, 4))
    wtex = Texture(wkind, float(rng.uniform(0.15, 0.6)), float(rng.uniform(0.05, 0.18)))
    return wall, floor, wtex, ftex


def _wall_boxes(rects, doors_on_lines, rng) -> list[Wall]:
    """Wall boxes along every room boundary, with door intervals cut out, each once."""
    t = WALL_THICKNESS
    walls: list[Wall] = []
    n = len(rects)
    for i in range(n):
        x0, y0, x1, y1 = rects[i]
        sides = [("y", y0, x0, x1), ("y", y1, x0, x1), ("x", x0, y0, y1), ("x", x1, y0, y1)]
        for axis, c, lo, hi in sides:
            pieces = [(lo, hi)]
            # a stretch shared with a lower-numbered room was emitted by that room
            for j in range(i):
                e = _shared_edge(rects[i], rects[j])
                if e and e[0] == axis and abs(e[1] - c) < 1e-6:
                    pieces = _subtract(pieces, e[2], e[3])
            for dl, dc, da, db in doors_on_lines:
                if dl == axis and abs(dc - c) < 1e-6:
                    pieces = _subtract(pieces, da, db)
            for a, b in pieces:
                if b - a < 1e-3:
                    continue
                # extend by half a thickness so corners close; doors are cut after extension
                a2, b2 = a - t / 2, b + t / 2
                for dl, dc, da, db in doors_on_lines:
                    if dl == axis and abs(dc - c) < 1e-6:
                        if abs(b - da) < 1e-6:
                            b2 = b
                        if abs(a - db) < 1e-6:
                            a2 = a
                tint = float(rng.uniform(0.9, 1.08))
                decal = None
                if b2 - a2 > 1.5 and rng.uniform() < 0.6:
                    wd = float(rng.uniform(0.5, min(1.4, b2 - a2 - 0.6)))
                    u0 = float(rng.uniform(a2 + 0.3, b2 - 0.3 - wd))
                    h0 = float(rng.uniform(0.9, 1.4))
                    h1 = h0 + float(rng.uniform(0.4, 0.9))
                    col = _hsv(rng.uniform(0, 1), rng.uniform(0.3, 0.9), rng.uniform(0.25, 0.95))
                    decal = (round(u0, 3), round(u0 + wd, 3), round(h0, 3), round(h1, 3), *col)
                if axis == "y":
                    walls.append(Wall(a2, c - t / 2, b2, c + t / 2, round(tint, 3), decal))
                else:
                    walls.append(Wall(c - t / 2, a2, c + t / 2, b2, round(tint, 3), decal))
    return walls


def _subtract(pieces, a, b):
    out = []
    for lo, hi in pieces:
        if b <= lo or a >= hi:
            out.append((lo, hi))
            continue
        if a > lo:
            out.append((lo, a))
        if b < hi:
            out.append((b, hi))
    return out


# --------------------------------------------------------------------------- objects
class _Placer:
    """Places boxes in one room, keeping doorways clear and the room's floor connected."""

    def __init__(self, room_rect, door_zones, existing):
        self.rx0, self.ry0, self.rx1, self.ry1 = room_rect
        t = WALL_THICKNESS / 2 + 0.02
        self.ix0, self.iy0 = self.rx0 + t, self.ry0 + t
        self.ix1, self.iy1 = self.rx1 - t, self.ry1 - t
        self.door_zones = door_zones  # rectangles that must stay empty
        self.boxes: list[tuple[float, float, float, float]] = list(existing)
        # local occupancy grid of the room interior for the connectivity check
        self.nx = int(math.ceil((self.ix1 - self.ix0) / GRID_RES))
        self.ny = int(math.ceil((self.iy1 - self.iy0) / GRID_RES))
        self.occ = np.zeros((self.ny, self.nx), np.uint8)
        self.door_cells = []
        for zx0, zy0, zx1, zy1 in door_zones:
            cx = min(max((zx0 + zx1) / 2, self.ix0), self.ix1)
            cy = min(max((zy0 + zy1) / 2, self.iy0), self.iy1)
            i = min(max(int((cy - self.iy0) / GRID_RES), 0), self.ny - 1)
            j = min(max(int((cx - self.ix0) / GRID_RES), 0), self.nx - 1)
            self.door_cells.append((i, j))

    def fits(self, b) -> bool:
        x0, y0, x1, y1 = b
        if x0 < self.ix0 or y0 < self.iy0 or x1 > self.ix1 or y1 > self.iy1:
            return False
        gap = 0.05
        for o in self.boxes:
            if x0 < o[2] + gap and o[0] < x1 + gap and y0 < o[3] + gap and o[1] < y1 + gap:
                return False
        for z in self.door_zones:
            if x0 < z[2] and z[0] < x1 and y0 < z[3] and z[1] < y1:
                return False
        return self._still_connected(b)

    def _still_connected(self, b) -> bool:
        occ = self.occ.copy()
        r = AGENT_RADIUS + 0.05  # conservative: NavMap's rasterisation differs slightly
        j0 = max(int((b[0] - r - self.ix0) / GRID_RES), 0)
        j1 = min(int(math.ceil((b[2] + r - self.ix0) / GRID_RES)), self.nx)
        i0 = max(int((b[1] - r - self.iy0) / GRID_RES), 0)
        i1 = min(int(math.ceil((b[3] + r - self.iy0) / GRID_RES)), self.ny)
        occ[i0:i1, j0:j1] = 1
        free = (occ == 0).astype(np.uint8)
        # the interior border lies within the agent radius of a wall
        k = int(math.ceil((AGENT_RADIUS + 0.05) / GRID_RES))
        free[:k, :] = 0
        free[-k:, :] = 0
        free[:, :k] = 0
        free[:, -k:] = 0
        n, lab = cv2.connectedComponents(free, connectivity=8)
        if n < 2:
            return False
        labels = set()
        for i, j in self.door_cells:
            i = min(max(i, k), self.ny - k - 1)
            j = min(max(j, k), self.nx - k - 1)
            labels.add(int(lab[i, j]))
        if 0 in labels or len(labels) > 1:
            return False
        counts = np.bincount(lab.ravel())
        main = labels.pop() if labels else int(np.argmax(counts[1:]) + 1)
        if counts[main] < 0.85 * counts[1:].sum():
            return False
        self.pending = (i0, i1, j0, j1)
        return True

    def add(self, b) -> None:
        i0, i1, j0, j1 = self.pending
        self.occ[i0:i1, j0:j1] = 1
        self.boxes.append(b)


def _against_wall(rng, placer: _Placer, w: float, d: float):
    side = int(rng.integers(0, 4))
    if side in (0, 1):  # bottom / top wall: the long side runs along x
        x0 = rng.uniform(placer.ix0, max(placer.ix1 - w, placer.ix0))
        y0 = placer.iy0 if side == 0 else placer.iy1 - d
        return (x0, y0, x0 + w, y0 + d)
    y0 = rng.uniform(placer.iy0, max(placer.iy1 - w, placer.iy0))
    x0 = placer.ix0 if side == 2 else placer.ix1 - d
    return (x0, y0, x0 + d, y0 + w)


def _free_spot(rng, placer: _Placer, w: float, d: float, near=None):
    if rng.uniform() < 0.5:
        w, d = d, w
    if near is not None:  # next to a table: one of its sides
        tx0, ty0, tx1, ty1 = near
        side = int(rng.integers(0, 4))
        if side == 0:
            x0, y0 = rng.uniform(tx0 - w / 2, tx1 - w / 2), ty0 - d - 0.08
        elif side == 1:
            x0, y0 = rng.uniform(tx0 - w / 2, tx1 - w / 2), ty1 + 0.08
        elif side == 2:
            x0, y0 = tx0 - w - 0.08, rng.uniform(ty0 - d / 2, ty1 - d / 2)
        else:
            x0, y0 = tx1 + 0.08, rng.uniform(ty0 - d / 2, ty1 - d / 2)
        return (x0, y0, x0 + w, y0 + d)
    x0 = rng.uniform(placer.ix0, max(placer.ix1 - w, placer.ix0))
    y0 = rng.uniform(placer.iy0, max(placer.iy1 - d, placer.iy0))
    return (x0, y0, x0 + w, y0 + d)


def _place_objects(rng, rects, kinds, doors) -> list[ObjectInstance]:
    objects: list[ObjectInstance] = []
    for ri, (rect, kind) in enumerate(zip(rects, kinds, strict=True)):
        zones = []
        for dr in doors:
            if ri in (dr.a, dr.b):  # keep 1 m in front of and behind each doorway clear
                if dr.x1 - dr.x0 < dr.y1 - dr.y0:  # opening in a vertical wall
                    zones.append((dr.x0 - 1.0, dr.y0 - 0.1, dr.x1 + 1.0, dr.y1 + 0.1))
                else:
                    zones.append((dr.x0 - 0.1, dr.y0 - 1.0, dr.x1 + 0.1, dr.y1 + 1.0))
        placer = _Placer(rect, zones, [])
        table = None
        for cls, p, (lo, hi) in _PRIORS[kind]:
            if rng.uniform() >= p:
                continue
            count = int(rng.integers(lo, hi + 1))
            w0, d0, h0, bottom, wall = _SIZES[cls]
            for _ in range(count):
                s = rng.uniform(0.88, 1.12, size=3)
                w, d, h = w0 * s[0], d0 * s[1], h0 * s[2]
                for _attempt in range(25):
                    if wall:
                        b = _against_wall(rng, placer, w, d)
                    else:
                        near = table if cls in ("chair", "stool") and table is not None else None
                        b = _free_spot(rng, placer, w, d, near)
                    b = tuple(round(float(v), 3) for v in b)
                    if placer.fits(b):
                        placer.add(b)
                        if cls == "table":
                            table = b
                        hue = _CLASS_HUE[cls] + rng.normal(0, 0.06)
                        color = _hsv(hue, rng.uniform(0.35, 0.85), rng.uniform(0.35, 0.95))
                        # mounted objects (bottom > 0) keep the bottom and jitter the top
                        top = h if bottom == 0 else bottom + (h0 - bottom) * s[2]
                        top = round(float(top), 3)
                        objects.append(
                            ObjectInstance(len(objects) + 1, cls, ri, *b, float(bottom), top, color)
                        )
                        break
    return objects


# --------------------------------------------------------------------------- entry point
def generate_house(seed: int, name: str | None = None, n_rooms: int | None = None) -> Scene:
    """Generate a house from ``seed``: 4-12 rooms, floor at most 20 m × 20 m.

    ``n_rooms`` forces the number of rooms (4..12); by default it is drawn from the seed.
    The same arguments always give an identical :class:`Scene`.
    """
    rng = np.random.default_rng(seed)
    n = int(rng.integers(4, 13)) if n_rooms is None else int(n_rooms)
    if not 4 <= n <= 12:
        raise ValueError(f"n_rooms must be in 4..12, got {n}")
    scene = None
    for _attempt in range(50):
        scene = _generate(rng, seed, name, n)
        if _all_rooms_connected(scene):
            return scene
    return scene  # pragma: no cover - the layout retries practically always succeed


def _all_rooms_connected(scene: Scene) -> bool:
    """True when the navigable main component reaches every room (ground-truth check)."""
    nav = NavMap.from_scene(scene)
    rooms = np.unique(scene.room_id_grid()[nav.grid])
    return len(rooms) == len(scene.rooms)


def door_tree(rng: np.random.Generator, rects, weight=None, loops: float = 0.2) -> list:
    """Which adjacent rooms get a door: a random spanning tree of the rooms sharing enough wall
    (edge order drawn from ``rng``, scaled by ``weight(i, j)`` when given, so a smaller weight
    comes first), plus each other adjacency with probability ``loops``. Returns
    ``[(i, j, shared_edge), ...]``."""
    edges = []
    for i in range(len(rects)):
        for j in range(i + 1, len(rects)):
            e = _shared_edge(rects[i], rects[j])
            if e and e[3] - e[2] >= DOOR_WIDTH + 0.5:
                w = float(rng.uniform())
                edges.append((w * weight(i, j) if weight else w, i, j, e))
    edges.sort(key=lambda t: t[0])
    parent = list(range(len(rects)))

    def find(a):
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    chosen = []
    for _wt, i, j, e in edges:
        if find(i) != find(j):
            parent[find(i)] = find(j)
            chosen.append((i, j, e))
        elif rng.uniform() < loops:
            chosen.append((i, j, e))
    return chosen


def cut_doors(rng: np.random.Generator, chosen, width=None) -> tuple[list[Door], list[tuple]]:
    """A door in each chosen shared wall, at a random place along it: the :class:`Door`
    rectangles and the door intervals ``(axis, coord, lo, hi)`` the walls are cut at.
    ``width(i, j, span)`` may widen a door (default :data:`DOOR_WIDTH`)."""
    doors: list[Door] = []
    lines = []
    t = WALL_THICKNESS
    for i, j, (axis, c, lo, hi) in chosen:
        dw = width(i, j, hi - lo) if width else DOOR_WIDTH
        a = round(float(rng.uniform(lo + 0.25, hi - 0.25 - dw)), 3)
        b = round(a + dw, 3)
        lines.append((axis, c, a, b))
        if axis == "x":
            doors.append(Door(i, j, c - t / 2, a, c + t / 2, b))
        else:
            doors.append(Door(i, j, a, c - t / 2, b, c + t / 2))
    return doors, lines


def _generate(rng: np.random.Generator, seed: int, name: str | None, n: int) -> Scene:
    # area grows with the room count; about 14 m^2 per room, capped at 20 m x 20 m
    area = n * rng.uniform(12.0, 18.0)
    aspect = rng.uniform(0.7, 1.4)
    w = min(max(math.sqrt(area * aspect), 2 * 2.6), 20.0)
    d = min(max(area / w, 2 * 2.6), 20.0)
    w, d = round(w * 4) / 4, round(d * 4) / 4
    rects = _split_rooms(rng, w, d, n)
    while len(rects) < 4:  # a too-small floor: enlarge until 4 rooms fit
        w, d = min(w + 1.0, 20.0), min(d + 1.0, 20.0)
        rects = _split_rooms(rng, w, d, n)
    kinds = _assign_kinds(rng, rects)

    doors, door_lines = cut_doors(rng, door_tree(rng, rects))
    walls = _wall_boxes(rects, door_lines, rng)

    rooms = []
    for i, (r, k) in enumerate(zip(rects, kinds, strict=True)):
        wall_c, floor_c, wtex, ftex = _room_style(rng, k)
        rooms.append(Room(i, k, *[float(v) for v in r], wall_c, floor_c, wtex, ftex))
    objects = _place_objects(rng, rects, kinds, doors)
    return Scene(
        name=name or f"house_{seed}",
        seed=int(seed),
        width=float(w),
        depth=float(d),
        rooms=tuple(rooms),
        doors=tuple(doors),
        walls=tuple(walls),
        objects=tuple(objects),
    )
