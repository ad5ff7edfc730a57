"""Old module paths (before the memory / agent / benchmark layout), kept importable for one
release: importing one warns (:class:`DeprecationWarning`) and gives a module that forwards every
attribute to where it lives now. Remove after 0.2.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import types
import warnings

#: old module -> the modules its names now live in (looked up in order)
MOVED: dict[str, tuple[str, ...]] = {
    "kgnav.model": ("kgnav.memory.model", "kgnav.memory.constants"),
    "kgnav.graphml": ("kgnav.memory.graphml", "kgnav.memory.graphml.read",
                      "kgnav.memory.graphml.write", "kgnav._deprecated"),
    "kgnav.graphml_read": ("kgnav.memory.graphml.read", "kgnav._deprecated"),
    "kgnav.graphml_schema": ("kgnav.memory.graphml.schema",),
    "kgnav.store": ("kgnav.memory.store",),
    "kgnav.relocator": ("kgnav.memory.relocator",),
    "kgnav.merge": ("kgnav.memory.merge",),
    "kgnav.query": ("kgnav.memory.query",),
    "kgnav.evidence": ("kgnav.memory.evidence",),
    "kgnav.geometry": ("kgnav.memory.geometry",),
    "kgnav.export_html": ("kgnav.memory.html",),
    "kgnav.synthetic": ("kgnav.memory.synthetic",),
    "kgnav.demo": ("kgnav.memory.demo",),
    "kgnav.atomic": ("kgnav.common.atomic",),
    "kgnav.se2": ("kgnav.common.se2",),
    "kgnav.classes": ("kgnav.common.classes",),
    "kgnav.npz_weights": ("kgnav.nets.weights",),
    "kgnav.training": ("kgnav.nets.training",),
    "kgnav.agent.segmenter": ("kgnav.agent.segmentation", "kgnav.agent.noise_segmenters"),
    "kgnav.cli_eval": ("kgnav.cli.eval",),
    "kgnav.cli_memory_map": ("kgnav.cli.eval",),
    "kgnav.cli_scenes": ("kgnav.cli.scenes",),
    "kgnav.cli_encoder": ("kgnav.cli.encoder",),
    "kgnav.cli_segnet": ("kgnav.cli.segmenter",),
    "kgnav.cli_explore": ("kgnav.cli.policy",),
    "kgnav.cli_training": ("kgnav.cli._training",),
}
#: old package -> new package: every module under it moved with it
MOVED_PACKAGES: dict[str, str] = {
    "kgnav.encoder": "kgnav.nets.encoder",
    "kgnav.segnet": "kgnav.nets.segnet",
    "kgnav.explore": "kgnav.nets.explore",
    "kgnav.evaluation": "kgnav.benchmark",
}
#: renamed inside a moved package
MOVED_PACKAGES_RENAMED = {"kgnav.nets.encoder.relocation": "kgnav.nets.encoder.calibration",
                          "kgnav.benchmark.sources": "kgnav.sim.sources"}


def read_model(path, *, max_bytes=None):
    """The old ``kgnav.graphml.read_model``: :meth:`kgnav.AbstractModel.load`."""
    from kgnav.memory.model import AbstractModel

    return AbstractModel.load(path, max_bytes=max_bytes)


def new_names(old: str) -> tuple[str, ...] | None:
    """Where the names of module ``old`` live now, or None if it did not move."""
    if old in MOVED:
        return MOVED[old]
    for pkg, new in MOVED_PACKAGES.items():
        if old == pkg or old.startswith(pkg + "."):
            target = new + old[len(pkg):]
            return (MOVED_PACKAGES_RENAMED.get(target, target),)
    return None


class _Forward(types.ModuleType):
    """A module whose attributes are those of the modules it forwards to."""

    def __getattr__(self, name: str):
        for target in self.__kgnav_targets__:
            mod = importlib.import_module(target)
            if hasattr(mod, name):
                return getattr(mod, name)
        raise AttributeError(f"module {self.__name__!r} has no attribute {name!r}")

    def __dir__(self):
        return sorted({n for t in self.__kgnav_targets__
                       for n in dir(importlib.import_module(t))})


class _Finder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    def find_spec(self, fullname, path=None, target=None):
        targets = new_names(fullname)
        if targets is None:
            return None
        is_pkg = fullname in MOVED_PACKAGES
        return importlib.util.spec_from_loader(fullname, self, is_package=is_pkg)

    def create_module(self, spec):
        mod = _Forward(spec.name)
        mod.__kgnav_targets__ = new_names(spec.name)
        return mod

    def exec_module(self, module):
        new = module.__kgnav_targets__[0]
        warnings.warn(f"{module.__name__} moved to {new}; the old path goes away in kgnav 0.2",
                      DeprecationWarning, stacklevel=2)
        importlib.import_module(new)  # a broken new module fails here, at the import
        if module.__spec__.submodule_search_locations is not None:
            module.__path__ = []


def install() -> None:
    if not any(isinstance(f, _Finder) for f in sys.meta_path):
        sys.meta_path.append(_Finder())
