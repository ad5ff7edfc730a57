"""``Memory``: what the agent may reuse in an episode: stored models and a relocator over them.

The agent is never told which environment it is in; the memory holds every stored model and
relocation picks one by matching the current state's features (the paper's ``s*``). The memory
is a read-only snapshot for the episode: what the episode learns goes back to the store at its
end (see :mod:`kgnav.benchmark.runner`). Each model's occupancy (what its states' range
profiles saw, :mod:`kgnav.memory.geometry`) is built on first use and kept, to verify relocations
and seed the episode map.
"""

from __future__ import annotations

from collections.abc import Mapping

from kgnav.memory.model import AbstractModel
from kgnav.memory.relocator import Match, Relocator


class Memory:
    """Stored Abstract Models plus a fitted :class:`~kgnav.memory.relocator.Relocator` over them."""

    def __init__(self, models: Mapping[str, AbstractModel], threshold: float = 0.3,
                 backend: str = "exact"):
        self.models = dict(models)
        self.relocator = Relocator(threshold=threshold, backend=backend).fit(
            self.models.values())
        self._geometry: dict = {}

    @property
    def threshold(self) -> float:
        return self.relocator.threshold

    def __len__(self) -> int:
        return len(self.models)

    def match(self, features) -> Match | None:
        """The best stored state within the threshold, or None (also when memory is empty)."""
        if not self.models:
            return None
        return self.relocator.match(features)

    def nearest(self, features, k: int = 1) -> list[Match]:
        """The ``k`` stored states nearest in feature space, best first (any distance)."""
        if not self.models:
            return []
        return self.relocator.nearest(features, k)

    def model(self, model_id: str) -> AbstractModel:
        return self.models[model_id]

    def geometry(self, model_id: str):
        """The model's :class:`~kgnav.agent.relocation.StoredGeometry` (None without range
        profiles), built once."""
        if model_id not in self._geometry:
            from kgnav.agent.relocation import StoredGeometry

            self._geometry[model_id] = StoredGeometry.of(self.models[model_id])
        return self._geometry[model_id]
