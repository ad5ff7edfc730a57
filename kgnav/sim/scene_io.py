"""Versioned JSON files for scenes: save (atomic), load (validated).

Format: a JSON object with ``"format": "kgnav-scene"``, ``"version": 1`` and the fields of
:class:`~kgnav.sim.house.Scene`. A missing, corrupt, foreign or other-version file raises
:class:`~kgnav.errors.SceneFileError` naming the file and the reason.

>>> import tempfile, os
>>> from kgnav.sim.house import generate_house
>>> p = os.path.join(tempfile.mkdtemp(), "s.json")
>>> save_scene(generate_house(5), p)
>>> load_scene(p) == generate_house(5)
True
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import asdict
from typing import Any

from kgnav.common.atomic import atomic_open
from kgnav.common.classes import OBJECT_CLASSES
from kgnav.errors import SceneFileError
from kgnav.sim.house import (
    ROOM_KINDS,
    Door,
    ObjectInstance,
    Room,
    Scene,
    Texture,
    Wall,
)

SCENE_FORMAT = "kgnav-scene"
SCENE_VERSION = 1


def atomic_write_text(path: str | os.PathLike[str], text: str) -> None:
    """Write ``text`` (UTF-8) so that a failed write never destroys the previous file."""
    with atomic_open(path, "wb") as fh:
        fh.write(text.encode("utf-8"))


def scene_to_dict(scene: Scene) -> dict[str, Any]:
    """Plain JSON-able dict of a scene, with the format header."""
    return {
        "format": SCENE_FORMAT,
        "version": SCENE_VERSION,
        "generator": scene.generator,
        "name": scene.name,
        "seed": scene.seed,
        "width": scene.width,
        "depth": scene.depth,
        "wall_height": scene.wall_height,
        "rooms": [asdict(r) for r in scene.rooms],
        "doors": [asdict(d) for d in scene.doors],
        "walls": [asdict(w) for w in scene.walls],
        "objects": [asdict(o) for o in scene.objects],
    }


def save_scene(scene: Scene, path: str | os.PathLike[str]) -> None:
    """Save ``scene`` as a versioned JSON file (atomically)."""
    atomic_write_text(path, json.dumps(scene_to_dict(scene), separators=(",", ":")))


def read_json(path: str | os.PathLike[str]) -> Any:
    """Parse a JSON file, turning every way it can fail into a :class:`SceneFileError`."""
    path = os.fspath(path)
    try:
        with open(path, encoding="utf-8") as f:
            return json.load(f)
    except FileNotFoundError:
        raise SceneFileError(path, "file not found") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise SceneFileError(path, f"not valid JSON ({e})") from None
    except OSError as e:
        raise SceneFileError(path, f"cannot read ({e.strerror or e})") from None


def load_scene(path: str | os.PathLike[str]) -> Scene:
    """Load and validate a scene file; :class:`SceneFileError` if it cannot be used."""
    return scene_from_dict(read_json(path), os.fspath(path))


def check_header(data: Any, path: str, fmt: str, version: int) -> None:
    """Raise SceneFileError unless ``data`` is a dict with the given format and version."""
    if not isinstance(data, dict) or "format" not in data:
        raise SceneFileError(path, f"not a {fmt} file (no 'format' header)")
    if data["format"] != fmt:
        raise SceneFileError(path, f"not a {fmt} file (format is {data['format']!r})")
    if data.get("version") != version:
        raise SceneFileError(
            path, f"unsupported {fmt} version {data.get('version')!r} (this kgnav reads {version})"
        )


def scene_from_dict(data: Any, path: str = "<scene>") -> Scene:
    """Build a :class:`Scene` from its dict form, validating every field."""
    check_header(data, path, SCENE_FORMAT, SCENE_VERSION)
    try:
        return _build(data, path)
    except SceneFileError:
        raise
    except (KeyError, TypeError, ValueError, IndexError) as e:
        what = f"missing field {e}" if isinstance(e, KeyError) else str(e)
        raise SceneFileError(path, f"invalid scene: {what}") from None


def _num(v, what) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise ValueError(f"{what} must be a finite number, got {v!r}")
    return float(v)


def _color(v, what) -> tuple[int, int, int]:
    if not isinstance(v, list | tuple) or len(v) != 3:
        raise ValueError(f"{what} must be 3 integers")
    out = tuple(int(c) for c in v)
    if any(c < 0 or c > 255 for c in out):
        raise ValueError(f"{what} out of 0..255: {v!r}")
    return out  # type: ignore[return-value]


def _rect(d, what) -> tuple[float, float, float, float]:
    x0, y0, x1, y1 = (_num(d[k], f"{what}.{k}") for k in ("x0", "y0", "x1", "y1"))
    if not (x0 < x1 and y0 < y1):
        raise ValueError(f"{what} has an empty rectangle ({x0}, {y0}, {x1}, {y1})")
    return x0, y0, x1, y1


def _build(d: dict, path: str) -> Scene:
    width, depth = _num(d["width"], "width"), _num(d["depth"], "depth")
    if not (0 < width <= 100 and 0 < depth <= 100):
        raise ValueError(f"house size {width} x {depth} m out of range")
    rooms = []
    for i, r in enumerate(d["rooms"]):
        if r["kind"] not in ROOM_KINDS:
            raise ValueError(f"room {i}: unknown kind {r['kind']!r}")
        if int(r["id"]) != i:
            raise ValueError(f"room {i}: id {r['id']!r} out of order")
        rooms.append(
            Room(
                i,
                r["kind"],
                *_rect(r, f"room {i}"),
                _color(r["wall_color"], f"room {i} wall_color"),
                _color(r["floor_color"], f"room {i} floor_color"),
                Texture(**r["wall_texture"]),
                Texture(**r["floor_texture"]),
            )
        )
    if not rooms:
        raise ValueError("no rooms")
    n = len(rooms)
    doors = []
    for i, dr in enumerate(d["doors"]):
        a, b = int(dr["a"]), int(dr["b"])
        if not (0 <= a < n and 0 <= b < n):
            raise ValueError(f"door {i} joins unknown rooms {a}, {b}")
        doors.append(Door(a, b, *_rect(dr, f"door {i}")))
    walls = []
    for i, w in enumerate(d["walls"]):
        dec = w.get("decal")
        if dec is not None:
            if not isinstance(dec, list | tuple) or len(dec) != 7:
                raise ValueError(f"wall {i}: decal must have 7 numbers")
            dec = (*(_num(v, f"wall {i} decal") for v in dec[:4]), *_color(dec[4:], "decal"))
        walls.append(Wall(*_rect(w, f"wall {i}"), _num(w.get("tint", 1.0), "tint"), dec))
    objects = []
    for i, o in enumerate(d["objects"]):
        if o["cls"] not in OBJECT_CLASSES:
            raise ValueError(f"object {i}: unknown class {o['cls']!r}")
        if int(o["id"]) != i + 1:
            raise ValueError(f"object {i}: id {o['id']!r} (ids must be 1..N in order)")
        if not 0 <= int(o["room"]) < n:
            raise ValueError(f"object {i}: unknown room {o['room']!r}")
        bottom, top = _num(o["bottom"], "bottom"), _num(o["top"], "top")
        if not 0 <= bottom < top:
            raise ValueError(f"object {i}: bad heights bottom={bottom} top={top}")
        objects.append(
            ObjectInstance(
                i + 1,
                o["cls"],
                int(o["room"]),
                *_rect(o, f"object {i}"),
                bottom,
                top,
                _color(o["color"], f"object {i} color"),
            )
        )
    return Scene(
        name=str(d["name"]),
        seed=int(d["seed"]),
        width=width,
        depth=depth,
        rooms=tuple(rooms),
        doors=tuple(doors),
        walls=tuple(walls),
        objects=tuple(objects),
        wall_height=_num(d.get("wall_height", 2.5), "wall_height"),
        generator=str(d.get("generator", "")),
    )
