"""Global policies that pick a long-term goal on a grid over the map around the agent.

* ``ppo`` / ``ppo-semantic`` — :class:`LearnedPolicy`: the PPO-trained :class:`ExploreNet` on the
  episode map (the semantic one also reads the goal class's channel). By default it samples
  its goal from the network's distribution, seeded per episode (``reset(seed)``), as it was
  trained; ``deterministic=True`` takes the most likely goal.
* ``random-goal`` — :class:`RandomGoalPolicy`: a uniformly drawn cell of the same grid (the
  bench's floor).

Both return a reachable cell: the grid cell's centre is moved to the nearest cell the planner
can reach on the agent's map (unknown space counts as free, as for the planner), like the
map-level environment moves it to the nearest navigable cell.

>>> from kgnav.agent.policy import make_policy
>>> make_policy("ppo").name, make_policy("random-goal").name
('ppo', 'random-goal')
"""

from __future__ import annotations

import os

import numpy as np
import torch

from kgnav.agent.mapping import EpisodeMap
from kgnav.agent.planner import FMMPlanner, fmm_distance
from kgnav.agent.policy import register_policy
from kgnav.nets.explore.net import ExploreArch, ExploreNet, Observer
from kgnav.nets.explore.weights import PolicyWeights, load_weights

_WALLED_IN = 25


class GridGoalPolicy:
    """Base of the grid-goal policies: subclasses choose an action index of ``arch``'s grid."""

    name = "grid-goal"

    def __init__(self, arch: ExploreArch):
        self.arch = arch
        self._rng = np.random.default_rng(0)

    def reset(self, seed: int) -> None:
        self._rng = np.random.default_rng([int(seed), 17])

    def _choose(self, m: EpisodeMap, pose, goal_class: str | None) -> int:
        raise NotImplementedError

    def select(self, m: EpisodeMap, pose, goal_class: str, planner: FMMPlanner
               ) -> tuple[int, int] | None:
        agent = m.to_cell(pose[0], pose[1])
        if not m.inside(*agent):
            return None
        di, dj = self.arch.goal_offset(self._choose(m, pose, goal_class))
        return reachable_cell(m, agent, (agent[0] + di, agent[1] + dj), planner)


def reachable_cell(m: EpisodeMap, agent: tuple[int, int], goal: tuple[int, int],
                   planner: FMMPlanner) -> tuple[int, int]:
    """The cell nearest to ``goal`` (L2) that the planner can reach from ``agent``, on a window
    around both; ``goal`` itself (clipped to the map) when nothing is reachable."""
    H, W = m.shape
    gi, gj = min(max(goal[0], 0), H - 1), min(max(goal[1], 0), W - 1)
    mask = np.zeros((H, W), bool)
    mask[gi, gj] = True
    crop = planner.window(m, agent, mask)
    i0, i1, j0, j1 = crop
    src = np.zeros((i1 - i0, j1 - j0), bool)
    src[agent[0] - i0, agent[1] - j0] = True
    # the planner keeps the agent's own 5 x 5 cells free: reaching no more is being walled in
    # by the inflated map (at a wall or in a doorway), where the planner squeezes too
    for squeeze in (False, True):
        ok = np.isfinite(fmm_distance(planner.traversable(m, crop, agent, squeeze=squeeze), src))
        if ok.sum() > _WALLED_IN:
            break
    else:
        return gi, gj
    ii, jj = np.nonzero(ok)
    k = int(np.argmin((ii + i0 - gi) ** 2 + (jj + j0 - gj) ** 2))
    return int(ii[k] + i0), int(jj[k] + j0)


class LearnedPolicy(GridGoalPolicy):
    """The PPO policy (see the module docstring).

    ``weights``: a :class:`PolicyWeights` or a path (default: the shipped file of ``name``);
    ``device``: ``cpu`` (default: one small forward pass every 25 steps gains nothing from a
    GPU, and the benchmark's forked workers could not share one), ``auto`` or ``cuda``;
    ``threads``: CPU threads per decision (1: a 60 × 60 input gains nothing from more on a
    shared machine).
    """

    def __init__(self, name: str = "ppo", weights: PolicyWeights | str | os.PathLike | None = None,
                 *, deterministic: bool = False, device: str = "cpu", threads: int | None = 1):
        from kgnav.nets.encoder.extractor import resolve_device

        semantic = name == "ppo-semantic"
        if not isinstance(weights, PolicyWeights):
            weights = load_weights(weights, semantic=semantic)
        super().__init__(weights.arch)
        self.name = name
        self.weights = weights
        self.deterministic = bool(deterministic)
        self.device = resolve_device(device)
        self.threads = threads
        net = ExploreNet(weights.arch)
        net.load_state_dict({k: torch.from_numpy(v) for k, v in weights.params.items()})
        self.net = net.eval().to(self.device)
        self.observer = Observer(weights.arch)

    def reset(self, seed: int) -> None:
        super().reset(seed)
        self.observer.reset()

    def logits(self, m: EpisodeMap, pose, goal_class: str | None) -> np.ndarray:
        """The network's goal logits for this map and pose (adds the pose to the trajectory)."""
        x = torch.from_numpy(self.observer(m, pose, goal_class))[None].to(self.device)
        prev = torch.get_num_threads()
        if self.threads and self.threads != prev:
            torch.set_num_threads(self.threads)
        try:
            with torch.no_grad():
                logits, _ = self.net(x)
        finally:
            if self.threads and self.threads != prev:
                torch.set_num_threads(prev)
        return logits[0].double().cpu().numpy()

    def _choose(self, m, pose, goal_class) -> int:
        z = self.logits(m, pose, goal_class)
        if self.deterministic:
            return int(np.argmax(z))
        p = np.exp(z - z.max())
        return int(self._rng.choice(len(p), p=p / p.sum()))


class RandomGoalPolicy(GridGoalPolicy):
    """A uniformly random cell of the goal grid, seeded per episode."""

    name = "random-goal"

    def __init__(self, arch: ExploreArch | None = None):
        super().__init__(arch or ExploreArch())

    def _choose(self, m, pose, goal_class) -> int:
        return int(self._rng.integers(self.arch.n_actions))


@register_policy("ppo")
def _ppo(**params) -> LearnedPolicy:
    return LearnedPolicy("ppo", **params)


@register_policy("ppo-semantic")
def _ppo_semantic(**params) -> LearnedPolicy:
    return LearnedPolicy("ppo-semantic", **params)


register_policy("random-goal")(RandomGoalPolicy)
