"""Seeded multi-room houses for the MiniWorld adapter: floor plan, objects, episodes, ground truth.

Everything here is plain numpy (no OpenGL, no MiniWorld import), so a process that only needs
the ground truth (the benchmark's parent process, scoring memories) never opens a GL context.
A house is a grid of 2 × 2 or 2 × 3 rectangular rooms, 3–5 m a side, joined by 1 m doorways
(a random spanning tree of the room grid plus a few extra doors); each room gets its own wall
and floor textures and one to three objects of :data:`CLASSES`, MiniWorld meshes (an office
chair, an office desk, a barrel, a cone, a ball) or its coloured box, turned by a multiple of
90° so that their footprints are exact axis-aligned boxes.

World frame: x east, y north (metres, origin at the house's south-west corner), θ
counter-clockwise from +x. MiniWorld's frame is x, z = -y, with ``dir`` = θ.

The navigable grid (:class:`kgnav.sim.navmesh.NavMap`, 5 cm) marks walls (10 cm thick, doors cut
out), object footprints and the outside as occupied; geodesic distances are Fast Marching over
it, and the adapter moves the agent on it with kgnav's motion rule (exact 0.25 m steps in 2.5 cm
sub-steps, 30° turns).

>>> h = generate_house(0, "mw-demo")
>>> len(h.rooms), len(h.doors), len(h.objects), sorted({o.cls for o in h.objects})
(4, 3, 8, ['ball', 'barrel', 'box', 'chair', 'cone', 'desk'])
"""

from __future__ import annotations

import importlib.util
import math
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path

import numpy as np

from kgnav.errors import KgnavError
from kgnav.sim.house import GRID_RES, ObjectInstance, rasterize_box
from kgnav.sim.navmesh import NavMap

#: The object vocabulary (class id k is ``CLASSES[k - 1]``).
CLASSES = ("chair", "desk", "barrel", "box", "cone", "ball")
#: per class: MiniWorld mesh (``None``: MiniWorld's coloured ``Box``) and height (m)
MESHES: dict[str, tuple[str | None, float]] = {
    "chair": ("office_chair", 1.0),
    "desk": ("office_desk", 0.8),
    "barrel": ("barrel", 0.9),
    "box": (None, 0.6),
    "cone": ("cone", 0.6),
    "ball": ("ball_{color}", 0.5),
}
COLORS = ("red", "green", "blue", "yellow", "purple")  # boxes and balls
WALL_TEXTURES = ("brick_wall", "concrete", "drywall", "stucco", "wood_planks", "marble",
                 "cinder_blocks", "wood")
FLOOR_TEXTURES = ("floor_tiles_bw", "wood_planks", "concrete_tiles", "marble", "asphalt", "wood")
CEILING_TEXTURE = "ceiling_tiles"
WALL_HEIGHT = 2.74  # MiniWorld's
WALL_THICKNESS = 0.1  # of the collision walls (MiniWorld's walls are planes)
DOOR_WIDTH = 1.0
AGENT_RADIUS = 0.18
MIN_GEODESIC, MAX_GEODESIC = 1.5, 14.0  # episode start to the goal's success region (m)
SUCCESS_DISTANCE = 1.0


@dataclass(frozen=True)
class Room:
    """A rectangle ``[x0, x1] × [y0, y1]`` and its textures."""

    id: int
    x0: float
    y0: float
    x1: float
    y1: float
    wall: str
    floor: str


@dataclass(frozen=True)
class Door:
    """An opening of the wall between rooms ``a`` and ``b``: along x (``axis`` 0, the wall at
    y = ``at``) or along y (``axis`` 1, the wall at x = ``at``), from ``lo`` to ``hi``."""

    a: int
    b: int
    axis: int
    at: float
    lo: float
    hi: float


@dataclass(frozen=True)
class Placed:
    """How an object is drawn: MiniWorld mesh (None: a box), colour, height, position
    (world x, y of the mesh origin) and heading (radians, a multiple of 90°)."""

    mesh: str | None
    color: str
    height: float
    x: float
    y: float
    dir: float


@dataclass(frozen=True)
class Episode:
    episode_id: str
    start: tuple[float, float, float]
    goal_class: str
    geodesic_distance: float


@dataclass
class House:
    """One generated house (see the module doc): ``objects`` are
    :class:`~kgnav.sim.house.ObjectInstance` (ids 1..N, the semantic instance ids), ``placed``
    how MiniWorld draws each, ``nav`` the navigable grid."""

    name: str
    seed: int
    width: float
    depth: float
    rooms: tuple[Room, ...]
    doors: tuple[Door, ...]
    objects: tuple[ObjectInstance, ...]
    placed: tuple[Placed, ...]
    nav: NavMap | None = None
    _by_class: dict = field(default_factory=dict, repr=False)

    def objects_of(self, cls: str) -> list[ObjectInstance]:
        if cls not in self._by_class:
            self._by_class[cls] = [o for o in self.objects if o.cls == cls]
        return self._by_class[cls]


# ---------------------------------------------------------------------- meshes
def miniworld_dir() -> Path:
    """Where the installed ``miniworld`` package lives (found without importing it: its import
    opens an OpenGL context), or a one-line error naming the missing extra."""
    spec = importlib.util.find_spec("miniworld")
    if spec is None or spec.origin is None:
        raise KgnavError("environment 'miniworld' needs the MiniWorld simulator, which is not "
                         "installed: pip install 'kgnav[miniworld]'")
    return Path(spec.origin).parent


@cache
def mesh_extent(mesh: str) -> tuple[np.ndarray, np.ndarray]:
    """(min, max) corner (x, y, z) of a MiniWorld mesh at unit scale, centred as MiniWorld's
    ``ObjMesh`` centres it (base at y = 0, the centre of its vertex extent at x = z = 0)."""
    path = miniworld_dir() / "meshes" / f"{mesh}.obj"
    verts, faces = [], []
    for line in path.read_text().splitlines():
        tok = line.split()
        if not tok:
            continue
        if tok[0] == "v":
            verts.append([float(v) for v in tok[1:4]])
        elif tok[0] == "f":
            faces.append([int(t.split("/")[0]) - 1 for t in tok[1:4]])
    v = np.asarray(verts, np.float32)[np.asarray(faces)]  # (faces, 3, 3) as ObjMesh holds them
    lo, hi = v.min(axis=0).min(axis=0), v.max(axis=0).min(axis=0)  # (sic: ObjMesh's centring)
    mid = (lo + hi) / 2
    v[:, :, 1] -= lo[1]
    v[:, :, 0] -= mid[0]
    v[:, :, 2] -= mid[2]
    return v.min(axis=0).min(axis=0), v.max(axis=0).max(axis=0)


def local_box(cls: str, color: str) -> tuple[float, float, float, float, float]:
    """An object's footprint in its own frame (x0, x1, z0, z1, in metres) and its height."""
    mesh, height = MESHES[cls]
    if mesh is None:  # MiniWorld's Box: a cube of side ``height`` centred on its position
        s = height / 2
        return -s, s, -s, s, height
    lo, hi = mesh_extent(mesh.format(color=color))
    k = height / float(hi[1])  # MiniWorld scales a mesh to its height
    return float(lo[0] * k), float(hi[0] * k), float(lo[2] * k), float(hi[2] * k), height


def footprint(cls: str, color: str, x: float, y: float, dir_: float
              ) -> tuple[float, float, float, float]:
    """World footprint (x0, y0, x1, y1) of an object at (x, y) turned by ``dir_`` (a multiple
    of 90°: MiniWorld's ``glRotatef(dir, 0, 1, 0)`` maps local (lx, lz) to
    (lx cos + lz sin, -lx sin + lz cos) in its x, z, and world y is -z)."""
    x0, x1, z0, z1, _h = local_box(cls, color)
    c, s = round(math.cos(dir_)), round(math.sin(dir_))
    xs, ys = [], []
    for lx in (x0, x1):
        for lz in (z0, z1):
            mx, mz = lx * c + lz * s, -lx * s + lz * c
            xs.append(x + mx)
            ys.append(y - mz)
    return min(xs), min(ys), max(xs), max(ys)


# ---------------------------------------------------------------------- generation
def generate_house(seed: int, name: str) -> House:
    """The house of ``seed`` (same seed, same house), with its navigable grid."""
    rng = np.random.default_rng([seed, 0x4D57])
    cols = int(rng.integers(2, 4))
    sizes = np.arange(3.0, 5.01, 0.5)
    xs = np.r_[0.0, np.cumsum(rng.choice(sizes, cols))]
    ys = np.r_[0.0, np.cumsum(rng.choice(sizes, 2))]
    rooms = []
    for r in range(2):
        for c in range(cols):
            rooms.append(Room(len(rooms), float(xs[c]), float(ys[r]), float(xs[c + 1]),
                              float(ys[r + 1]), str(rng.choice(WALL_TEXTURES)),
                              str(rng.choice(FLOOR_TEXTURES))))
    doors = _doors(rooms, cols, rng)
    for _attempt in range(50):
        objects, placed = _objects(rooms, doors, rng)
        house = House(name, seed, float(xs[-1]), float(ys[-1]), tuple(rooms), tuple(doors),
                      tuple(objects), tuple(placed))
        house.nav = navigable_map(house)
        if _connected(house):
            return house
    raise KgnavError(f"house {name!r} (seed {seed}): no object layout keeps every room "
                     "reachable")  # not seen: a layout is found within a few attempts


def _doors(rooms: list[Room], cols: int, rng) -> list[Door]:
    """A random spanning tree of the room grid, plus each other wall with probability 1/4."""
    edges = [(r * cols + c, r * cols + c + 1) for r in range(2) for c in range(cols - 1)]
    edges += [(c, cols + c) for c in range(cols)]
    order = rng.permutation(len(edges))
    parent = list(range(len(rooms)))

    def root(i: int) -> int:
        while parent[i] != i:
            i = parent[i]
        return i

    doors = []
    for k in order:
        a, b = edges[int(k)]
        joined = root(a) != root(b)
        if joined:
            parent[root(a)] = root(b)
        if joined or rng.random() < 0.25:
            ra, rb = rooms[a], rooms[b]
            if ra.y0 == rb.y0:  # side by side: the wall at x = ra.x1, opening along y
                axis, at, lo, hi = 1, ra.x1, ra.y0, ra.y1
            else:  # one above the other: the wall at y = ra.y1, opening along x
                axis, at, lo, hi = 0, ra.y1, ra.x0, ra.x1
            mid = float(rng.uniform(lo + 0.4 + DOOR_WIDTH / 2, hi - 0.4 - DOOR_WIDTH / 2))
            doors.append(Door(a, b, axis, at, round(mid - DOOR_WIDTH / 2, 3),
                              round(mid + DOOR_WIDTH / 2, 3)))
    return sorted(doors, key=lambda d: (d.a, d.b))


def _objects(rooms: list[Room], doors: list[Door], rng):
    """One to three objects a room; classes cycle through a shuffled vocabulary, so that a
    house holds every class once before any twice."""
    pool: list[str] = []
    objects, placed = [], []
    for room in rooms:
        for _ in range(int(rng.integers(1, 4))):
            if not pool:
                pool = [str(c) for c in rng.permutation(CLASSES)]
            cls = pool.pop()
            color = str(rng.choice(COLORS))
            spot = _place(cls, color, room, doors, objects, rng)
            if spot is None:
                continue
            x, y, d, box = spot
            mesh, height = MESHES[cls]
            objects.append(ObjectInstance(len(objects) + 1, cls, room.id, *box, 0.0, height,
                                          (0, 0, 0)))
            placed.append(Placed(None if mesh is None else mesh.format(color=color), color,
                                 height, x, y, d))
    return objects, placed


def _place(cls, color, room: Room, doors, objects, rng, tries: int = 40):
    """A position and heading in ``room`` keeping 0.25 m from the walls, 0.6 m from other
    objects and 1 m from doorways; None if none is found."""
    for _ in range(tries):
        d = float(rng.integers(4)) * math.pi / 2
        x = float(rng.uniform(room.x0, room.x1))
        y = float(rng.uniform(room.y0, room.y1))
        x0, y0, x1, y1 = footprint(cls, color, x, y, d)
        if x0 < room.x0 + 0.25 or x1 > room.x1 - 0.25 or y0 < room.y0 + 0.25 \
                or y1 > room.y1 - 0.25:
            continue
        if any(_gap((x0, y0, x1, y1), (o.x0, o.y0, o.x1, o.y1)) < 0.6 for o in objects):
            continue
        if any(_gap((x0, y0, x1, y1), _door_box(dr, 0.0)) < 1.0 for dr in doors):
            continue
        return x, y, d, (x0, y0, x1, y1)
    return None


def _gap(a, b) -> float:
    """Distance between two boxes (x0, y0, x1, y1); 0 when they overlap."""
    dx = max(a[0] - b[2], b[0] - a[2], 0.0)
    dy = max(a[1] - b[3], b[1] - a[3], 0.0)
    return math.hypot(dx, dy)


def _door_box(d: Door, half: float):
    if d.axis == 0:
        return d.lo, d.at - half, d.hi, d.at + half
    return d.at - half, d.lo, d.at + half, d.hi


def navigable_map(house: House) -> NavMap:
    """The house's navigable grid (walls with doors cut out, object footprints, outside)."""
    h = int(math.ceil(house.depth / GRID_RES)) + 1
    w = int(math.ceil(house.width / GRID_RES)) + 1
    occ = np.zeros((h, w), bool)
    t = WALL_THICKNESS / 2
    for r in house.rooms:
        rasterize_box(occ, r.x0 - t, r.y0 - t, r.x1 + t, r.y0 + t, True)
        rasterize_box(occ, r.x0 - t, r.y1 - t, r.x1 + t, r.y1 + t, True)
        rasterize_box(occ, r.x0 - t, r.y0 - t, r.x0 + t, r.y1 + t, True)
        rasterize_box(occ, r.x1 - t, r.y0 - t, r.x1 + t, r.y1 + t, True)
    for d in house.doors:
        rasterize_box(occ, *_door_box(d, 2 * t), False)
    for o in house.objects:
        rasterize_box(occ, o.x0, o.y0, o.x1, o.y1, True)
    return NavMap.from_occupancy(house, occ, AGENT_RADIUS, CLASSES)


def _connected(house: House) -> bool:
    """Every room has navigable floor and every object a navigable cell within success
    distance (the grid keeps only the largest connected region)."""
    nav = house.nav
    for r in house.rooms:
        (i0, j0), (i1, j1) = nav.to_cell(r.x0, r.y0), nav.to_cell(r.x1, r.y1)
        if not nav.grid[i0:i1, j0:j1].any():
            return False
    return len(nav.reachable_objects()) == len(house.objects)


def generate_episodes(house: House, n: int, seed: int = 0) -> list[Episode]:
    """``n`` episodes: a goal class present in the house and a start cell whose geodesic
    distance to its success region is within [:data:`MIN_GEODESIC`, :data:`MAX_GEODESIC`],
    drawn uniformly over such (class, cell) pairs' classes, then cells; heading uniform."""
    nav = house.nav
    rng = np.random.default_rng([seed, house.seed, 0x4550])
    usable = []
    for c in CLASSES:
        if house.objects_of(c):
            f = nav.distance_field(c)
            ok = nav.grid & (f >= MIN_GEODESIC) & (f <= MAX_GEODESIC)
            if ok.any():
                usable.append((c, f, np.argwhere(ok)))
    out = []
    for k in range(n):
        c, f, cells = usable[int(rng.integers(len(usable)))]
        i, j = cells[int(rng.integers(len(cells)))]
        x, y = nav.to_world(int(i), int(j))
        theta = float(rng.uniform(-math.pi, math.pi))
        out.append(Episode(f"{house.name}_ep{k:04d}", (round(x, 4), round(y, 4),
                                                         round(theta, 6)), c,
                           round(float(f[i, j]), 4)))
    return out
