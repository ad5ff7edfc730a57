"""The memory update between rounds: fold an episode's model into the stored models.

What the benchmark does at the end of each round for every episode of a learning variant
(``si``, ``sem+si``), in scene order; an integrator running their own loop calls the same
function to keep a memory the way ``kgnav eval`` does.

>>> from kgnav.memory.model import AbstractModel
>>> models = {}
>>> absorb(models, AbstractModel(4, model_id="house-e000"))
('house-e000', [])
>>> changed, gone = absorb(models, AbstractModel(4, model_id="house-e001"),
...                        into="house-e000", transform=(0.0, 0.0, 0.0))
>>> changed, gone, sorted(models)
('house-e000', [], ['house-e000'])
"""

from __future__ import annotations

from collections.abc import Mapping

from kgnav.common import se2
from kgnav.memory.evidence import forget
from kgnav.memory.merge import merge
from kgnav.memory.model import AbstractModel
from kgnav.memory.posegraph import DriftModel, bend, straighten

__all__ = ["absorb"]


def absorb(models: dict[str, AbstractModel], model: AbstractModel, *, into: str | None = None,
           transform: tuple[float, float, float] | None = None,
           bridges: Mapping[str, tuple[float, float, float]] | None = None,
           forget_below: float = 0.0, forget_label_share: float = 0.0,
           drift: DriftModel | None = None) -> tuple[str, list[str]]:
    """Fold an episode's ``model`` into the memory ``models`` (id -> model, changed in place).

    ``into``: the stored model the episode relocated into (and kept as mergeable), with
    ``transform`` the episode frame -> that model's frame; the episode is merged into it.
    Without one (or if it is no longer stored) the episode's model is stored as a new model.
    ``bridges``: other stored models the episode verifiably matched too (id -> episode ->
    model transform); they are merged into ``into`` as well, so separate models of one house
    join. Objects whose belief fell below ``forget_below``, or whose place mostly gave
    another class (label share below ``forget_label_share``), are then forgotten
    (:func:`kgnav.memory.evidence.forget`). With ``drift`` (the odometry's
    :class:`~kgnav.memory.posegraph.DriftModel`), the merged model's pose graph is optimised
    again over every episode's recorded odometry and loop-closure links
    (:func:`kgnav.memory.posegraph.straighten`) and its states and objects moved to the
    result. Returns the id of the model that changed and the ids of
    the models folded away (to delete from a store).
    """
    def consolidate(m: AbstractModel) -> None:
        if forget_below > 0 or forget_label_share > 0:
            forget(m, forget_below, min_label_share=forget_label_share)

    if into is None or into not in models:
        models[model.model_id] = model
        consolidate(model)
        return model.model_id, []
    merged = merge(models[into], model, transform=transform)
    gone = []
    for mid, T in sorted((bridges or {}).items()):
        if mid == into or mid not in models:
            continue
        # the bridged model's frame -> the episode's -> the target's
        merged = merge(merged, models.pop(mid), transform=se2.compose(transform,
                                                                      se2.inverse(T)))
        gone.append(mid)
    if drift is not None:
        rejected: list[dict] = []
        bend(merged, straighten(merged, drift, rejected))
        merged.reject_loop_closures(rejected)
    consolidate(merged)
    models[into] = merged
    return into, gone
