"""Ground-truth navigable map and geodesic distances (Fast Marching, scikit-fmm).

The map is a boolean grid at 5 cm (rows = y, columns = x, cell (i, j) centred at
``origin + ((j + 0.5) * res, (i + 0.5) * res)``). A cell is navigable when the agent's disc
(radius 0.18 m) centred there touches no wall and no object box, and it belongs to the largest
connected free region (the house interior reachable through doors).

>>> from kgnav.sim.house import generate_house
>>> nav = NavMap.from_scene(generate_house(3))
>>> bool(nav.grid.any())
True
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np
import skfmm

from kgnav.common.classes import OBJECT_CLASSES
from kgnav.common.edt import distance_to_zero
from kgnav.sim.scene import AGENT_RADIUS, GRID_RES, Scene, rasterize_box

SUCCESS_DISTANCE = 1.0  # m, the paper's success threshold


@dataclass
class NavMap:
    """Navigable grid of a scene plus cached geodesic distance fields.

    ``grid`` bool (H, W); ``resolution`` metres per cell; ``origin`` world (x, y) of the grid's
    corner (0, 0). ``obstacles`` marks walls and object footprints (not inflated). ``scene``
    needs only ``objects`` (with ``id``, ``x0, y0, x1, y1`` and ``distance_to(x, y)``) and
    ``objects_of(cls)``; ``classes`` is the vocabulary goal classes are checked against.
    """

    scene: Scene
    grid: np.ndarray
    obstacles: np.ndarray
    resolution: float = GRID_RES
    origin: tuple[float, float] = (0.0, 0.0)
    agent_radius: float = AGENT_RADIUS
    classes: tuple[str, ...] = OBJECT_CLASSES
    _fields: dict = field(default_factory=dict, repr=False)

    @classmethod
    def from_scene(cls, scene: Scene, agent_radius: float = AGENT_RADIUS) -> NavMap:
        """Build (or fetch from the scene's cache) the navigable map of ``scene``."""
        key = ("navmap", agent_radius)
        if key in scene._cache:
            return scene._cache[key]
        rooms = scene.room_id_grid() >= 0
        occ = ~rooms
        for w in scene.walls:
            rasterize_box(occ, w.x0, w.y0, w.x1, w.y1, True)
        for o in scene.objects:
            rasterize_box(occ, o.x0, o.y0, o.x1, o.y1, True)
        nav = cls.from_occupancy(scene, occ, agent_radius)
        scene._cache[key] = nav
        return nav

    @classmethod
    def from_occupancy(cls, scene, occupied: np.ndarray, agent_radius: float = AGENT_RADIUS,
                       classes: tuple[str, ...] = OBJECT_CLASSES) -> NavMap:
        """The navigable map of any floor plan: ``occupied`` (bool, rows = y, at
        :data:`GRID_RES` from the origin) marks walls, object footprints and the outside.
        A cell is navigable when the agent's disc there touches no occupied cell and it lies in
        the largest connected free region."""
        occ = np.asarray(occupied, bool)
        # distance (cells) from each free cell centre to the nearest obstacle cell
        dist = distance_to_zero(~occ)
        # an obstacle cell's edge is half a cell nearer than its centre
        free = (dist - 0.5) * GRID_RES >= agent_radius
        n, lab = cv2.connectedComponents(free.astype(np.uint8), connectivity=8)
        if n > 1:
            counts = np.bincount(lab.ravel())
            counts[0] = 0
            free = lab == int(np.argmax(counts))
        return cls(scene, free, occ, agent_radius=agent_radius, classes=tuple(classes))

    # ------------------------------------------------------------------ coordinates
    def to_cell(self, x: float, y: float) -> tuple[int, int]:
        """Grid cell (row, col) containing world point (x, y); may lie outside the grid."""
        return (
            int(math.floor((y - self.origin[1]) / self.resolution)),
            int(math.floor((x - self.origin[0]) / self.resolution)),
        )

    def to_world(self, i: int, j: int) -> tuple[float, float]:
        """World (x, y) of the centre of cell (row i, col j)."""
        return (
            self.origin[0] + (j + 0.5) * self.resolution,
            self.origin[1] + (i + 0.5) * self.resolution,
        )

    def is_navigable(self, x: float, y: float) -> bool:
        """True when the agent may stand with its centre at (x, y)."""
        i, j = self.to_cell(x, y)
        h, w = self.grid.shape
        return 0 <= i < h and 0 <= j < w and bool(self.grid[i, j])

    def navigable_cells(self) -> np.ndarray:
        """(N, 2) int array of (row, col) of every navigable cell, row-major order."""
        return np.argwhere(self.grid)

    # ------------------------------------------------------------------ geodesics
    def goal_region(self, cls: str, radius: float = SUCCESS_DISTANCE) -> np.ndarray:
        """Navigable cells whose centre is within ``radius`` (L2) of a ``cls`` footprint."""
        key = ("region", cls, radius)
        if key not in self._fields:
            h, w = self.grid.shape
            ys = self.origin[1] + (np.arange(h) + 0.5) * self.resolution
            xs = self.origin[0] + (np.arange(w) + 0.5) * self.resolution
            near = np.zeros((h, w), bool)
            for o in self.scene.objects_of(cls):
                dx = np.maximum(np.maximum(o.x0 - xs, 0.0), xs - o.x1)
                dy = np.maximum(np.maximum(o.y0 - ys, 0.0), ys - o.y1)
                near |= (dy[:, None] ** 2 + dx[None, :] ** 2) <= radius**2
            self._fields[key] = near & self.grid
        return self._fields[key]

    def distance_field(self, cls: str) -> np.ndarray:
        """Geodesic distance (m) from every navigable cell to the goal region of ``cls``.

        Fast Marching from the region (distance 0 inside it) through navigable cells; cells
        that are not navigable or cannot reach the region hold ``inf``. Cached per class.
        """
        if cls not in self.classes:
            from kgnav.errors import UnknownClassError

            raise UnknownClassError(cls, self.classes)
        key = ("field", cls)
        if key not in self._fields:
            self._fields[key] = self._fmm(self.goal_region(cls))
        return self._fields[key]

    def distance_field_to_point(self, x: float, y: float) -> np.ndarray:
        """Geodesic distance (m) from every navigable cell to the cell of point (x, y)."""
        i, j = self.snap(x, y)
        target = np.zeros_like(self.grid)
        target[i, j] = True
        return self._fmm(target)

    def _fmm(self, target: np.ndarray) -> np.ndarray:
        out = np.full(self.grid.shape, np.inf)
        if not target.any():
            return out
        phi = np.where(target, -1.0, 1.0)
        # the zero level set sits half a cell outside the target; shift so target cells read 0
        d = skfmm.distance(np.ma.MaskedArray(phi, ~self.grid), dx=self.resolution)
        vals = np.ma.filled(d.astype(float), np.inf)
        vals = np.where(target, 0.0, vals + 0.5 * self.resolution)
        out[self.grid] = vals[self.grid]
        return out

    def snap(self, x: float, y: float, max_radius: float = 1.0) -> tuple[int, int]:
        """Nearest navigable cell to (x, y) within ``max_radius`` metres (ValueError if none)."""
        i, j = self.to_cell(x, y)
        h, w = self.grid.shape
        if 0 <= i < h and 0 <= j < w and self.grid[i, j]:
            return i, j
        r = int(math.ceil(max_radius / self.resolution))
        i0, i1 = max(i - r, 0), min(i + r + 1, h)
        j0, j1 = max(j - r, 0), min(j + r + 1, w)
        if i0 >= i1 or j0 >= j1:
            raise ValueError(f"point ({x:.2f}, {y:.2f}) is outside the map")
        cand = np.argwhere(self.grid[i0:i1, j0:j1])
        if len(cand) == 0:
            raise ValueError(f"no navigable cell within {max_radius} m of ({x:.2f}, {y:.2f})")
        cand += (i0, j0)
        k = int(np.argmin((cand[:, 0] - i) ** 2 + (cand[:, 1] - j) ** 2))
        return int(cand[k, 0]), int(cand[k, 1])

    def geodesic_distance(self, x: float, y: float, cls: str) -> float:
        """Geodesic distance (m) from world point (x, y) to the success region of ``cls``.

        The point is snapped to the nearest navigable cell (within 1 m); ``inf`` when the
        region is unreachable or the class absent.
        """
        try:
            i, j = self.snap(x, y)
        except ValueError:
            return math.inf
        return float(self.distance_field(cls)[i, j])

    def geodesic_between(self, a: tuple[float, float], b: tuple[float, float]) -> float:
        """Geodesic distance (m) between two world points (each snapped to the map)."""
        i, j = self.snap(*a)
        return float(self.distance_field_to_point(*b)[i, j])

    def l2_to_class(self, x: float, y: float, cls: str) -> float:
        """L2 distance (m) from (x, y) to the closest footprint of a ``cls`` instance."""
        objs = self.scene.objects_of(cls)
        return min((o.distance_to(x, y) for o in objs), default=math.inf)

    def reachable_objects(self) -> list[int]:
        """Ids of objects with a navigable cell within the success distance of their box."""
        h, w = self.grid.shape
        ys = self.origin[1] + (np.arange(h) + 0.5) * self.resolution
        xs = self.origin[0] + (np.arange(w) + 0.5) * self.resolution
        out = []
        r = SUCCESS_DISTANCE
        for o in self.scene.objects:
            jm = (xs >= o.x0 - r) & (xs <= o.x1 + r)
            im = (ys >= o.y0 - r) & (ys <= o.y1 + r)
            sub = self.grid[np.ix_(im, jm)]
            dx = np.maximum(np.maximum(o.x0 - xs[jm], 0.0), xs[jm] - o.x1)
            dy = np.maximum(np.maximum(o.y0 - ys[im], 0.0), ys[im] - o.y1)
            if (sub & ((dy[:, None] ** 2 + dx[None, :] ** 2) <= r * r)).any():
                out.append(o.id)
        return out
