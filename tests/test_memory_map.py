"""Top-down pictures of a memory: real objects are discs, phantoms crosses, in world frame."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from kgnav.benchmark.memory_map import PALETTE, draw_memory, draw_run
from kgnav.cli import main
from kgnav.errors import KgnavError
from kgnav.memory.model import AbstractModel, Detection
from kgnav.sim.house import generate_house
from kgnav.sim.topdown import _MARGIN, draw_topdown

PPM = 40.0
COLOUR = np.array(PALETTE[0])


def _px(scene, img, x, y):
    """Row and column of world (x, y) in a memory picture (below its text band)."""
    band = img.shape[0] - draw_topdown(scene, labels=False, ppm=PPM).shape[0]
    return (int(round(_MARGIN + (scene.depth - y) * PPM)) + band,
            int(round(_MARGIN + x * PPM)))


def _model(cls, xy):
    m = AbstractModel(2, model_id="val_00-e0")
    for k in range(2):  # seen twice: trusted, drawn large
        m.add_state([1.0, float(k)], (0, 0, 0), [Detection(cls, (xy[0], xy[1], 0.4))])
    return m


def test_a_real_object_is_a_disc_where_its_frame_puts_it_in_the_world():
    scene = generate_house(1)
    real = max(scene.objects, key=lambda o: (o.x1 - o.x0) * (o.y1 - o.y0))
    cx, cy = (real.x0 + real.x1) / 2, (real.y0 + real.y1) / 2
    frame = (1.0, 2.0, math.pi / 2)  # the model's origin in the world, turned 90° left
    local = (cy - 2.0, -(cx - 1.0))  # world (cx, cy) seen from that frame
    img = draw_memory(scene, [("val_00-e0", _model(real.cls, local), frame)], ppm=PPM)
    r, c = _px(scene, img, cx, cy)
    rad = int(0.14 * PPM)
    assert (img[r, c] == COLOUR).all() and (img[r, c + rad - 2] == COLOUR).all()
    # with the identity frame the same object lands elsewhere and is a phantom there
    img2 = draw_memory(scene, [("val_00-e0", _model(real.cls, local), (0.0, 0.0, 0.0))],
                       ppm=PPM)
    assert not (img2[r, c] == COLOUR).all()


def test_a_phantom_is_a_cross(tmp_path):
    scene = generate_house(1)
    # a bed 0.3 m outside the house: no bed there
    img = draw_memory(scene, [("val_00-e0", _model("bed", (-0.3, -0.3)), (0.0, 0.0, 0.0))],
                      tmp_path / "m.png", ppm=PPM)
    r, c = _px(scene, img, -0.3, -0.3)
    rad = int(0.14 * PPM)
    assert (img[r, c] == COLOUR).all()  # the arms cross at the centre
    assert (img[r - rad + 1, c - rad + 1] == COLOUR).all()  # a diagonal arm
    assert not (img[r, c + rad - 2] == COLOUR).all()  # no disc around it
    assert (tmp_path / "m.png").stat().st_size > 0


def test_a_directory_that_is_not_a_run_is_one_line(tmp_path, capsys):
    with pytest.raises(KgnavError, match="not a kgnav eval output directory"):
        draw_run(tmp_path)
    (tmp_path / "config.json").write_text(json.dumps({"split": "val-small", "episodes": 2}))
    with pytest.raises(SystemExit) as exc:
        main(["memory-map", str(tmp_path), "--variant", "si"])
    assert exc.value.code == 1
    err = capsys.readouterr().err
    assert "no stored memory for 'si'" in err and len(err.strip().splitlines()) == 1


def test_a_run_it_cannot_draw_says_so_in_one_line(tmp_path, capsys):
    """Another environment's run, or a memory of houses the split does not hold, is a one-line
    error, not a silent success that drew nothing."""
    (tmp_path / "config.json").write_text(json.dumps({"split": "val", "env": "miniworld"}))
    with pytest.raises(KgnavError, match="environment 'miniworld'"):
        draw_run(tmp_path)
    (tmp_path / "config.json").write_text(json.dumps({"split": "val-small", "episodes": 2}))
    store = tmp_path / "memory" / "si"
    store.mkdir(parents=True)
    m = _model("bed", (1.0, 1.0))
    m.model_id = "elsewhere-e000"
    m.save(store / "elsewhere-e000.graphml")
    with pytest.raises(SystemExit) as exc:
        main(["memory-map", str(tmp_path)])
    assert exc.value.code == 1
    err = capsys.readouterr().err
    assert "none of its 1 models belongs to a house of split 'val-small'" in err
    assert len(err.strip().splitlines()) == 1


def test_goal_floors_calibrates_per_class_on_a_runs_memory(tmp_path, capsys):
    """`kgnav goal-floors`: the stored objects' confidence split into real and phantom by
    ground truth (in the world, through the model's frame), and a floor for a class whose
    real objects are surer than its phantoms, none where they overlap."""
    from kgnav.benchmark import fidelity
    from kgnav.common import se2
    from kgnav.sim.sources import scene_source

    source = scene_source("val-small", None)
    scene = source.scene(0)
    start = source.episodes(0, 2)[0].start
    to_model = se2.inverse(start)
    m = AbstractModel(2, model_id=f"{scene.name}-e000")
    plants = [o for o in scene.objects if o.cls == "plant"]
    chairs = [o for o in scene.objects if o.cls == "chair"]
    assert len(plants) >= 3 and len(chairs) >= 3
    dets = []
    for k, o in enumerate(plants):  # real plants seen surely, phantom plants less so
        dets.append(("plant", (o.x0 + o.x1) / 2, (o.y0 + o.y1) / 2, 0.9 + 0.01 * k))
        dets.append(("plant", -5.0 - 3 * k, -5.0, 0.6))
    for k, o in enumerate(chairs):  # chairs: phantoms as sure as the real ones
        dets.append(("chair", (o.x0 + o.x1) / 2, (o.y0 + o.y1) / 2, 0.7))
        dets.append(("chair", -5.0 - 3 * k, -9.0, 0.75))
    for k in range(3):
        m.add_state([1.0, float(k)], (0, 0, 0),
                    [Detection(c, (*se2.apply_to_point(to_model, x, y), 0.4), score=s)
                     for c, x, y, s in dets])
    stats = fidelity.confidence_by_class([(m, start)], scene.objects)
    assert len(stats["plant"]["real"]) == len(plants)
    assert len(stats["plant"]["phantom"]) == len(plants)
    assert sorted(stats["chair"]["phantom"]) == pytest.approx([0.75] * len(chairs))
    (tmp_path / "config.json").write_text(json.dumps({"split": "val-small", "episodes": 2}))
    (tmp_path / "memory" / "si").mkdir(parents=True)
    m.save(tmp_path / "memory" / "si" / f"{m.model_id}.graphml")
    def run(*args):
        with pytest.raises(SystemExit) as exc:
            main(["goal-floors", str(tmp_path), *args])
        return exc.value.code

    assert run("--json") == 0
    out = json.loads(capsys.readouterr().out)
    assert out["floors"] == {"plant": 0.9}
    assert out["classes"]["chair"]["phantom"]["n"] == len(chairs)
    assert run() == 0
    assert "--goals remembered_floor=plant:0.90" in capsys.readouterr().out
    # no true poses kept beside this memory: its own frame is its start frame
    assert run("--frame", "start", "--json") == 0
    assert json.loads(capsys.readouterr().out)["floors"] == {"plant": 0.9}
    assert run("--frame", "world") == 2
    assert run("--variant", "sp") == 1  # no such memory: one line
    assert "no stored memory for 'sp'" in capsys.readouterr().err


def test_goal_floors_prints_class_names_from_files_as_text(tmp_path, capsys):
    """A class name in a model file is printed as it is, never as rich markup."""
    from kgnav.sim.sources import scene_source

    scene = scene_source("val-small", None).scene(0)
    m = AbstractModel(2, model_id=f"{scene.name}-e000", classes=("[red]x[/red]", "chair"))
    for k in range(3):
        m.add_state([1.0, float(k)], (0, 0, 0), [Detection("[red]x[/red]", (-9.0, -9.0, 0.4))])
    (tmp_path / "config.json").write_text(json.dumps({"split": "val-small", "episodes": 2}))
    (tmp_path / "memory" / "si").mkdir(parents=True)
    m.save(tmp_path / "memory" / "si" / f"{m.model_id}.graphml")
    with pytest.raises(SystemExit) as exc:
        main(["goal-floors", str(tmp_path)])
    assert exc.value.code == 0
    assert "[red]x[/red]" in capsys.readouterr().out
