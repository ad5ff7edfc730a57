"""``Memory``: what the agent may reuse in an episode: stored models and a relocator over them.

The agent is never told which environment it is in; the memory holds every stored model and
relocation picks one by matching the current state's features (the paper's ``s*``). The memory
is a read-only snapshot for the episode: what the episode learns goes back to the store at its
end (see :mod:`kgnav.evaluation.runner`).
"""

from __future__ import annotations

from collections.abc import Mapping

from kgnav.model import AbstractModel
from kgnav.relocator import Match, Relocator


class Memory:
    """Stored Abstract Models plus a fitted :class:`~kgnav.relocator.Relocator` over them."""

    def __init__(self, models: Mapping[str, AbstractModel], threshold: float = 0.3,
                 backend: str = "exact"):
        self.models = dict(models)
        self.relocator = Relocator(threshold=threshold, backend=backend).fit(
            self.models.values())

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

    def model(self, model_id: str) -> AbstractModel:
        return self.models[model_id]
