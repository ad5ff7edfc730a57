"""Factories by name: one small registry serves environments, segmenters and global policies.

A registry is filled three ways: by the :meth:`Registry.register` decorator, by *plug-in modules*
that register on import (imported only when a name is missing, so that code which never asks for
the learned segmenter never imports torch), and by installed packages' entry points (for
environments). Asking for an unknown name is a one-line :class:`~kgnav.errors.KgnavError` that
lists the known ones.

>>> shapes = Registry("shape")
>>> @shapes.register("square", "box")
... def square(side=1.0):
...     return side * side
>>> shapes.get("box")(side=2.0)
4.0
>>> shapes.names()
['box', 'square']
>>> shapes.get("circle")
Traceback (most recent call last):
...
kgnav.errors.KgnavError: unknown shape 'circle' (known: box, square)
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Iterable
from importlib.metadata import entry_points
from typing import Generic, TypeVar

from kgnav.errors import KgnavError

F = TypeVar("F", bound=Callable)


class Registry(Generic[F]):
    """Factories of one ``kind`` by name.

    ``plugins`` are modules imported, in order, the first time a name is missing (each registers
    its factories on import); ``entry_point_group`` names the installed packages' entry points
    to load when a name is still missing. :attr:`factories` is the plain dict underneath
    (kept public: ``kgnav.envs.ENVS`` and friends are it).
    """

    def __init__(self, kind: str, plugins: Iterable[str] = (),
                 entry_point_group: str | None = None):
        self.kind = kind
        self.plugins = tuple(plugins)
        self.entry_point_group = entry_point_group
        self.factories: dict[str, F] = {}

    def register(self, *names: str) -> Callable[[F], F]:
        """Decorator adding a factory under one or more names."""

        def deco(factory: F) -> F:
            for n in names:
                self.factories[n] = factory
            return factory

        return deco

    def __contains__(self, name: str) -> bool:
        return name in self.factories

    def _load_entry_points(self) -> None:
        if self.entry_point_group is None:
            return
        for ep in entry_points(group=self.entry_point_group):
            if ep.name not in self.factories:
                try:
                    self.factories[ep.name] = ep.load()
                except Exception as e:  # a broken plug-in must not hide the others
                    raise KgnavError(f"{self.kind} {ep.name!r} ({ep.value}) does not load: "
                                     f"{type(e).__name__}: {e}") from None

    def names(self) -> list[str]:
        """Every registered name, the plug-ins' and entry points' included, sorted."""
        for mod in self.plugins:
            importlib.import_module(mod)
        self._load_entry_points()
        return sorted(self.factories)

    def get(self, name: str) -> F:
        """The factory registered as ``name``, importing plug-ins only as far as needed."""
        for mod in self.plugins:
            if name in self.factories:
                break
            importlib.import_module(mod)
        if name not in self.factories:
            self._load_entry_points()
        if name not in self.factories:
            raise KgnavError(f"unknown {self.kind} {name!r} (known: {', '.join(self.names())})")
        return self.factories[name]
