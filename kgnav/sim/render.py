"""A 2.5D ray caster in numpy: RGB, z-depth and semantic frames of a :class:`Scene`.

Every image column casts one horizontal ray. The scene is made only of axis-aligned boxes
standing between two heights (walls: floor to ceiling; objects: their own bottom and top), so
each column needs only ray/box slab tests, done for all columns and boxes at once:

* the nearest wall hit per column is the background; floor and ceiling planes in front of it
  come from plane intersection per row;
* every object hit nearer than that wall is drawn into a z-buffer over the rows its box spans
  (front face, plus its top when seen from above and its underside when seen from below),
  restricted to the object's bounding rows and columns. Exact depth, no K-nearest cut-off.

Depth is pinhole z-depth (distance along the optical axis): the ray direction of column ``u`` is
``forward + x_u * right`` with unit forward component, so the ray parameter *is* z-depth.

>>> from kgnav.sim.house import generate_house
>>> r = Renderer(generate_house(1), 160, 120)
>>> rgb, depth, sem = r.render(*r.scene.rooms[0].center, 0.0)
>>> rgb.shape, depth.dtype, sem.shape
((120, 160, 3), dtype('float32'), (120, 160, 2))
"""

from __future__ import annotations

import ctypes
import math
import os
import sys

import numpy as np

from kgnav.common.classes import OBJECT_CLASSES
from kgnav.sim.house import GRID_RES, Scene

CAMERA_HEIGHT = 0.88  # m (Habitat ObjectNav)
HFOV_DEG = 79.0
MIN_DEPTH = 0.5
MAX_DEPTH = 5.0

N_LEVELS = 64  # brightness levels of the pre-shaded palette
LEVELS_PER_UNIT = 32.0  # level of brightness factor 1.0; factors up to 2 are representable
FLOOR_TEXEL = 0.025  # m, resolution of the baked floor texture
_CEILING_COLOR = (235, 232, 225)
_FACE_SHADE_X = 0.82  # faces normal to x are darker: a fixed "sun" direction gives corners


_MALLOC_TUNED = False


def tune_malloc() -> bool:
    """Keep large numpy temporaries on the heap instead of fresh ``mmap`` pages (glibc only).

    Each frame allocates and frees a few dozen image-sized arrays; glibc serves blocks above
    its mmap threshold with new zeroed pages, and the page faults cost up to a third of a
    640x480 frame. Raising the mmap/trim thresholds (64/128 MiB) and the top pad removes that.
    Process-wide; called once by :class:`Renderer`; disable with ``KGNAV_NO_MALLOC_TUNING=1``.
    Returns True when applied.
    """
    global _MALLOC_TUNED
    if _MALLOC_TUNED or os.environ.get("KGNAV_NO_MALLOC_TUNING"):
        return _MALLOC_TUNED
    _MALLOC_TUNED = True
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL("libc.so.6")
        m_trim, m_top_pad, m_mmap = -1, -2, -3  # glibc's M_TRIM_THRESHOLD etc.
        ok = libc.mallopt(m_mmap, 64 << 20) and libc.mallopt(m_trim, 128 << 20)
        return bool(ok and libc.mallopt(m_top_pad, 64 << 20))
    except (OSError, AttributeError):
        return False


class Renderer:
    """Renders egocentric frames of one scene at a fixed resolution.

    ``render(x, y, theta)`` returns ``(rgb uint8 (H,W,3), depth float32 (H,W), semantic int32
    (H,W,2))``; the semantic channels are class id (1-based index in
    :data:`kgnav.common.classes.OBJECT_CLASSES`, 0 = wall/floor/ceiling) and object instance id
    (:attr:`ObjectInstance.id`, 0 = none). Depth is clipped to ``[min_depth, max_depth]``.
    """

    def __init__(
        self,
        scene: Scene,
        width: int = 160,
        height: int = 120,
        hfov_deg: float = HFOV_DEG,
        camera_height: float = CAMERA_HEIGHT,
        min_depth: float = MIN_DEPTH,
        max_depth: float = MAX_DEPTH,
    ):
        if width < 1 or height < 1:
            raise ValueError(f"resolution must be positive, got {width}x{height}")
        tune_malloc()
        self.scene = scene
        self.width, self.height = int(width), int(height)
        self.hfov = math.radians(hfov_deg)
        self.cam_h = float(camera_height)
        self.min_depth, self.max_depth = float(min_depth), float(max_depth)
        self.ceiling = float(scene.wall_height)
        W, H = self.width, self.height
        self.focal = (W / 2) / math.tan(self.hfov / 2)
        self.xu = ((np.arange(W) + 0.5) - W / 2) / self.focal  # right-positive
        yv = (H / 2 - (np.arange(H) + 0.5)) / self.focal  # up-positive
        self.yv = yv
        with np.errstate(divide="ignore"):
            inv = 1.0 / yv
        self.inv_neg = np.where(yv < 0, inv, 0.0)
        self.inv_pos = np.where(yv > 0, inv, 0.0)
        zplane = np.full(H, np.inf)
        zplane[yv < 0] = -self.cam_h / yv[yv < 0]
        zplane[yv > 0] = (self.ceiling - self.cam_h) / yv[yv > 0]
        self.zplane = zplane
        self.floor_rows = np.flatnonzero(yv < 0)
        self.f0 = int(self.floor_rows[0]) if len(self.floor_rows) else H
        self._prepare_scene()
        self.zplane32 = self.zplane.astype(np.float32)
        self.yv32 = self.yv.astype(np.float32)
        self._cols = np.arange(W)
        self._cols32 = np.arange(W, dtype=np.int32)
        # palette: [ceiling | wall per room, outside | floor per room, outside | picture per
        # wall | object per instance], pre-shaded at N_LEVELS brightness levels (uint8)
        n_r = len(self.scene.rooms)
        self._n_rooms = n_r
        self._ceil_i = 0
        self._wall0 = 1
        self._floor0 = 2 + n_r
        self._dec0 = 3 + 2 * n_r
        self._obj0 = self._dec0 + len(self.wb)
        pal = np.vstack(
            [np.array([_CEILING_COLOR], float), self.r_wall.reshape(-1, 3), [[150, 150, 150]],
             self.floor_pal, self.w_decal_col, self.o_col]
        )
        n_pal = len(pal)
        gain = (np.arange(N_LEVELS) + 0.5) / LEVELS_PER_UNIT
        self._spal = np.clip(pal[:, None, :] * gain[None, :, None], 0, 255).round().astype(
            np.uint8).reshape(-1, 3)
        self._bake_floor()
        self._sem_table = np.zeros((n_pal, 2), np.int32)
        self._sem_table[self._obj0 :, 0] = self.o_cls
        self._sem_table[self._obj0 :, 1] = self.o_inst

    # ------------------------------------------------------------------ scene tables
    def _prepare_scene(self) -> None:
        s = self.scene
        walls = s.walls
        self.wb = np.array([[w.x0, w.y0, w.x1, w.y1] for w in walls], float).reshape(-1, 4)
        self.w_tint = np.array([w.tint for w in walls], float)
        dec = np.array(
            [w.decal[:4] if w.decal else (0, -1, 0, -1) for w in walls], float
        ).reshape(-1, 4)
        self.w_decal = dec
        self.w_decal_col = np.array(
            [w.decal[4:] if w.decal else (0, 0, 0) for w in walls], float
        ).reshape(-1, 3)
        objs = s.objects
        self.ob = np.array([[o.x0, o.y0, o.x1, o.y1] for o in objs], float).reshape(-1, 4)
        self.o_bot = np.array([o.bottom for o in objs], float)
        self.o_top = np.array([o.top for o in objs], float)
        self.o_col = np.array([o.color for o in objs], float).reshape(-1, 3)
        self.o_cls = np.array([OBJECT_CLASSES.index(o.cls) + 1 for o in objs], np.int32)
        self.o_inst = np.array([o.id for o in objs], np.int32)
        rooms = s.rooms
        self.r_wall = np.array([r.wall_color for r in rooms], float)
        self.r_floor = np.array([r.floor_color for r in rooms], np.float32)
        # wall texture as a parity pattern of a*u + b*h (stripes, bands, checks) + wainscot
        a = np.zeros(len(rooms))
        b = np.zeros(len(rooms))
        wains = np.zeros(len(rooms))
        amp = np.zeros(len(rooms))
        for i, r in enumerate(rooms):
            t = r.wall_texture
            amp[i] = t.amp
            if t.kind == 1:
                a[i] = 1 / t.period
            elif t.kind == 2:
                a[i] = b[i] = 1 / t.period
            elif t.kind == 3:
                b[i] = 1 / t.period
                wains[i] = -0.12
        self.r_wa, self.r_wb32 = a, b.astype(np.float32)
        self.r_wains32, self.r_wamp = wains.astype(np.float32), amp
        self.r_fkind = np.array([r.floor_texture.kind for r in rooms])
        self.r_fper = np.array([r.floor_texture.period for r in rooms], np.float32)
        self.r_famp = np.array([r.floor_texture.amp for r in rooms], np.float32)
        self.r_frot = np.array([r.floor_texture.angle_deg != 0 for r in rooms])
        self._n_walls = len(self.wb)
        self.boxes = np.vstack([self.wb, self.ob])
        self._bx0, self._by0, self._bx1, self._by1 = (self.boxes[:, i].copy() for i in range(4))
        self.room_grid = s.room_id_grid()
        self._room_flat = self.room_grid.ravel()
        # floor palette with an extra entry (last) for points outside every room
        self.floor_pal = np.vstack([self.r_floor, [[90, 90, 90]]]).astype(np.float32)

    # ------------------------------------------------------------------ ray casting
    @staticmethod
    def _slab(ox, oy, dx, dy, boxes):
        """Entry/exit ray parameters (W, N) of rays o + t*d against boxes; inf on a miss."""
        with np.errstate(divide="ignore", invalid="ignore"):
            ix = 1.0 / np.where(dx == 0, 1e-12, dx)
            iy = 1.0 / np.where(dy == 0, 1e-12, dy)
            tx1 = (boxes[:, 0] - ox) * ix[:, None]
            tx2 = (boxes[:, 2] - ox) * ix[:, None]
            ty1 = (boxes[:, 1] - oy) * iy[:, None]
            ty2 = (boxes[:, 3] - oy) * iy[:, None]
        txn = np.minimum(tx1, tx2)
        tyn = np.minimum(ty1, ty2)
        tn = np.maximum(txn, tyn)
        tf = np.minimum(np.maximum(tx1, tx2), np.maximum(ty1, ty2))
        hit = (tf >= tn) & (tf > 0)
        tn = np.where(hit, np.maximum(tn, 1e-6), np.inf)
        return tn, tf, txn >= tyn  # last: entered through a face normal to x

    def render(self, x: float, y: float, theta: float):
        """Frames seen from world pose (x, y, theta): ``(rgb, depth, semantic)``."""
        W, H = self.width, self.height
        c, s = math.cos(theta), math.sin(theta)
        dx = c + self.xu * s  # forward + x_u * right, right = (sin, -cos)
        dy = s - self.xu * c

        # one slab test for walls and objects (culled: boxes wholly behind the camera)
        keep = self._cull(x, y, c, s)
        nw = int(np.searchsorted(keep, self._n_walls))
        tn, tf, xface = self._slab(x, y, dx, dy, self.boxes[keep])
        # walls: the nearest hit per column is the background
        if nw:
            k = np.argmin(tn[:, :nw], axis=1)
            sw = tn[self._cols, k]
            wk = keep[k]
            wx = xface[self._cols, k]
        else:
            sw = np.full(W, np.inf)
            wk = np.zeros(W, np.int64)
            wx = np.zeros(W, bool)
        sw = np.minimum(sw, 1e3)
        hx, hy = x + sw * dx, y + sw * dy
        # room of the wall face: step back from the hit towards the camera
        back = 0.06 / np.sqrt(dx * dx + dy * dy)
        room = self._room_at(hx - back * dx, hy - back * dy)
        u = np.where(wx, hy, hx)  # coordinate along the wall

        sw32 = sw.astype(np.float32)
        zbuf = np.minimum(self.zplane32[:, None], sw32[None, :])  # (H, W)
        is_wall = sw32[None, :] <= self.zplane32[:, None]
        idx, fac = self._background(is_wall, room, wk, wx, u, sw32, x, y, dx, dy)

        # objects nearer than the wall: z-buffered per object over its bounding rows/cols
        box = [H, 0, W, 0]  # rows/cols touched by objects, for the semantic frame
        if len(keep) > nw:
            self._draw_objects(tn[:, nw:], tf[:, nw:], xface[:, nw:], keep[nw:] - self._n_walls,
                               sw, zbuf, idx, fac, box)
        # brightness level: pattern/shade factor with distance attenuation (a depth cue),
        # quantised so one lookup in the pre-shaded uint8 palette gives the final colour
        lev = fac * (LEVELS_PER_UNIT / (1.0 + 0.06 * zbuf))
        lev = np.minimum(lev, N_LEVELS - 1).astype(np.int32)
        idx *= N_LEVELS
        idx += lev
        rgb = np.take(self._spal, idx, axis=0)  # np.take is much faster than fancy indexing
        depth = np.clip(zbuf, self.min_depth, self.max_depth)
        sem = np.zeros((H, W, 2), np.int32)
        r0, r1, c0, c1 = box
        if r0 < r1:
            sem[r0:r1, c0:c1] = np.take(self._sem_table, idx[r0:r1, c0:c1] // N_LEVELS, axis=0)
        return rgb, depth, sem

    def _cull(self, x, y, c, s):
        """Sorted indices into ``self.boxes`` of boxes not wholly behind the camera."""
        # forward coordinate of the box corner furthest along the view direction
        fx = (self._bx1 if c >= 0 else self._bx0) - x
        fy = (self._by1 if s >= 0 else self._by0) - y
        return np.flatnonzero(fx * c + fy * s > 0)

    def _draw_objects(self, on, of, oxf, ids, sw, zbuf, idx, fac, box):
        """Z-buffer every object hit in front of the wall into the frame buffers."""
        valid = on < sw[:, None]
        vis = np.flatnonzero(valid.any(axis=0))
        if len(vis) == 0:
            return
        # per-object, per-column quantities for all visible objects at once
        valid = valid[:, vis]
        k = ids[vis]
        B, T = self.o_bot[k], self.o_top[k]
        ch = self.cam_h
        s1 = np.where(valid, on[:, vis], np.inf)
        s2 = of[:, vis]
        # rows covered: the height range the ray spans inside the box meets [B, T]
        with np.errstate(divide="ignore", invalid="ignore"):  # lanes of a miss: masked below
            ylo = (B - ch) / np.where(B <= ch, s1, s2)
            yhi = (T - ch) / np.where(T >= ch, s1, s2)
        ylo = np.where(valid, ylo, np.inf)
        yhi = np.where(valid, yhi, -np.inf)
        H, W = zbuf.shape
        f = self.focal
        r0s = np.maximum(np.floor(H / 2 - yhi.max(axis=0) * f - 0.5), 0).astype(int)
        r1s = np.minimum(np.ceil(H / 2 - ylo.min(axis=0) * f - 0.5) + 1, H).astype(int)
        c0s = np.argmax(valid, axis=0)
        c1s = W - np.argmax(valid[::-1], axis=0)
        # depth beyond the front face: the top (seen from above) or underside (from below)
        caps = np.maximum(np.outer(T - ch, self.inv_neg), np.outer(B - ch, self.inv_pos))
        fs = np.where(oxf[:, vis], np.float32(_FACE_SHADE_X), np.float32(1.0))
        obj_i = self._obj0 + k
        for j in range(len(vis)):
            r0, r1, c0, c1 = int(r0s[j]), int(r1s[j]), int(c0s[j]), int(c1s[j])
            if r0 >= r1:
                continue
            yv = self.yv[r0:r1, None]
            cover = (yv >= ylo[c0:c1, j]) & (yv <= yhi[c0:c1, j])
            sj = s1[c0:c1, j]
            cap = caps[j, r0:r1, None]
            d = np.maximum(sj, cap)
            zs = zbuf[r0:r1, c0:c1]
            m = cover & (d < zs)
            # slices are views: assigning through them updates the frame buffers in place
            zs[...] = np.where(m, d, zs)
            ib = idx[r0:r1, c0:c1]
            ib[...] = np.where(m, obj_i[j], ib)
            fb = fac[r0:r1, c0:c1]
            fb[...] = np.where(m, np.where(cap > sj, np.float32(1.12), fs[c0:c1, j]), fb)
            box[0] = min(box[0], r0)
            box[1] = max(box[1], r1)
            box[2] = min(box[2], c0)
            box[3] = max(box[3], c1)

    def _bake_floor(self) -> None:
        """Texel maps of the whole floor: palette index and brightness (planks / tiles)."""
        res = FLOOR_TEXEL
        ny = int(math.ceil(self.scene.depth / res))
        nx = int(math.ceil(self.scene.width / res))
        yy, xx = np.mgrid[0:ny, 0:nx]
        px, py = (xx + 0.5) * res, (yy + 0.5) * res
        g = self.room_grid
        room = g[np.clip((py / GRID_RES).astype(int), 0, g.shape[0] - 1),
                 np.clip((px / GRID_RES).astype(int), 0, g.shape[1] - 1)]
        rs = np.maximum(room, 0)
        rot = self.r_frot[rs]
        pa, pb = np.where(rot, py, px), np.where(rot, px, py)
        per = self.r_fper[rs]
        ia, ib = np.floor(pa / per), np.floor(pb / per)
        checks = (ia + ib) % 2
        # planks: each board (index ia, staggered 1.2 m segments) gets a hashed brightness
        seg = np.floor(pb / 1.2 + 0.37 * ia)
        planks = np.sin(ia * 12.9898 + seg * 78.233) * 0.5 + 0.5
        # thin dark joints between boards/tiles
        joint = ((pa / per) % 1.0) < 0.08
        pat = np.where(self.r_fkind[rs] == 2, checks, planks) * 2 - 1
        fac = (1.0 + self.r_famp[rs] * pat) * np.where(joint, 0.85, 1.0)
        self._ftex_fac = fac.astype(np.float32).ravel()
        self._ftex_idx = (self._floor0 + np.where(room >= 0, room, self._n_rooms)).astype(
            np.int32).ravel()
        self._ftex_w, self._ftex_h, self._ftex_inv = nx, ny, np.float32(1 / res)
        self._ftex_size = nx * ny

    def _room_at(self, px, py):
        g = self.room_grid
        i = np.minimum(np.maximum((py * (1 / GRID_RES)).astype(np.int32), 0), g.shape[0] - 1)
        j = np.minimum(np.maximum((px * (1 / GRID_RES)).astype(np.int32), 0), g.shape[1] - 1)
        return np.take(self._room_flat, i * g.shape[1] + j)

    def _background(self, is_wall, room, wk, wx, u, sw, x, y, dx, dy):
        """Palette index and brightness factor (H, W) of walls, ceiling and floor."""
        H, W = is_wall.shape
        r = np.maximum(room, 0)
        h = self.cam_h + sw[None, :] * self.yv32[:, None]  # height of the wall point per pixel
        # wall pattern: parity of a*u + b*h gives stripes, bands or checks per room; the
        # per-column factors carry the wall's tint and the face shading
        phase = (self.r_wa[r] * u).astype(np.float32)[None, :] + self.r_wb32[r][None, :] * h
        phase -= np.floor(phase)
        amp = self.r_wamp[r]
        col = self.w_tint[wk] * np.where(wx, _FACE_SHADE_X, 1.0)
        hi = ((1 + amp) * col).astype(np.float32)
        lo = ((1 - amp) * col).astype(np.float32)
        fac = np.where(phase < 0.5, hi[None, :], lo[None, :])
        wains = self.r_wains32[r]
        if wains.any():
            fac += wains[None, :] * (h < 0.9)
        wall_i = np.where(room >= 0, self._wall0 + room, self._wall0 + self._n_rooms)
        idx = np.broadcast_to(wall_i.astype(np.int32)[None, :], (H, W)).copy()
        dec = self.w_decal[wk]
        in_u = (u >= dec[:, 0]) & (u <= dec[:, 1])
        if in_u.any():
            d2 = dec[:, 2].astype(np.float32)
            d3 = dec[:, 3].astype(np.float32)
            in_dec = in_u[None, :] & (h >= d2[None, :]) & (h <= d3[None, :])
            idx = np.where(in_dec, (self._dec0 + wk).astype(np.int32)[None, :], idx)
            fac = np.where(in_dec, np.float32(1.0), fac)
        f0 = self.f0
        # ceiling: rows above the horizon not covered by a wall
        ceil = is_wall[:f0]
        idx[:f0] = np.where(ceil, idx[:f0], self._ceil_i)
        fac[:f0] = np.where(ceil, fac[:f0], np.float32(1.0))
        # floor: only the band of rows where some column sees floor
        fl = ~is_wall[f0:]
        rows = np.flatnonzero(fl.any(axis=1))
        if len(rows):
            a = f0 + int(rows[0])
            fl = fl[rows[0]:]
            z = self.zplane32[a:, None]
            # floor colour and pattern are baked into texel maps; two lookups per pixel
            zi = z * self._ftex_inv
            j = (zi * dx.astype(np.float32)[None, :] + np.float32(x * self._ftex_inv)).astype(
                np.int32)
            i = (zi * dy.astype(np.float32)[None, :] + np.float32(y * self._ftex_inv)).astype(
                np.int32)
            # points off the map (never visible floor in a closed house) just clamp
            flat = i * self._ftex_w
            flat += j
            np.maximum(flat, 0, out=flat)
            np.minimum(flat, self._ftex_size - 1, out=flat)
            idx[a:] = np.where(fl, np.take(self._ftex_idx, flat), idx[a:])
            fac[a:] = np.where(fl, np.take(self._ftex_fac, flat), fac[a:])
        return idx, fac
