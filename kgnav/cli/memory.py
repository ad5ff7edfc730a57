"""``kgnav inspect | merge | query | export | store | demo``: the memory's own commands, which
read, merge, query and draw Abstract Models and list or check a store of them."""

from __future__ import annotations

import base64
from pathlib import Path

import click
from rich.text import Text

from kgnav.cli._output import _FILE, _JSON, DataError, _about, _emit_json, _row, _table, out, safe
from kgnav.errors import KgnavError
from kgnav.memory import query
from kgnav.memory.merge import best_anchor, merge
from kgnav.memory.model import AbstractModel
from kgnav.memory.store import ModelStore, backend_of


def _stderr():
    from rich.console import Console

    return Console(stderr=True)


def _parse_xy(ctx, param, value: str | None) -> tuple[float, float] | None:
    if value is None:
        return None
    try:
        x, y = (float(v) for v in value.split(","))
    except ValueError:
        raise click.BadParameter(f"expected X,Y in metres, got {value!r}") from None
    return (x, y)


def _parse_anchor(ctx, param, value: str) -> str | tuple[str, str]:
    if value == "auto":
        return value
    parts = value.split(":")
    if len(parts) != 2 or not all(parts):
        raise click.BadParameter(f"expected 'auto' or TARGET_STATE:SOURCE_STATE, got {value!r}")
    return (parts[0], parts[1])



@click.command("inspect")
@click.argument("file", type=_FILE)
@_JSON
def inspect(file: Path, as_json: bool) -> None:
    """Summarise a model: sizes, frame extent, episodes, provenance, class inventory."""
    info = query.summary(AbstractModel.load(file))
    if as_json:
        _emit_json(info)
        return
    out.print(Text.assemble((safe(file), "bold"), "  model ", (safe(info["model_id"]), "cyan")))
    for key in ("schema_version", "feature_dim", "extractor", "states", "objects", "transitions",
                "views", "actions", "episodes", "merged_from"):
        out.print(f"  {key:<15}{safe(info[key])}")
    if info["extent"]:
        ex = info["extent"]
        out.print(
            f"  {'extent':<15}x {ex['x'][0]:.2f}..{ex['x'][1]:.2f} m, "
            f"y {ex['y'][0]:.2f}..{ex['y'][1]:.2f} m"
        )
    lc = info["loop_closures"]
    if lc["kept"] or lc["rejected"]:
        linked = f"; {lc['linked']} of the kept linked to stored states" if lc["linked"] else ""
        if lc.get("joins"):
            linked += f", {lc['joins']} of them by joins of stored models"
        out.print(f"  {'loop closures':<15}{lc['kept']} kept, {lc['rejected']} rejected "
                  f"(drifting episodes bent onto the model{linked})")
    if info["odometry_states"]:
        out.print(f"  {'odometry':<15}raw odometry of {info['odometry_states']} states "
                  "(the model's pose graph is optimised again at each merge)")
    table = _table("class", "objects", "views", "max views", title="class inventory")
    for cls, c in info["classes"].items():
        _row(table, cls, c["objects"], c["views"], c["max_views"])
    out.print(table)


@click.command("merge")
@click.argument("target", type=_FILE)
@click.argument("source", type=_FILE)
@click.option("-o", "--output", type=_FILE, required=True, help="Where to write the result.")
@click.option(
    "--anchor",
    default="auto",
    show_default=True,
    callback=_parse_anchor,
    help="'auto' (the closest feature pair) or TARGET_STATE:SOURCE_STATE.",
)
def merge_cmd(target: Path, source: Path, output: Path, anchor) -> None:
    """Merge SOURCE into TARGET through an anchor pair of matching states.

    The result keeps TARGET's frame and id; SOURCE is mapped by
    T = pose(target_state) o pose(source_state)^-1.
    """
    a, b = AbstractModel.load(target), AbstractModel.load(source)
    if anchor == "auto":
        ta, sb, dist = best_anchor(a, b)
        note = f"auto anchor {ta}:{sb} (cosine distance {dist:.4f})"
    else:
        ta, sb = anchor
        for path, model, state in ((target, a, ta), (source, b, sb)):
            if not model.has_state(state):
                raise DataError(f"{path}: no state {state!r}")
        note = f"anchor {ta}:{sb}"
    merged = merge(a, b, anchor=(ta, sb))
    merged.save(output)
    out.print(safe(
        f"merged {source} into {target} with {note}: {merged.n_states} states, "
        f"{merged.n_objects} objects -> {output}"
    ))


@click.command("query")
@click.argument("file", type=_FILE)
@click.option("--goal", required=True, help="Goal object class, e.g. chair.")
@click.option(
    "--near",
    callback=_parse_xy,
    help="X,Y position (model frame, metres) to pick the closest goal from [default: 0,0].",
)
@click.option(
    "--top", default=5, show_default=True, type=click.IntRange(min=1),
    help="How many most-seen objects to consider.",
)
@_JSON
def query_cmd(file: Path, goal: str, near, top: int, as_json: bool) -> None:
    """The goal point for a class, as the paper picks it, and the visibility ranking."""
    xy = near or (0.0, 0.0)
    model = AbstractModel.load(file)
    try:
        ranked = query.ranked_objects(model, goal)
        chosen = query.goal_point(model, goal, near=xy, top_k=top)
    except KgnavError as exc:
        raise _about(file, exc) from None
    if as_json:
        _emit_json(
            {
                "model_id": model.model_id,
                "goal": goal,
                "near": list(xy),
                "goal_point": None if chosen is None else _obj_json(chosen),
                "ranking": [_obj_json(o) for o in ranked],
            }
        )
        return
    if chosen is None:
        out.print(safe(f"{file}: no {goal} in model {model.model_id}"))
        return
    x, y, z = chosen.position
    out.print(safe(
        f"goal {goal}: object {chosen.id} at ({x:.2f}, {y:.2f}, {z:.2f}), "
        f"seen from {chosen.n_views} states"
    ))
    table = _table("rank", "object", "x", "y", "views", title=f"{goal} by visibility")
    for i, o in enumerate(ranked, 1):
        _row(table, i, o.id, f"{o.position[0]:.2f}", f"{o.position[1]:.2f}", o.n_views)
    out.print(table)


def _obj_json(o) -> dict:
    return {"id": o.id, "cls": o.cls, "position": list(o.position), "n_views": o.n_views,
            "n_obs": o.n_obs}


@click.command("export")
@click.argument("file", type=_FILE)
@click.option("--html", type=_FILE, required=True, help="Where to write the HTML page.")
def export_cmd(file: Path, html: Path) -> None:
    """Write an interactive HTML floor-plan view of a model (works offline)."""
    from kgnav.memory.html import export_html

    path = export_html(AbstractModel.load(file), html)
    out.print(safe(f"wrote {path}"))


@click.group("store")
def store_app() -> None:
    """Work with a directory of models."""


@store_app.command("ls")
@click.argument("directory", metavar="STORE", type=click.Path(path_type=Path))
@_JSON
def store_ls(directory: Path, as_json: bool) -> None:
    """List the models of a store; unreadable files are reported on stderr and skipped."""
    _list_store(directory, as_json)


@store_app.command("check")
@click.argument("directory", metavar="STORE", type=click.Path(path_type=Path))
@_JSON
def store_check(directory: Path, as_json: bool) -> None:
    """Report every problem in a store, changing nothing; exit status 1 if there is any.

    Problems: model files that do not load (corrupt, foreign, another schema version, a name
    that is not their model id), entries named like a model that are not regular files
    (directories, FIFOs, dangling symbolic links, loops), and temporary files that interrupted
    saves left behind.
    """
    good, problems = _open_store(directory).check()
    if as_json:
        _emit_json({"directory": str(directory), "models": good,
                    "problems": [{"path": p.path, "kind": p.kind, "reason": p.reason}
                                 for p in problems]})
    else:
        for p in problems:
            click.echo(safe(f"{p.path}: {p.reason}"))
        click.echo(safe(f"{directory}: {len(good)} models load, {len(problems)} problems"))
    if problems:
        raise click.exceptions.Exit(1)


def _open_store(path: Path) -> ModelStore:
    """An existing store: a directory of GraphML files or a graph database (by its suffix)."""
    if backend_of(path) == "directory":
        if not path.is_dir():
            raise DataError(f"{path}: not a directory" if path.exists()
                            else f"{path}: not a directory (no such store)")
    elif not path.exists():
        raise DataError(f"{path}: no such store")
    return ModelStore(path)


@store_app.command("convert")
@click.argument("source", metavar="SRC", type=click.Path(path_type=Path))
@click.argument("dest", metavar="DST", type=click.Path(path_type=Path))
def store_convert(source: Path, dest: Path) -> None:
    """Copy every model of SRC into DST, between a directory of GraphML files and a graph
    database (a path ending in .lbug), either way. Models that do not load are reported on
    stderr and skipped; a model of DST with the same id is replaced."""
    from rich.progress import Progress

    src = _open_store(source)
    dst = ModelStore(dest)
    copied = 0
    with Progress(console=_stderr(), transient=True) as bar:
        task = bar.add_task("converting", total=len(src.ids()))
        for _, model, problem in src.each():  # one model in memory at a time
            bar.advance(task)
            if model is None:
                bar.console.print(f"kgnav: warning: skipped {safe(problem)}", markup=False,
                                  highlight=False, soft_wrap=True)
                continue
            dst.save(model)
            copied += 1
    out.print(safe(f"{source} -> {dest}: {copied} models"))


@store_app.command("upgrade")
@click.argument("store", metavar="STORE", type=click.Path(path_type=Path))
def store_upgrade(store: Path) -> None:
    """Bring a graph-database STORE written by an earlier kgnav to this layout, in one
    transaction (nothing changes if it fails). A directory of GraphML files needs none."""
    st = _open_store(store)
    if backend_of(store) == "directory":
        raise DataError(f"{store}: a directory of GraphML files has no layout to upgrade")
    old = st.upgrade()
    from kgnav.memory.graphdb import DB_SCHEMA_VERSION

    out.print(safe(f"{store}: layout version {old} -> {DB_SCHEMA_VERSION}" if old !=
                   DB_SCHEMA_VERSION else f"{store}: already layout version {old}"))


@store_app.command("index")
@click.argument("store", metavar="STORE", type=click.Path(path_type=Path))
@click.option("--backend", type=click.Choice(["exact", "hnsw"]), default="exact",
              show_default=True, help="Search: exact, or HNSW (needs faiss) for 1e5+ states.")
@click.option("--rebuild", is_flag=True, help="Fit again even if the saved index is current.")
@_JSON
def store_index(store: Path, backend: str, rebuild: bool, as_json: bool) -> None:
    """Fit the relocator over STORE and save its index beside it (reused while the store is
    unchanged). Features are streamed from the store: a database's models are never loaded."""
    import time

    from rich.progress import Progress

    from kgnav.memory.relocator import Relocator

    st = _open_store(store)
    path = st.index_path()

    def stamp():
        return path.stat().st_mtime_ns if path.is_file() else None

    before, t = stamp(), time.perf_counter()
    with Progress(console=_stderr(), transient=True) as bar:
        task = bar.add_task("indexing", total=st.state_count())
        r = Relocator.open(st, backend=backend, rebuild=rebuild,
                           progress=lambda n: bar.advance(task, n))
    took = time.perf_counter() - t
    fitted = before is None or stamp() != before
    for p in r.problems_:
        click.echo(f"kgnav: warning: skipped {safe(p)}", err=True)
    report = {"store": str(store), "index": str(path), "backend": backend,
              "models": len(r.model_ids_), "states": r.n_states_,
              "feature_dim": r.feature_dim_, "seconds": round(took, 2),
              "skipped": len(r.problems_), "fitted": fitted}
    if as_json:
        _emit_json(report)
    else:
        out.print(safe(f"{path}: {r.n_states_} states of {len(r.model_ids_)} models "
                       f"({backend}, {took:.1f} s, "
                       f"{'fitted' if fitted else 'saved index was current'})"))


@click.command("cypher")
@click.argument("store", type=click.Path(path_type=Path))
@click.argument("query")
@_JSON
def cypher_cmd(store: Path, query: str, as_json: bool) -> None:
    """Run a read-only Cypher QUERY on a graph-database STORE and print its rows (a query that
    would write is refused). docs/graphdb.md has the schema and example queries."""
    db = _open_store(store)
    if not hasattr(db, "cypher"):
        raise DataError(f"{store}: a directory store; Cypher needs a graph database "
                        f"(kgnav store convert {store} memory.lbug)")
    columns, rows = db.cypher(query)
    if as_json:
        _emit_json({"columns": columns,
                    "rows": [dict(zip(columns, map(_json_cell, r), strict=True)) for r in rows]})
        return
    table = _table(*columns, title=f"{len(rows)} rows")
    for r in rows:
        _row(table, *(_text_cell(v) for v in r))
    out.print(table)


def _json_cell(v):
    if isinstance(v, bytes):  # features and range profiles: raw little-endian bytes
        return base64.b64encode(v).decode("ascii")
    if isinstance(v, dict | list | str | int | float | bool) or v is None:
        return v
    return str(v)


def _text_cell(v) -> str:
    return f"<{len(v)} bytes>" if isinstance(v, bytes) else "" if v is None else str(v)


def _list_store(directory: Path, as_json: bool) -> None:
    models, problems = _open_store(directory).load_all()
    for p in problems:
        click.echo(f"kgnav: warning: skipped {safe(p)}", err=True)
    rows = [
        {
            "model_id": m.model_id,
            "states": m.n_states,
            "objects": m.n_objects,
            "transitions": m.n_transitions,
            "episodes": len(m.episodes),
            "merged_from": m.merged_from,
        }
        for m in models.values()
    ]
    if as_json:
        _emit_json({"models": rows, "skipped": [{"path": p.path, "reason": p.reason}
                                                 for p in problems]})
        return
    table = _table("model", "states", "objects", "transitions", "episodes", "merged from",
                   title=str(directory))
    for r in rows:
        _row(table, r["model_id"], r["states"], r["objects"], r["transitions"], r["episodes"],
             ", ".join(r["merged_from"]))
    out.print(table)


@click.command("demo")
@click.option(
    "--out", "out_dir", type=click.Path(file_okay=False, path_type=Path),
    default=Path("export/demo"), show_default=True, help="Where the memory and pages go.",
)
@click.option("--worlds", default=3, show_default=True, type=click.IntRange(min=1),
              help="Synthetic environments.")
@click.option("--episodes", default=3, show_default=True, type=click.IntRange(min=1),
              help="Episodes per environment.")
@click.option("--steps", default=200, show_default=True, type=click.IntRange(min=1),
              help="Actions per episode.")
@click.option("--seed", default=0, show_default=True, help="Seed of the worlds and walks.")
@click.option("--overwrite", is_flag=True, help="Replace the models a previous demo left in --out.")
def demo(out_dir: Path, worlds: int, episodes: int, steps: int, seed: int, overwrite: bool) -> None:
    """Build a small memory on synthetic worlds, inspect it and export every model to HTML."""
    from rich.progress import Progress

    from kgnav.memory.demo import build_demo_memory
    from kgnav.memory.html import export_html

    store_dir = out_dir / "memory"
    store = ModelStore(store_dir)
    if store.ids() and not overwrite:
        raise DataError(f"{store_dir}: already holds a memory; pass --overwrite or another --out")
    for model_id in store.ids():  # only the store's own model files, nothing else in the folder
        store.delete(model_id)
    with Progress(transient=True) as bar:
        task = bar.add_task("exploring", total=worlds * episodes)
        rows = build_demo_memory(
            store_dir, worlds=worlds, episodes=episodes, steps=steps, seed=seed,
            progress=lambda done, total: bar.update(task, completed=done),
        )
    table = _table("world", "episode", "relocated", "at step", "distance", "model", "states",
                   "objects", title="episodes")
    for r in rows:
        _row(table, r.world, r.episode, "yes" if r.relocated else "no",
             "" if r.match_step is None else r.match_step,
             "" if r.match_distance is None else f"{r.match_distance:.3f}",
             r.model_id, r.states, r.objects)
    out.print(table)
    _list_store(store_dir, as_json=False)
    models, _ = store.load_all()
    for model_id, model in models.items():
        page = export_html(model, out_dir / "html" / f"{model_id}.html")
        goal = query.goal_point(model, "chair")
        if goal is None:
            where = "none seen"
        else:
            x, y, _ = goal.position
            where = f"{goal.id} at ({x:.2f}, {y:.2f}), {goal.n_views} views"
        out.print(safe(f"{model_id}: goal 'chair' -> {where}; page {page}"))
