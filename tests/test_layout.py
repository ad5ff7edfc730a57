"""The package's layout: three faces and no import circles; old module paths still import, warning.

The import graph is read from the source (every ``import`` statement, inside functions too; not
those under ``if TYPE_CHECKING:``, which never run), so a circle hidden in a lazy import counts.
"""

from __future__ import annotations

import ast
import importlib
import subprocess
import sys
import warnings
from pathlib import Path

import networkx as nx
import pytest

import kgnav
from kgnav import _deprecated

PKG = Path(kgnav.__file__).parent


def _module_name(path: Path, root: Path) -> str:
    parts = path.relative_to(root.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _is_type_checking(node: ast.If) -> bool:
    t = node.test
    return (isinstance(t, ast.Name) and t.id == "TYPE_CHECKING") or (
        isinstance(t, ast.Attribute) and t.attr == "TYPE_CHECKING")


def _imports(tree: ast.AST, here: str, is_pkg: bool, modules: set[str]) -> set[str]:
    """The kgnav modules a module's import statements name (``from P import m`` names ``P.m``
    when that is a module, else ``P``)."""
    out: set[str] = set()
    stack = [tree]
    while stack:
        node = stack.pop()
        if isinstance(node, ast.If) and _is_type_checking(node):
            stack.extend(node.orelse)
            continue
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                pkg = here if is_pkg else here.rpartition(".")[0]
                for _ in range(node.level - 1):
                    pkg = pkg.rpartition(".")[0]
                base = f"{pkg}.{base}" if base else pkg
            for a in node.names:
                sub = f"{base}.{a.name}"
                out.add(sub if sub in modules else base)
        stack.extend(ast.iter_child_nodes(node))
    return {m for m in out if m in modules}


def import_graph(root: Path = PKG) -> nx.DiGraph:
    files = {p: _module_name(p, root) for p in root.rglob("*.py")}
    modules = set(files.values())
    g = nx.DiGraph()
    g.add_nodes_from(modules)
    for path, name in files.items():
        tree = ast.parse(path.read_text(), str(path))
        for target in _imports(tree, name, path.name == "__init__.py", modules):
            if target != name:
                g.add_edge(name, target)
    return g


def test_no_import_circles():
    cycles = list(nx.simple_cycles(import_graph()))
    assert cycles == [], f"import circles: {cycles[:5]}"


def test_the_cycle_check_sees_a_lazy_import_circle(tmp_path):
    pkg = tmp_path / "kgnav"
    (pkg / "memory").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "memory" / "__init__.py").write_text("")
    (pkg / "memory" / "a.py").write_text("from kgnav.memory.b import f\n")
    (pkg / "memory" / "b.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from kgnav.memory import a\n"
        "def f():\n    from kgnav.memory import a\n")
    assert list(nx.simple_cycles(import_graph(pkg))) != []
    (pkg / "memory" / "b.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from kgnav.memory import a\n")
    assert list(nx.simple_cycles(import_graph(pkg))) == []


def test_the_root_holds_only_the_faces_and_shared_modules():
    modules = sorted(p.name for p in PKG.glob("*.py"))
    assert modules == ["__init__.py", "_deprecated.py", "errors.py", "registry.py"]
    packages = sorted(p.name for p in PKG.iterdir() if (p / "__init__.py").exists())
    assert packages == ["agent", "benchmark", "cli", "common", "envs", "memory", "nets", "sim"]


def test_every_old_module_path_imports_with_a_warning_and_the_same_objects():
    # in a fresh interpreter, so that nothing here was imported by the old name before
    code = (
        "import warnings, importlib, json\n"
        "from kgnav import _deprecated\n"
        "out = {}\n"
        "for old, new in _deprecated.MOVED.items():\n"
        "    with warnings.catch_warnings(record=True) as w:\n"
        "        warnings.simplefilter('always')\n"
        "        mod = importlib.import_module(old)\n"
        "    target = importlib.import_module(new[0])\n"
        "    names = [n for n in dir(target) if not n.startswith('__')][:5]\n"
        "    warned = any(issubclass(x.category, DeprecationWarning)"
        " and new[0] in str(x.message) for x in w)\n"
        "    out[old] = [warned, all(getattr(mod, n) is getattr(target, n) for n in names)]\n"
        "print(json.dumps(out))\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    import json

    seen = json.loads(res.stdout)
    assert set(seen) == set(_deprecated.MOVED)
    assert all(w for w, _ in seen.values()), [k for k, (w, _) in seen.items() if not w]
    assert all(same for _, same in seen.values()), [k for k, (_, s) in seen.items() if not s]


@pytest.mark.parametrize("old, new", [
    ("kgnav.evaluation.runner", "kgnav.benchmark.runner"),
    ("kgnav.encoder.relocation", "kgnav.nets.encoder.calibration"),
    ("kgnav.segnet.segmenter", "kgnav.nets.segnet.segmenter"),
    ("kgnav.explore.weights", "kgnav.nets.explore.weights"),
])
def test_moved_packages_forward_their_modules(old, new):
    assert _deprecated.new_names(old) == (new,)
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        sys.modules.pop(old, None)
        mod = importlib.import_module(old)
    assert any(issubclass(x.category, DeprecationWarning) for x in w)
    target = importlib.import_module(new)
    public = [n for n in vars(target) if not n.startswith("_")]
    assert public and all(getattr(mod, n) is getattr(target, n) for n in public)


def test_old_paths_keep_the_public_merge_function_and_read_model(tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        sys.modules.pop("kgnav.merge", None)
        importlib.import_module("kgnav.merge")
        from kgnav.graphml import read_model
    assert callable(kgnav.merge) and kgnav.merge is sys.modules["kgnav.memory.merge"].merge
    m = kgnav.AbstractModel(feature_dim=2, model_id="old-path")
    m.add_state([1.0, 0.0], pose=(0.0, 0.0, 0.0))
    m.save(tmp_path / "m.graphml")
    assert read_model(tmp_path / "m.graphml") == m


def test_an_unknown_old_name_is_still_an_import_error():
    with pytest.raises(ModuleNotFoundError):
        importlib.import_module("kgnav.no_such_module")
