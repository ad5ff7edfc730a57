"""Top-down pictures of a scene: rooms, walls, objects, an episode's start, goal instances,
trajectory and (optionally) the agent's own map overlaid. PNG via OpenCV.

>>> from kgnav.sim.house import generate_house
>>> img = draw_topdown(generate_house(1))
>>> img.dtype, img.ndim
(dtype('uint8'), 3)
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence

import cv2
import numpy as np

from kgnav.sim.episodes import Episode
from kgnav.sim.house import AGENT_RADIUS, Scene
from kgnav.sim.metrics import SUCCESS_DISTANCE
from kgnav.sim.navmesh import NavMap

_MARGIN = 20  # px


def draw_topdown(
    scene: Scene,
    path: str | os.PathLike[str] | None = None,
    episode: Episode | None = None,
    trajectory: Sequence[Sequence[float]] | None = None,
    agent_map: np.ndarray | None = None,
    map_resolution: float = 0.05,
    map_origin: tuple[float, float] = (0.0, 0.0),
    ppm: float = 40.0,
    labels: bool = True,
) -> np.ndarray:
    """Draw ``scene`` from above; returns an RGB uint8 image and writes a PNG to ``path``.

    ``trajectory``: world poses (x, y[, theta]) in order. ``agent_map``: a 2-D array in the
    *episode-start frame* (the frame of the ``pose`` observation; rows = y, cell (i, j) centred at
    ``map_origin + ((j + .5) * res, (i + .5) * res)``); non-zero cells are tinted blue. Its
    placement needs ``episode`` (the start pose).
    """
    W = int(round(scene.width * ppm)) + 2 * _MARGIN
    H = int(round(scene.depth * ppm)) + 2 * _MARGIN

    def px(x, y):
        return (int(round(_MARGIN + x * ppm)), int(round(_MARGIN + (scene.depth - y) * ppm)))

    img = np.full((H, W, 3), 40, np.uint8)
    nav = NavMap.from_scene(scene)
    for r in scene.rooms:
        c = tuple(int(0.55 * v + 0.45 * 255) for v in r.floor_color)
        cv2.rectangle(img, px(r.x0, r.y1), px(r.x1, r.y0), c, -1)
    # non-navigable floor (too close to walls/objects for the agent's centre) is shaded
    grid = cv2.resize(nav.grid.astype(np.uint8)[::-1],
                      (int(round(nav.grid.shape[1] * nav.resolution * ppm)),
                       int(round(nav.grid.shape[0] * nav.resolution * ppm))),
                      interpolation=cv2.INTER_NEAREST)
    gh, gw = min(grid.shape[0], H - 2 * _MARGIN), min(grid.shape[1], W - 2 * _MARGIN)
    inner = img[_MARGIN:_MARGIN + gh, _MARGIN:_MARGIN + gw]
    blocked = grid[:gh, :gw] == 0
    inner[blocked] = (inner[blocked] * 0.8).astype(np.uint8)

    goal_ids = set()
    if episode is not None:
        goal_ids = {o.id for o in scene.objects_of(episode.goal_class)}
        region = nav.goal_region(episode.goal_class, SUCCESS_DISTANCE)
        reg = cv2.resize(region.astype(np.uint8)[::-1], (gw, gh), interpolation=cv2.INTER_NEAREST)
        inner[reg[:gh, :gw] > 0] = (inner[reg[:gh, :gw] > 0] * 0.6 + np.array([255, 200, 60])
                                    * 0.4).astype(np.uint8)
    if agent_map is not None and episode is not None:
        _overlay_agent_map(img, agent_map, map_resolution, map_origin, episode.start, scene, ppm)
    for w in scene.walls:
        cv2.rectangle(img, px(w.x0, w.y1), px(w.x1, w.y0), (25, 25, 25), -1)
    for o in scene.objects:
        cv2.rectangle(img, px(o.x0, o.y1), px(o.x1, o.y0), tuple(int(v) for v in o.color), -1)
        edge = (230, 30, 30) if o.id in goal_ids else (0, 0, 0)
        cv2.rectangle(img, px(o.x0, o.y1), px(o.x1, o.y0), edge, 3 if o.id in goal_ids else 1)
    if labels:
        for r in scene.rooms:
            p = px(r.x0 + 0.15, r.y1 - 0.35)
            cv2.putText(img, r.kind.replace("_", " "), p, cv2.FONT_HERSHEY_SIMPLEX, 0.4,
                        (20, 20, 20), 1, cv2.LINE_AA)
        for o in scene.objects:
            if o.id in goal_ids:
                cv2.putText(img, o.cls, px(o.x0, o.y0 - 0.25), cv2.FONT_HERSHEY_SIMPLEX, 0.4,
                            (200, 0, 0), 1, cv2.LINE_AA)
    if trajectory is not None and len(trajectory) > 1:
        pts = np.array([px(p[0], p[1]) for p in trajectory], np.int32)
        cv2.polylines(img, [pts], False, (20, 60, 230), 2, cv2.LINE_AA)
    if episode is not None:
        _agent(img, px, episode.start, (0, 170, 0), ppm)
    if trajectory is not None and len(trajectory) > 0 and len(trajectory[-1]) > 2:
        _agent(img, px, trajectory[-1], (20, 60, 230), ppm)
    if labels and episode is not None:
        cv2.putText(img, f"{episode.episode_id}  goal: {episode.goal_class}", (6, 14),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
    if path is not None:
        write_png(img, path)
    return img


def write_png(img: np.ndarray, path: str | os.PathLike[str]) -> None:
    """Write an RGB image as a PNG, creating its directory; OSError if it cannot."""
    path = os.fspath(path)
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    if not cv2.imwrite(path, img[..., ::-1]):
        raise OSError(f"{path}: could not write PNG")


def _agent(img, px, pose, color, ppm) -> None:
    x, y, t = pose[0], pose[1], pose[2]
    c = px(x, y)
    cv2.circle(img, c, max(int(AGENT_RADIUS * ppm), 3), color, 2, cv2.LINE_AA)
    tip = px(x + 0.4 * math.cos(t), y + 0.4 * math.sin(t))
    cv2.line(img, c, tip, color, 2, cv2.LINE_AA)


def _overlay_agent_map(img, amap, res, origin, start, scene, ppm) -> None:
    """Blend the agent's map (episode-start frame) onto the image in blue."""
    sx, sy, st = start
    c, s = math.cos(st), math.sin(st)
    # map pixel (j, i) -> start frame (ox + (j+.5)res, oy + (i+.5)res) -> world -> image
    # u = M + x*ppm, v = M + (D - y)*ppm, x = sx + c*a - s*b, y = sy + s*a + c*b
    a0, b0 = origin[0] + 0.5 * res, origin[1] + 0.5 * res
    A = np.array([[c * res * ppm, -s * res * ppm, 0.0], [-s * res * ppm, -c * res * ppm, 0.0]])
    A[0, 2] = _MARGIN + (sx + c * a0 - s * b0) * ppm
    A[1, 2] = _MARGIN + (scene.depth - (sy + s * a0 + c * b0)) * ppm
    mask = cv2.warpAffine((np.asarray(amap) != 0).astype(np.uint8), A,
                          (img.shape[1], img.shape[0]), flags=cv2.INTER_NEAREST)
    m = mask > 0
    img[m] = (img[m] * 0.55 + np.array([60, 110, 255]) * 0.45).astype(np.uint8)
