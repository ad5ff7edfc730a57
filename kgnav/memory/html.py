"""Export an Abstract Model as one self-contained, offline HTML page (vis-network via pyvis).

The page reads as a floor plan: every state is drawn at its ``(x, y)`` pose (nudged a little
along its heading, so the states of one spot that differ only by a turn form a small ring instead
of a single dot), every object at its mean position in its class's colour, transitions as arrows
coloured and labelled by action, and the observations (*sees* edges, state → object) as faint
dashed lines. Physics is off and the nodes are fixed, so what you see is the model's geometry.
Hovering a node shows its details; a header gives the model id, counts, a legend and a switch for
the sees edges (shown by default only when there are at most :data:`SEES_SHOWN_MAX`).

The file needs no network at all: vis-network is inlined from pyvis's bundled copy and kgnav's
own template (``kgnav/templates/graph.html``) loads nothing else — pyvis's stock template pulls
bootstrap from a CDN even in ``cdn_resources="in_line"`` mode.

>>> import pathlib, tempfile
>>> from kgnav.memory.synthetic import SyntheticWorld
>>> model = SyntheticWorld(seed=1, feature_dim=16).explore(steps=20)
>>> out = export_html(model, pathlib.Path(tempfile.mkdtemp()) / "model.html")
>>> html = out.read_text(encoding="utf-8")
>>> "new vis.Network(" in html, "cdn" in html.lower(), len(html) < 600_000
(True, False, True)
"""

from __future__ import annotations

import colorsys
import copy
import math
import os
import pathlib
from collections import Counter, defaultdict

import jinja2
import numpy as np
import pyvis
from pyvis.network import Network

from kgnav.common.atomic import atomic_open
from kgnav.memory.evidence import belief, object_evidence
from kgnav.memory.model import SEES, AbstractModel
from kgnav.memory.query import occupancy, visible_classes

#: Metres → pixels (vis-network's canvas units); a 0.25 m forward step is 25 px.
PX_PER_M = 100.0
#: States are drawn this far (m) ahead of their position along their heading (see module doc).
HEADING_OFFSET_M = 0.08
#: Above this many sees edges they start hidden (the header's checkbox shows them).
SEES_SHOWN_MAX = 1000

TEMPLATE_DIR = pathlib.Path(__file__).with_name("templates")
TEMPLATE = "graph.html"

STATE_COLOR = {"background": "#9fb3c8", "border": "#4a5d73"}
#: States a loop closure placed (kgnav.memory.posegraph): kept by the optimisation, or rejected
CLOSURE_COLOR = {True: {"background": "#2e9e44", "border": "#14532d"},
                 False: {"background": "#d62728", "border": "#7f1d1d"}}
ACTION_COLORS = {
    "move_forward": "#4a5d73",
    "turn_left": "#2b8cbe",
    "turn_right": "#e6550d",
    "stop": "#111111",
}
#: Actions and classes outside the tables above.
OTHER_COLOR = "#999999"
#: Short arrow labels (the tooltip and the legend give the full names); others are shown as is.
ACTION_LABELS = {"move_forward": "fwd", "turn_left": "left", "turn_right": "right"}
SEES_OPACITY = 0.3
#: Merged into every sees edge by the page's script, so it is not repeated per edge.
SEES_STYLE = {
    "dashes": [3, 4],
    "width": 0.6,
    "arrows": {"to": {"enabled": False}},
    "smooth": False,
    "selectionWidth": 0.5,
}

_OPTIONS = {
    "physics": {"enabled": False},
    # improvedLayout runs a layout pass meant for nodes without positions; ours all have one.
    "layout": {"improvedLayout": False},
    "interaction": {"hover": True, "tooltipDelay": 120, "multiselect": True},
    "nodes": {
        "shape": "dot",
        "size": 3.5,
        "borderWidth": 1,
        "fixed": True,
        "font": {"size": 11, "face": "system-ui, sans-serif", "strokeWidth": 3},
    },
    "edges": {
        # straight edges: cheaper to draw for thousands, and truer to a floor plan
        "smooth": False,
        "width": 1,
        "arrows": {"to": {"enabled": True, "scaleFactor": 0.35}},
        # labels are drawn only once zoomed in (font size x zoom >= drawThreshold - 1): when
        # the whole plan is in view they would be an unreadable smear
        "font": {"size": 8, "align": "middle", "strokeWidth": 2, "color": "#333"},
        "scaling": {"label": {"drawThreshold": 13}},
    },
}


#: Kelly's colours of maximum contrast (less white, black and the greys) and four more; classes
#: past the palette's end get golden-angle hues.
CLASS_PALETTE = (
    "#e6a100", "#875692", "#f38400", "#6fa8dc", "#be0032", "#c2b280", "#008856", "#e68fac",
    "#0067a5", "#f99379", "#604e97", "#b3446c", "#c9c000", "#882d17", "#8db600", "#654522",
    "#e25822", "#2b3d26", "#17becf", "#ff1493", "#4b0082", "#7f7f00", "#00a087", "#a0522d",
)


def class_color(index: int) -> str:
    """A stable colour for the ``index``-th class of a model's vocabulary.

    The colour of a class depends only on its position in ``model.classes``, so one class looks
    the same in every export of models sharing a vocabulary.

    >>> class_color(0), class_color(24)
    ('#e6a100', '#cbcc3e')
    """
    if 0 <= index < len(CLASS_PALETTE):
        return CLASS_PALETTE[index]
    hue = (index * 137.50776405) % 360.0 / 360.0
    r, g, b = colorsys.hls_to_rgb(hue, 0.52, 0.58)
    return "#{:02x}{:02x}{:02x}".format(*(round(c * 255) for c in (r, g, b)))


def _vis_js_path() -> str:
    """Path of pyvis's bundled vis-network (newest bundled version), relative to its templates."""
    root = pathlib.Path(pyvis.__file__).with_name("templates")
    found = sorted(root.glob("lib/vis-*/vis-network.min.js"))
    if not found:
        raise RuntimeError(f"pyvis at {root} bundles no vis-network.min.js")
    return found[-1].relative_to(root).as_posix()


def _xy(x: float, y: float) -> tuple[float, float]:
    # screen y grows downwards: flip it so the page shows the model frame as a plan from above
    return round(x * PX_PER_M, 1), round(-y * PX_PER_M, 1)


def _state_node(model: AbstractModel, sid: str, d: dict) -> dict:
    x, y, theta = d["x"], d["y"], d["theta"]
    seen = visible_classes(model, sid)
    norm = float(np.linalg.norm(d["features"]))
    title = (
        f"state {sid}\n"
        f"pose x={x:.2f} m  y={y:.2f} m  θ={math.degrees(theta):.0f}°\n"
        f"episode {d['episode']}  step {d['step']}\n"
        f"sees {', '.join(seen) if seen else '(nothing)'}\n"
        f"|F|₂ = {norm:.4g}"
    )
    px, py = _xy(x + HEADING_OFFSET_M * math.cos(theta), y + HEADING_OFFSET_M * math.sin(theta))
    return {"id": sid, "x": px, "y": py, "title": title, "color": STATE_COLOR}


def _closures(model: AbstractModel) -> dict[str, list[tuple[int, bool, str | None]]]:
    """State id -> the loop closures that placed it: (episode, kept, the stored state it is
    linked to or None) each."""
    out: dict[str, list[tuple[int, bool, str | None]]] = defaultdict(list)
    for c in model.loop_closures:
        sid = model.known_node(c["state"])
        if sid is not None:
            to = model.known_node(c["to"]) if "to" in c else None
            out[sid].append((c["episode"], c["kept"], to))
    return dict(out)


def _object_node(oid: str, d: dict, colour: str, ev=None) -> dict:
    title = (
        f"object {oid}: {d['cls']}\n"
        f"position x={d['x']:.2f} m  y={d['y']:.2f} m  z={d['z']:.2f} m\n"
        f"seen from {d['n_views']} states ({d['n_obs']} observations)"
    )
    if ev is not None:
        title += (f"\nin {ev.n_episodes} episodes, missed by {ev.n_missed} states"
                  f"\nbelief {belief(ev):.2f}")
    px, py = _xy(d["x"], d["y"])
    return {
        "id": oid,
        "x": px,
        "y": py,
        "label": d["cls"],
        "title": title,
        "shape": "square",
        "size": 7,
        "color": {"background": colour, "border": "#222222"},
    }


def build_network(model: AbstractModel, *, title: str, show_sees: bool | None = None) -> Network:
    """The pyvis :class:`~pyvis.network.Network` that :func:`export_html` renders.

    Built from a light copy of the model (positions, labels, tooltips, colours) — never with
    ``from_nx``, which would copy every attribute, feature vectors included, into the page.
    """
    g = model.graph
    colours = {cls: class_color(i) for i, cls in enumerate(model.classes)}
    # states first: vis draws in data order, so the objects end up on top of the path
    nodes = [_state_node(model, n, g.nodes[n]) for n in model.states()]
    closures = _closures(model)
    for node in nodes:
        for episode, kept, to in closures.get(node["id"], ()):
            node["title"] += (f"\nloop closure of episode {episode}: "
                              f"{'kept' if kept else 'rejected'}"
                              + (f", linked to state {to}" if to is not None else ""))
            node.update(shape="diamond", size=7, color=CLOSURE_COLOR[kept])
    evidence = object_evidence(model)
    nodes += [
        _object_node(n, g.nodes[n], colours.get(g.nodes[n]["cls"], OTHER_COLOR), evidence[n])
        for n in model.objects()
    ]

    # One arrow per ordered pair of states; parallel actions share it, labels joined.
    actions: dict[tuple[str, str], list[tuple[str, int]]] = defaultdict(list)
    sees: list[dict] = []
    for u, v, k, d in g.edges(keys=True, data=True):
        if d["kind"] == "transition":
            actions[(u, v)].append((k, int(d["count"])))
        elif k == SEES:
            colour = colours.get(g.nodes[v]["cls"], OTHER_COLOR)
            sees.append({"from": u, "to": v, "kind": "sees", "color": colour})
    if show_sees is None:
        show_sees = len(sees) <= SEES_SHOWN_MAX
    for e in sees:
        e["hidden"] = not show_sees
    edges = list(sees)  # first: vis draws edges in data order, so the arrows lie on top of them
    for (u, v), acts in actions.items():
        acts.sort()
        edges.append(
            {
                "from": u,
                "to": v,
                "label": "/".join(ACTION_LABELS.get(a, a) for a, _ in acts),
                "title": f"{u} → {v}\n" + "\n".join(f"{a} ×{c}" for a, c in acts),
                "color": ACTION_COLORS.get(acts[0][0], OTHER_COLOR),
            }
        )

    net = Network(
        height="100%", width="100%", directed=True, heading=title, cdn_resources="in_line"
    )
    # pyvis's add_node/add_edge check membership in lists (quadratic in the model's size);
    # the lists they fill are what generate_html renders, so fill them directly.
    net.nodes = nodes
    net.edges = edges
    net.node_ids = [n["id"] for n in nodes]
    net.node_map = {n["id"]: n for n in nodes}
    net.options = copy.deepcopy(_OPTIONS)  # a dict: pyvis renders it with json.dumps

    # set_template_dir names our template (net.path); the environment is then widened so that
    # the template can also include pyvis's bundled vis-network, which it inlines.
    net.set_template_dir(str(TEMPLATE_DIR) + os.sep, TEMPLATE)
    net.templateEnv = jinja2.Environment(
        loader=jinja2.ChoiceLoader(
            [
                jinja2.FileSystemLoader(str(TEMPLATE_DIR)),
                jinja2.FileSystemLoader(str(pathlib.Path(pyvis.__file__).with_name("templates"))),
            ]
        )
    )
    class_counts = Counter(d["cls"] for _, d in g.nodes(data=True) if d["kind"] == "object")
    used_actions = sorted({a for acts in actions.values() for a, _ in acts})
    net.templateEnv.globals["kgnav"] = {
        "vis_js": _vis_js_path(),
        "background": "#ffffff",
        "counts": [
            ("states", model.n_states),
            ("objects", model.n_objects),
            ("transitions", model.n_transitions),
            ("views", len(sees)),
            *([("loop closures", sum(len(v) for v in closures.values()))] if closures else []),
        ],
        "n_sees": len(sees),
        "show_sees": show_sees,
        "sees_style": SEES_STYLE,
        "sees_opacity": SEES_OPACITY,
        "action_legend": [
            (a, ACTION_LABELS.get(a, a), ACTION_COLORS.get(a, OTHER_COLOR))
            for a in used_actions
        ],
        "class_legend": [
            (cls, colours[cls], class_counts[cls]) for cls in model.classes if class_counts[cls]
        ],
        "floor": _floor_image(model),
    }
    return net


#: Metres per pixel of the remembered-floor picture drawn under the graph.
FLOOR_RESOLUTION = 0.1


def _floor_image(model: AbstractModel) -> dict | None:
    """What the states' range profiles saw (:func:`kgnav.memory.query.occupancy`) as a small PNG
    (free floor light, obstacles dark, unknown transparent) placed in canvas units."""
    import base64

    import cv2

    grid = occupancy(model, FLOOR_RESOLUTION)
    if grid is None:
        return None
    h, w = grid.free.shape
    img = np.zeros((h, w, 4), np.uint8)
    img[grid.free > 0] = (236, 231, 222, 255)  # BGRA
    img[grid.obstacle] = (70, 70, 70, 255)
    ok, png = cv2.imencode(".png", img[::-1])  # rows grow upwards in the model frame
    if not ok:  # pragma: no cover - encoding a uint8 image does not fail
        return None
    x0, y1 = _xy(grid.x0, grid.y0 + h * grid.resolution)
    return {"src": "data:image/png;base64," + base64.b64encode(png.tobytes()).decode("ascii"),
            "x": x0, "y": y1, "w": round(w * grid.resolution * PX_PER_M, 1),
            "h": round(h * grid.resolution * PX_PER_M, 1)}


def export_html(
    model: AbstractModel,
    path: str | os.PathLike[str],
    *,
    title: str | None = None,
    show_sees: bool | None = None,
) -> pathlib.Path:
    """Write ``model`` as a self-contained interactive HTML page at ``path``; return the path.

    ``title`` defaults to ``"Abstract Model <model_id>"``. ``show_sees`` chooses whether the
    state → object edges start visible; by default they do when there are at most
    :data:`SEES_SHOWN_MAX` of them (the page has a checkbox either way). The page opens with no
    network access. The file is replaced atomically: a failed export leaves any previous file.

    >>> import pathlib, tempfile
    >>> from kgnav.memory.synthetic import SyntheticWorld
    >>> m = SyntheticWorld(seed=2, feature_dim=16).explore(steps=10)
    >>> p = export_html(m, pathlib.Path(tempfile.mkdtemp()) / "m.html", title="demo")
    >>> "<title>demo</title>" in p.read_text(encoding="utf-8")
    True
    """
    path = pathlib.Path(path)
    if title is None:
        title = f"Abstract Model {model.model_id}"
    net = build_network(model, title=title, show_sees=show_sees)
    # generate_html only checks that the name it is given ends in .html; it writes nothing.
    html = net.generate_html(name="index.html")
    # bytes, not text mode: the page is UTF-8 whatever the locale's default encoding is
    with atomic_open(path, "wb") as fh:
        fh.write(html.encode("utf-8"))
    return path
