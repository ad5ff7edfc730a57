"""What a scene is: the rooms, doors, walls and objects of a house, with the grid conventions
every ground-truth map shares (:data:`GRID_RES`, :func:`rasterize_box`). The generators
(:mod:`kgnav.sim.house`, :mod:`kgnav.sim.house_v2`) make them; :mod:`kgnav.sim.navmesh` and the
renderer read them."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from kgnav.common.classes import OBJECT_CLASSES

#: Room kinds a house can contain.
ROOM_KINDS: tuple[str, ...] = (
    "bedroom",
    "bathroom",
    "kitchen",
    "living_room",
    "dining_room",
    "office",
    "hallway",
    "storage",
    "laundry",
)

WALL_HEIGHT = 2.5  # m, also the ceiling height
WALL_THICKNESS = 0.1  # m
DOOR_WIDTH = 0.95  # m
GRID_RES = 0.05  # m per cell of every ground-truth grid
AGENT_RADIUS = 0.18  # m
GENERATOR = "house-v1"  # bump when generation changes: cached files are then regenerated


@dataclass(frozen=True)
class Texture:
    """Procedural pattern parameters: ``kind`` 0 plain, 1 stripes, 2 checks, 3 panels/planks.

    ``period`` in metres, ``amp`` the relative brightness swing (0..0.5), ``angle_deg`` unused by
    walls (their stripes run vertically) and rotates floor planks by 0 or 90 degrees.
    """

    kind: int = 0
    period: float = 0.5
    amp: float = 0.1
    angle_deg: float = 0.0


@dataclass(frozen=True)
class Room:
    """An axis-aligned room ``[x0, x1] × [y0, y1]`` (metres, wall centre lines)."""

    id: int
    kind: str
    x0: float
    y0: float
    x1: float
    y1: float
    wall_color: tuple[int, int, int]
    floor_color: tuple[int, int, int]
    wall_texture: Texture
    floor_texture: Texture

    @property
    def area(self) -> float:
        return (self.x1 - self.x0) * (self.y1 - self.y0)

    @property
    def center(self) -> tuple[float, float]:
        return ((self.x0 + self.x1) / 2, (self.y0 + self.y1) / 2)


@dataclass(frozen=True)
class Door:
    """An opening between rooms ``a`` and ``b``: the rectangle cut out of their shared wall."""

    a: int
    b: int
    x0: float
    y0: float
    x1: float
    y1: float


@dataclass(frozen=True)
class Wall:
    """A wall box (footprint rectangle, floor to ceiling) with an optional picture on it.

    ``decal`` is ``(u0, u1, h0, h1, r, g, b)``: a coloured rectangle between world coordinates
    u0..u1 along the wall (x for a horizontal wall, y for a vertical one) and heights h0..h1;
    it makes places look different from each other. ``tint`` scales the room's wall colour.
    """

    x0: float
    y0: float
    x1: float
    y1: float
    tint: float = 1.0
    decal: tuple[float, float, float, float, int, int, int] | None = None


@dataclass(frozen=True)
class ObjectInstance:
    """One object: a box with footprint ``[x0, x1] × [y0, y1]`` between heights bottom and top.

    ``id`` is the 1-based instance id used in semantic frames; ``cls`` a name from
    :data:`kgnav.common.classes.OBJECT_CLASSES`; ``room`` the id of the room it stands in.
    """

    id: int
    cls: str
    room: int
    x0: float
    y0: float
    x1: float
    y1: float
    bottom: float
    top: float
    color: tuple[int, int, int]

    @property
    def center(self) -> tuple[float, float]:
        return ((self.x0 + self.x1) / 2, (self.y0 + self.y1) / 2)

    def distance_to(self, x: float, y: float) -> float:
        """L2 distance (m) from the point to the closest point of the footprint (0 inside)."""
        dx = max(self.x0 - x, 0.0, x - self.x1)
        dy = max(self.y0 - y, 0.0, y - self.y1)
        return math.hypot(dx, dy)


@dataclass(frozen=True)
class Scene:
    """A whole house. ``width`` × ``depth`` metres, origin at its lower-left corner."""

    name: str
    seed: int
    width: float
    depth: float
    rooms: tuple[Room, ...]
    doors: tuple[Door, ...]
    walls: tuple[Wall, ...]
    objects: tuple[ObjectInstance, ...]
    wall_height: float = WALL_HEIGHT
    generator: str = GENERATOR
    _cache: dict = field(default_factory=dict, compare=False, repr=False, hash=False)

    def objects_of(self, cls: str) -> tuple[ObjectInstance, ...]:
        """Every instance of class ``cls`` (possibly none)."""
        return tuple(o for o in self.objects if o.cls == cls)

    def classes_present(self) -> tuple[str, ...]:
        """Classes with at least one instance, in vocabulary order."""
        have = {o.cls for o in self.objects}
        return tuple(c for c in OBJECT_CLASSES if c in have)

    def room_at(self, x: float, y: float) -> Room | None:
        """The room whose rectangle contains the point, or None outside the house."""
        for r in self.rooms:
            if r.x0 <= x <= r.x1 and r.y0 <= y <= r.y1:
                return r
        return None

    def room_id_grid(self) -> np.ndarray:
        """int16 grid at :data:`GRID_RES` (rows = y, cols = x): room index, -1 outside.

        Cell (i, j) covers ``[j*res, (j+1)*res] × [i*res, (i+1)*res]``. Cached on the scene.
        """
        if "room_grid" not in self._cache:
            ny, nx = _grid_shape(self)
            g = np.full((ny, nx), -1, np.int16)
            for r in self.rooms:
                i0, i1 = _cells(r.y0, r.y1, ny)
                j0, j1 = _cells(r.x0, r.x1, nx)
                g[i0:i1, j0:j1] = r.id
            self._cache["room_grid"] = g
        return self._cache["room_grid"]


def _grid_shape(scene: Scene) -> tuple[int, int]:
    return int(math.ceil(scene.depth / GRID_RES)), int(math.ceil(scene.width / GRID_RES))


def _cells(a: float, b: float, n: int) -> tuple[int, int]:
    return max(int(round(a / GRID_RES)), 0), min(int(round(b / GRID_RES)), n)


def rasterize_box(grid: np.ndarray, x0: float, y0: float, x1: float, y1: float, value) -> None:
    """Set every cell whose centre lies inside the rectangle (at least one cell per box)."""
    ny, nx = grid.shape
    j0 = max(int(math.floor(x0 / GRID_RES + 0.5)), 0)
    j1 = min(max(int(math.ceil(x1 / GRID_RES - 0.5)), j0 + 1), nx)
    i0 = max(int(math.floor(y0 / GRID_RES + 0.5)), 0)
    i1 = min(max(int(math.ceil(y1 / GRID_RES - 0.5)), i0 + 1), ny)
    grid[i0:i1, j0:j1] = value
