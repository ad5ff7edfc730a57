"""A small memory built the way the with-memory agent builds it, on synthetic worlds.

Each world is visited for a few episodes. The first episode of a world finds no match and is
stored as a new model; in later episodes every state is matched against the whole store (the
agent is never told which world it is in) until a match below the threshold, and then the episode
model is merged into the matched one — the paper's Soft Incremental memory, minus the navigation.

>>> import tempfile
>>> rows = build_demo_memory(tempfile.mkdtemp(), worlds=2, episodes=2, steps=150, feature_dim=64)
>>> [r.relocated for r in rows]
[False, True, False, True]
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from kgnav.memory.merge import merge
from kgnav.memory.relocator import Relocator
from kgnav.memory.store import ModelStore
from kgnav.memory.synthetic import SyntheticWorld


@dataclass(frozen=True)
class EpisodeRecord:
    world: int
    episode: int
    model_id: str
    relocated: bool
    match_step: int | None
    match_distance: float | None
    states: int
    objects: int


def build_demo_memory(
    out: str | os.PathLike[str],
    *,
    worlds: int = 3,
    episodes: int = 3,
    steps: int = 200,
    feature_dim: int = 512,
    threshold: float = 0.3,
    seed: int = 0,
    progress=None,
) -> list[EpisodeRecord]:
    """Fill the store at ``out`` with models of ``worlds`` synthetic worlds; one record per episode.

    ``progress`` is an optional callable ``(done, total)``.
    """
    store = ModelStore(out)
    relocator = Relocator(threshold=threshold).fit(store)
    rows: list[EpisodeRecord] = []
    total = worlds * episodes
    for w in range(worlds):
        world = SyntheticWorld(seed=seed * 100 + w, feature_dim=feature_dim)
        for e in range(episodes):
            current = world.explore(steps, episode=e, seed=seed * 1000 + 10 * w + e)
            match, match_step = None, None
            ids, feats = current.state_features()
            for i, s in enumerate(ids):  # states in the order the agent met them
                match = relocator.match(feats[i])
                if match is not None:
                    match_step = current.graph.nodes[s]["step"]
                    stored = store.load(match.model_id)
                    current = merge(stored, current, anchor=(match.state_id, s))
                    break
            store.save(current)
            relocator.add(current)
            rows.append(
                EpisodeRecord(
                    w,
                    e,
                    current.model_id,
                    match is not None,
                    match_step,
                    None if match is None else round(match.distance, 4),
                    current.n_states,
                    current.n_objects,
                )
            )
            if progress is not None:
                progress(len(rows), total)
    return rows
