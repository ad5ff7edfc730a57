"""Top-down pictures of a stored memory against the house it describes.

A table of precision and copies says how cluttered a memory is; a picture says where: every
object of every model of one house, placed in the world with the model's ground-truth frame,
over the house drawn from above. Colour: the model it belongs to. Shape: a filled disc when it
stands for a real instance of its class (within :data:`~kgnav.benchmark.fidelity.TOLERANCE`
of one's footprint), a cross when it stands for nothing; large when the agent would trust it as
a goal (belief at least 0.5), small when not.

>>> from kgnav.sim.house import generate_house
>>> from kgnav.memory.model import AbstractModel
>>> scene = generate_house(1)
>>> img = draw_memory(scene, [], ppm=10)
>>> img.dtype, img.ndim
(dtype('uint8'), 3)

``kgnav memory-map RUN_DIR`` draws every house of a ``kgnav eval`` output directory.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from kgnav.benchmark import fidelity
from kgnav.errors import KgnavError
from kgnav.memory.model import AbstractModel
from kgnav.sim.house import Scene
from kgnav.sim.topdown import _MARGIN, draw_topdown, write_png

#: Model colours (RGB), in model-id order; more models than colours reuse them.
PALETTE = [(230, 25, 75), (60, 120, 216), (245, 130, 48), (145, 30, 180), (0, 130, 130),
           (240, 50, 230), (128, 128, 0), (0, 0, 128), (170, 110, 40), (90, 90, 90)]


def draw_memory(scene: Scene, models: Sequence[tuple[str, AbstractModel, tuple]],
                path: str | os.PathLike[str] | None = None, ppm: float = 30.0,
                placed: str | None = None) -> np.ndarray:
    """Draw the objects of ``models`` — (id, model, world pose of its frame) — over ``scene``
    from above; returns the RGB image and writes a PNG to ``path``. ``placed``: a line saying
    how the frames were chosen, for the picture's header."""
    img = draw_topdown(scene, labels=False, ppm=ppm).copy()

    def px(x, y):
        return (int(round(_MARGIN + x * ppm)), int(round(_MARGIN + (scene.depth - y) * ppm)))

    objs = []
    for k, (_mid, model, frame) in enumerate(models):
        color = PALETTE[k % len(PALETTE)]
        for cls, x, y, b, views in fidelity.model_objects(model, frame):
            real = fidelity.score_objects([(cls, x, y, b)], scene.objects)["precision"] == 1.0
            objs.append((cls, x, y, b, views))
            r = max(3, int(0.14 * ppm)) if b >= 0.5 else max(2, int(0.07 * ppm))
            if real:
                cv2.circle(img, px(x, y), r, color, -1, cv2.LINE_AA)
                cv2.circle(img, px(x, y), r, (255, 255, 255), 1, cv2.LINE_AA)
            else:
                p = np.array(px(x, y))
                cv2.line(img, tuple(p - r), tuple(p + r), color, 2, cv2.LINE_AA)
                cv2.line(img, (p[0] - r, p[1] + r), (p[0] + r, p[1] - r), color, 2, cv2.LINE_AA)
    s = fidelity.score_objects(objs, scene.objects)
    lines = [f"{scene.name}: {len(models)} model(s)",
             f"{len(objs)} objects, {len(scene.objects)} real",
             f"precision {s['precision']}, trusted {s['trusted_precision']}",
             f"copies {s['copies']}",
             "disc: real, cross: phantom, large: trusted"] + ([placed] if placed else [])
    band = np.full((14 * len(lines) + 6, img.shape[1], 3), 255, np.uint8)
    for i, text in enumerate(lines):
        cv2.putText(band, text, (4, 13 + 14 * i), cv2.FONT_HERSHEY_SIMPLEX, 0.38, (0, 0, 0), 1,
                    cv2.LINE_AA)
    img = np.vstack([band, img])
    if path is not None:
        write_png(img, path)
    return img


FRAMES = ("own", "start")
_PLACED = {"own": "each model in its own frame (fitted to the truth of its states)",
           "start": "each model in its creating episode's start frame"}


def run_memory(run_dir: str | os.PathLike[str], variant: str = "si", frame: str = "own"):
    """The memory ``variant`` left in a ``kgnav eval`` output directory of kgnav's own
    houses, house by house: a list of ``(scene, [(model id, model, world frame), ...])``
    (``pre-explored`` for the hp/sp memory). ``frame``: ``"own"`` places each model by the
    fit of its states to where they truly were (:func:`kgnav.benchmark.fidelity.alignment`,
    from the true poses the run kept beside the memory; a model without them stays in its
    start frame), ``"start"`` in the start frame of the episode that created it. One-line
    errors (:class:`KgnavError`) for a directory that is no such output, another
    environment's, or one without that memory."""
    return _run_memory(run_dir, variant, frame)[0]


def _run_memory(run_dir: str | os.PathLike[str], variant: str, frame: str):
    """:func:`run_memory`, and whether the models were placed by kept true poses (False in
    the start frame, or for a run that kept none)."""
    from kgnav.benchmark.runner import _house_of
    from kgnav.memory.store import ModelStore
    from kgnav.sim.sources import scene_source

    run = Path(run_dir)
    try:
        cfg = json.loads((run / "config.json").read_text(encoding="utf-8"))
        env = cfg.get("env", "kgnav")
        if env != "kgnav":
            # the ground truth needed (floor plans, episode starts) is kgnav's own scenes'
            raise KgnavError(f"{run}: a run on environment {env!r}; only runs on kgnav's own "
                             "simulator can be read against their houses")
        source = scene_source(cfg["split"], cfg.get("scenes_dir"))
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise KgnavError(f"{run}: not a kgnav eval output directory ({exc})") from None
    store_dir = next((p for p in (run / "memory" / variant, run / "memory" / f"{variant}.lbug",
                                  run / "memory" / variant / "models.lbug") if p.is_file()),
                     run / "memory" / variant)  # a database (eval --store ladybug), or files
    if not store_dir.exists():
        have = sorted(p.name.removesuffix(".lbug") for p in (run / "memory").glob("*")
                      if p.is_dir() or p.suffix == ".lbug")
        raise KgnavError(f"{store_dir}: no stored memory for {variant!r} "
                         f"(there: {', '.join(have) or 'none'})")
    if frame not in FRAMES:
        raise KgnavError(f"frame must be one of {', '.join(FRAMES)}, got {frame!r}")
    models, problems = ModelStore(store_dir).load_all()
    if problems:
        raise KgnavError(f"{store_dir}: {problems[0]}")
    truth = {} if frame == "start" else _truth(run, variant)
    houses = []
    for k in range(len(source)):
        scene = source.scene(k)
        mine = sorted((mid, m) for mid, m in models.items() if _house_of(mid) == scene.name)
        if not mine:
            continue
        episodes = source.episodes(k, cfg.get("episodes"))
        starts = [(m, episodes[0 if (tag := mid.rpartition("-")[2]) == "pre"
                                 else int(tag[1:])].start) for mid, m in mine]
        placed = fidelity.aligned_frames(starts, truth.get(scene.name, {}))
        houses.append((scene, [(mid, m, at) for (mid, _), (m, at) in
                               zip(mine, placed, strict=True)]))
    if models and not houses:
        raise KgnavError(f"{store_dir}: none of its {len(models)} models belongs to a house of "
                         f"split {cfg['split']!r}")
    return houses, bool(truth)


def _truth(run: Path, variant: str) -> dict:
    """The true poses of the stored states a run kept beside ``variant``'s memory (empty for
    a run made before they were kept)."""
    from kgnav.benchmark.runner import read_truth, truth_path

    return read_truth(run / "memory" / "pre-explored" / "truth.json"
                      if variant == "pre-explored" else truth_path(run, variant))


def draw_run(run_dir: str | os.PathLike[str], variant: str = "si",
             out: str | os.PathLike[str] | None = None, ppm: float = 30.0,
             frame: str = "own") -> list[Path]:
    """Draw the memory ``variant`` left in a ``kgnav eval`` output directory, one PNG per
    house (``pre-explored`` for the hp/sp memory) into ``out`` (default: ``RUN/memory``),
    each model placed as ``frame`` says (:func:`run_memory`). Returns the paths written."""
    out_dir = Path(out) if out is not None else Path(run_dir) / "memory"
    written = []
    houses, kept = _run_memory(run_dir, variant, frame)
    placed = _PLACED[frame] if kept or frame == "start" else \
        _PLACED["start"] + " (the run kept no true poses)"
    for scene, framed in houses:
        path = out_dir / f"{variant}_{scene.name}.png"
        draw_memory(scene, framed, path, ppm, placed=placed)
        written.append(path)
    return written
