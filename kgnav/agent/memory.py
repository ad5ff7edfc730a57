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
from contextlib import contextmanager

import numpy as np

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
        self._looks: dict = {}

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

    def looks(self, model_id: str) -> tuple[np.ndarray, np.ndarray]:
        """The model's state poses ``(n, 3)`` and unit feature vectors ``(n, d)``, built
        once: what each stored state saw from where, to compare with what an episode sees
        from the same place (:meth:`~kgnav.agent.relocation.Relocalizer.appearance`)."""
        if model_id not in self._looks:
            m = self.models[model_id]
            ids, feats = m.state_features()
            poses = np.array([m.pose(s) for s in ids], float).reshape(-1, 3)
            feats = np.asarray(feats, np.float32)
            norms = np.linalg.norm(feats, axis=1, keepdims=True)
            self._looks[model_id] = (poses, feats / np.maximum(norms, 1e-12))
        return self._looks[model_id]

    def update(self, model: AbstractModel) -> None:
        """Take ``model`` in (replacing a model of its id): indexed again, its occupancy
        rebuilt on next use. A memory shared by an episode's agents must not change; this is
        for the memory update between episodes (:mod:`kgnav.agent.consolidation`)."""
        self.models[model.model_id] = model
        self.relocator.add(model)
        self._geometry.pop(model.model_id, None)
        self._looks.pop(model.model_id, None)

    @contextmanager
    def without(self, model_id: str):
        """The memory with model ``model_id`` left out for the block (no relocation into it),
        then put back as it was (its occupancy is kept: the model did not change)."""
        model = self.models.pop(model_id)
        self.relocator.remove(model_id)
        try:
            yield self
        finally:
            self.models[model_id] = model
            self.relocator.add(model)

    def drop(self, model_id: str) -> AbstractModel | None:
        """Take the model ``model_id`` out (None if absent); see :meth:`update`."""
        self.relocator.remove(model_id)
        self._geometry.pop(model_id, None)
        return self.models.pop(model_id, None)
