"""The HTML export: a self-contained page that carries no features and that a browser draws offline.

The browser test needs Chromium (``apt-get install chromium``, or point ``KGNAV_CHROMIUM`` at a
Chromium/Chrome binary); without one it is skipped.
"""

from __future__ import annotations

import base64
import json
import os
import re
import shutil
import subprocess

import numpy as np
import pytest

from kgnav import AbstractModel
from kgnav.memory.html import export_html
from kgnav.memory.synthetic import SyntheticWorld

# Any attribute that would make the browser fetch something remote (http:, https:, or //host).
REMOTE_REF = re.compile(r"""\b(?:src|href)\s*=\s*["']?\s*(?:https?:)?//""", re.IGNORECASE)
# Offline and deterministic: no proxy reachable, every host name unresolvable, no QUIC, no
# background traffic; virtual time lets the page's scripts run to completion before the dump.
CHROMIUM_FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-dev-shm-usage",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--proxy-server=127.0.0.1:9",
    "--proxy-bypass-list=<-loopback>",
    "--host-resolver-rules=MAP * ~NOTFOUND",
    "--virtual-time-budget=5000",
]


@pytest.fixture(scope="module")
def model() -> AbstractModel:
    return SyntheticWorld(seed=3, feature_dim=64).explore(steps=60, episode=0, seed=0)


@pytest.fixture(scope="module")
def page(model, tmp_path_factory):
    path = export_html(model, tmp_path_factory.mktemp("html") / "model.html")
    return path, path.read_text(encoding="utf-8")


def _data(html: str, name: str) -> list[dict]:
    """The JSON array the page hands to ``vis.DataSet`` for ``nodes`` or ``edges``."""
    pattern = {"nodes": r"var nodes = new vis\.DataSet\((\[.*?\])\);\n",
               "edges": r"var edgeData = (\[.*?\]);\n"}[name]
    found = re.search(pattern, html)
    assert found, f"no {name} data in the page"
    return json.loads(found.group(1))


def _sees(model: AbstractModel) -> int:
    return sum(1 for _, _, d in model.graph.edges(data="kind") if d == "sees")


def test_writes_one_file(page, model):
    path, html = page
    assert path.is_file() and path.name == "model.html"
    assert f"<title>Abstract Model {model.model_id}</title>" in html
    assert f"{model.n_states} states · {model.n_objects} objects" in html
    assert f"{model.n_transitions} transitions · {_sees(model)} views" in html
    assert [p.name for p in path.parent.iterdir()] == ["model.html"]  # no lib/ folder, no temp


def test_references_nothing_remote(page):
    _, html = page
    assert not REMOTE_REF.findall(html)
    assert not re.search(r"<script[^>]*\bsrc=", html, re.IGNORECASE)
    assert not re.search(r"<link\b", html, re.IGNORECASE)
    assert "vis.Network" in html and "vis-network" in html  # the library itself is inline


def test_no_features_in_page(page, model):
    _, html = page
    for sid in list(model.states())[:10]:
        encoded = base64.b64encode(np.asarray(model.features(sid), "<f4").tobytes()).decode()
        assert encoded[:24] not in html
    # vis-network alone is ~470 kB; the 60-step model must add little beyond it
    assert len(html.encode("utf-8")) < 600_000


def test_data_matches_model(page, model):
    _, html = page
    nodes = _data(html, "nodes")
    assert len(nodes) == model.n_states + model.n_objects
    assert {n["id"] for n in nodes} == set(model.graph.nodes)
    assert all(set(n) <= {"id", "x", "y", "title", "color", "label", "shape", "size"}
               for n in nodes)
    edges = _data(html, "edges")
    pairs = {(u, v) for u, v, d in model.graph.edges(data="kind") if d == "transition"}
    assert sum(e.get("kind") == "sees" for e in edges) == _sees(model)
    assert {(e["from"], e["to"]) for e in edges if e.get("kind") != "sees"} == pairs
    # floor plan: an object sits at its metric position, y flipped for the screen
    o = next(model.objects())
    drawn = next(n for n in nodes if n["id"] == o)
    d = model.graph.nodes[o]
    assert drawn["x"] == pytest.approx(d["x"] * 100, abs=0.1)
    assert drawn["y"] == pytest.approx(-d["y"] * 100, abs=0.1)
    assert drawn["label"] == d["cls"]


def test_tooltips(page, model):
    _, html = page
    nodes = {n["id"]: n for n in _data(html, "nodes")}
    s = next(s for s in model.states() if model.graph.out_degree(s) > 1)
    title = nodes[s]["title"]
    assert title.startswith(f"state {s}\n") and "episode 0" in title and "|F|" in title
    seen = {model.graph.nodes[o]["cls"] for _, o, k in model.graph.out_edges(s, keys=True)
            if k == "sees"}
    assert all(cls in title for cls in seen)
    o = next(model.objects())
    assert f"seen from {model.graph.nodes[o]['n_views']} states" in nodes[o]["title"]


def test_title_is_escaped_and_failure_keeps_old_file(model, tmp_path, monkeypatch):
    path = export_html(model, tmp_path / "m.html", title="<b>A & B</b>")
    html = path.read_text(encoding="utf-8")
    assert "&lt;b&gt;A &amp; B&lt;/b&gt;" in html and "<b>A" not in html

    import kgnav.memory.html as mod

    def boom(*args, **kwargs):
        raise RuntimeError("render failed")

    monkeypatch.setattr(mod.Network, "generate_html", boom)
    with pytest.raises(RuntimeError):
        export_html(model, path)
    assert path.read_text(encoding="utf-8") == html
    assert [p.name for p in tmp_path.iterdir()] == ["m.html"]


def test_empty_model(tmp_path):
    html = export_html(AbstractModel(feature_dim=4, model_id="empty"), tmp_path / "e.html")
    assert _data(html.read_text(encoding="utf-8"), "nodes") == []


def _no_browser(reason: str):
    # CI installs Chromium and sets KGNAV_REQUIRE_BROWSER=1: there a missing browser is a failure
    if os.environ.get("KGNAV_REQUIRE_BROWSER") == "1":
        pytest.fail(reason.replace("browser test skipped", "KGNAV_REQUIRE_BROWSER=1 is set"))
    pytest.skip(reason)


def _chromium() -> str:
    wanted = os.environ.get("KGNAV_CHROMIUM")
    if wanted:
        found = shutil.which(wanted)
        if not found:
            _no_browser(f"KGNAV_CHROMIUM={wanted!r} is not an executable; browser test skipped")
        return found
    for name in ("chromium", "chromium-browser", "google-chrome"):
        found = shutil.which(name)
        if found:
            return found
    _no_browser("no Chromium found (apt-get install chromium); browser test skipped")


def test_renders_offline_in_chromium(page, model, tmp_path):
    browser = _chromium()
    path, html = page
    result = subprocess.run(
        [browser, *CHROMIUM_FLAGS, f"--user-data-dir={tmp_path / 'profile'}", "--dump-dom",
         path.resolve().as_uri()],
        capture_output=True,
        text=True,
        timeout=90,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    status = re.search(r'<div id="kgnav-status"([^>]*)>([^<]*)</div>', result.stdout)
    assert status, f"status element missing from the dumped DOM:\n{result.stdout[:500]}"
    attrs = dict(re.findall(r'(data-\w+)="([^"]*)"', status.group(1)))
    # written by the page's afterDrawing handler: vis-network loaded and drew the graph
    assert status.group(2) == "rendered", result.stderr[-2000:]
    assert int(attrs["data-nodes"]) == model.n_states + model.n_objects
    assert int(attrs["data-edges"]) == len(_data(html, "edges"))


def test_the_remembered_floor_and_evidence_are_drawn(tmp_path):
    """A model whose states carry range profiles gets its occupancy as a picture under the
    graph (with a switch), and object tooltips give the evidence and belief."""
    import cv2

    from kgnav import Detection
    from kgnav.memory.geometry import ScanGeometry

    m = AbstractModel(2, model_id="floor", scan=ScanGeometry(90.0, 9, 5.0))
    m.add_state([1.0, 0.0], (0, 0, 0), [Detection("chair", (2.0, 0.0, 0.4))],
                ranges=np.full(9, 3.0))
    m.add_state([0.0, 1.0], (0, 0, 1.5), ranges=np.full(9, 2.0))
    html = export_html(m, tmp_path / "f.html").read_text(encoding="utf-8")
    assert 'id="kgnav-floor"' in html and "beforeDrawing" in html
    src = html.split('"src": "data:image/png;base64,')[1].split('"')[0]
    img = cv2.imdecode(np.frombuffer(base64.b64decode(src), np.uint8), cv2.IMREAD_UNCHANGED)
    assert img.shape[2] == 4 and (img[..., 3] > 0).sum() > 100  # some floor is known
    assert (img[..., :3] == 70).all(axis=2).any()  # and some obstacle
    assert "belief" in html and "missed by" in html
    plain = AbstractModel(2, model_id="plain")
    plain.add_state([1.0, 0.0], (0, 0, 0))
    assert 'id="kgnav-floor"' not in export_html(plain, tmp_path / "p.html").read_text()
