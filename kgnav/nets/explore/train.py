"""PPO training of the exploration policy on the ``train`` houses, in the map-level environment.

One training step is one PPO iteration: ``episodes_per_iter`` whole episodes (500 actions each,
about 20–30 decisions) are played by the current policy, sampling its goals, in houses and from
starts of the ``train`` split's episodes; then ``epochs`` passes of clipped-surrogate updates over
their decisions in minibatches (advantages by GAE, normalised; value and entropy terms; gradient
norm clipped). Reward per decision: ``area_reward`` × newly explored m² (Active Neural SLAM), plus
for the semantic variant ``distance_reward`` × the decrease of the geodesic distance to the goal
class and ``success_reward`` on reaching it (SemExp); the episode then ends.

Reproducible: the episodes, the goals sampled and the minibatch order of iteration ``k`` come from
``default_rng([seed, k])`` and the weights are initialised from ``seed``, and no environment state
crosses iterations, so a run is a pure function of its :class:`PPOConfig` (on CPU, for a given
thread count) and a resumed run equals an uninterrupted one
(:class:`~kgnav.nets.training.SeededTrainer`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from kgnav.nets.explore.mapenv import Feedback, MapExploreEnv
from kgnav.nets.explore.net import ExploreArch, ExploreNet, Observer, init_weights
from kgnav.nets.explore.weights import PolicyWeights, PolicyWeightsError, load_weights
from kgnav.nets.training import SeededTrainer, TrainingConfig

CHECKPOINT_FORMAT = "kgnav-explore-checkpoint"


@dataclass(frozen=True)
class PPOConfig(TrainingConfig):
    """Everything that determines a training run (recorded in checkpoints and weight files)."""

    steps: int = 300  # PPO iterations
    lr: float = 5e-4
    weight_decay: float = 0.0
    warmup: int = 5
    split: str = "train"
    input_size: tuple[int, int] = (60, 60)
    semantic: bool = False
    episodes_per_iter: int = 8
    episode_pool: int = 30  # the first episodes of each house whose starts are used
    max_steps: int = 500  # actions per episode
    interval: int = 25  # actions per decision at most
    n_rays: int = 80
    epochs: int = 3
    minibatch: int = 64
    gamma: float = 0.99  # per decision
    gae_lambda: float = 0.95
    clip: float = 0.2
    value_coef: float = 0.5
    entropy_coef: float = 0.01
    max_grad_norm: float = 0.5
    area_reward: float = 0.01  # per m² newly explored
    distance_reward: float = 0.0  # per m of geodesic progress toward the goal class
    success_reward: float = 0.0  # on reaching the goal class's success region
    local_cells: int = 240
    wide_cells: int = 960
    channels: tuple[int, ...] = (32, 64, 64, 64, 32)
    hidden: int = 64
    init: str = ""  # weight file to start from (ppo-semantic: the shipped ppo weights)

    def __post_init__(self):
        if (self.steps < 0 or self.episodes_per_iter < 1 or self.n_houses < 1
                or self.minibatch < 2 or self.epochs < 1 or self.episode_pool < 1):
            raise ValueError("steps >= 0, episodes_per_iter, n_houses, epochs, episode_pool "
                             ">= 1 and minibatch >= 2 expected")
        if self.input_size[0] != self.input_size[1]:
            raise ValueError("the map input is square")

    @classmethod
    def for_policy(cls, name: str, **kw) -> PPOConfig:
        """The shipped settings of ``ppo`` or ``ppo-semantic`` (``kw`` overrides)."""
        if name == "ppo-semantic":
            kw = {"semantic": True, "area_reward": 0.01, "distance_reward": 0.1,
                  "success_reward": 0.5, **kw}
        elif name != "ppo":
            raise ValueError(f"no training settings for policy {name!r}")
        return cls(**kw)

    def reward(self, fb: Feedback) -> float:
        """The reward of a decision's :class:`~kgnav.nets.explore.mapenv.Feedback`."""
        return (self.area_reward * fb.gain_m2 + self.distance_reward * fb.progress_m
                + self.success_reward * (fb.distance_after == 0.0))

    @property
    def arch(self) -> ExploreArch:
        return ExploreArch(local_cells=self.local_cells, wide_cells=self.wide_cells,
                           input_size=self.input_size[0], semantic=self.semantic,
                           channels=tuple(self.channels), hidden=self.hidden)

    @property
    def policy_name(self) -> str:
        return "ppo-semantic" if self.semantic else "ppo"


class PPOTrainer(SeededTrainer):
    """Trains an :class:`ExploreNet` with PPO per a :class:`PPOConfig`; ``fit`` returns ``self``.

    ``scenes`` defaults to the first ``n_houses`` houses of ``config.split``. :attr:`curve`
    holds per iteration the mean return, explored area after 100/250/500 actions and entropy.
    """

    checkpoint_format = CHECKPOINT_FORMAT
    error = PolicyWeightsError

    def __init__(self, config: PPOConfig, device: str = "cpu", threads: int = 1,
                 scenes=None):
        super().__init__(config, device, threads)
        torch.manual_seed(config.seed)
        self.net = init_weights(ExploreNet(config.arch))
        if config.init:
            warm_start(self.net, load_weights(config.init))
        self.net.to(self.device)
        self.opt = torch.optim.Adam(self.net.parameters(), lr=config.lr, eps=1e-5,
                                    weight_decay=config.weight_decay)
        self._scenes = scenes
        self._env: MapExploreEnv | None = None
        self._pool: list | None = None
        self.curve: list[dict] = []

    def modules(self):
        return {"net": self.net}

    def extra_state(self) -> dict:
        return {"curve": self.curve}

    def load_extra_state(self, state: dict) -> None:
        self.curve = [dict(d) for d in state.get("curve", [])]

    # ------------------------------------------------------------------ environment
    @property
    def env(self) -> MapExploreEnv:
        if self._env is None:
            from kgnav.sim.episodes import episodes_for, load_scene_of

            c = self.config
            scenes = self._scenes or [load_scene_of(c.split, k) for k in range(c.n_houses)]
            self._env = MapExploreEnv(scenes, max_steps=c.max_steps, interval=c.interval,
                                      n_rays=c.n_rays, semantic=c.semantic,
                                      marks=(100, 250, c.max_steps))
            if self._scenes is None:
                self._pool = [(k, e) for k in range(len(scenes))
                              for e in episodes_for(c.split, k, c.episode_pool)]
            else:
                from kgnav.sim.episodes import generate_episodes

                self._pool = [(k, e) for k, s in enumerate(scenes)
                              for e in generate_episodes(s, c.episode_pool, seed=0)]
        return self._env

    def rollout(self, step: int) -> dict:
        """Play the episodes of iteration ``step`` with the current policy (sampling)."""
        c = self.config
        env = self.env
        rng = np.random.default_rng([c.seed, step])
        observe = Observer(c.arch)
        obs, acts, logps, values, rewards, dones = [], [], [], [], [], []
        returns, areas = [], {100: [], 250: [], c.max_steps: []}
        self.net.eval()
        for _ in range(c.episodes_per_iter):
            house, ep = self._pool[int(rng.integers(len(self._pool)))]
            env.reset(house, ep.start, ep.goal_class if c.semantic else None)
            observe.reset()
            total = 0.0
            while not env.done:
                o = observe(env.map_, env.pose, env.goal_class)
                with torch.no_grad():
                    logits, v = self.net(torch.from_numpy(o)[None].to(self.device))
                lp = torch.log_softmax(logits[0].double(), 0).cpu().numpy()
                p = np.exp(lp)
                a = int(rng.choice(len(p), p=p / p.sum()))
                ai, aj = env.map_.to_cell(*env.pose[:2])
                di, dj = c.arch.goal_offset(a)
                fb = env.step((ai + di, aj + dj))
                r = c.reward(fb)
                obs.append(o)
                acts.append(a)
                logps.append(lp[a])
                values.append(float(v[0]))
                rewards.append(r)
                dones.append(fb.done)
                total += r
            returns.append(total)
            for k, vals in areas.items():  # an episode that ended early keeps its last area
                vals.append(env.coverage.get(k, env.explored_m2))
        adv = np.zeros(len(rewards))
        last = 0.0
        for t in reversed(range(len(rewards))):
            nxt = 0.0 if dones[t] else values[t + 1]
            delta = rewards[t] + c.gamma * nxt - values[t]
            last = delta + c.gamma * c.gae_lambda * (0.0 if dones[t] else last)
            adv[t] = last
        return {"obs": np.stack(obs), "acts": np.array(acts), "logp": np.array(logps),
                "adv": adv, "ret": adv + np.array(values), "rng": rng,
                "stats": {"return": float(np.mean(returns)),
                          **{f"explored_{k}": float(np.mean(v)) for k, v in areas.items()},
                          "decisions": len(rewards)}}

    def _train_step(self) -> float:
        c = self.config
        roll = self.rollout(self.step)
        self.set_lr()
        self.net.train()
        dev = self.device
        obs = torch.from_numpy(roll["obs"]).to(dev)
        acts = torch.from_numpy(roll["acts"]).to(dev)
        old = torch.from_numpy(roll["logp"]).float().to(dev)
        adv = roll["adv"]
        adv = torch.from_numpy((adv - adv.mean()) / (adv.std() + 1e-8)).float().to(dev)
        ret = torch.from_numpy(roll["ret"]).float().to(dev)
        n = len(acts)
        losses, ents = [], []
        for _ in range(c.epochs):
            perm = roll["rng"].permutation(n)
            for idx in np.array_split(perm, max(1, n // c.minibatch)):
                i = torch.from_numpy(idx).to(dev)
                logits, v = self.net(obs[i])
                logp_all = F.log_softmax(logits, dim=1)
                logp = logp_all.gather(1, acts[i][:, None]).squeeze(1)
                ratio = torch.exp(logp - old[i])
                a = adv[i]
                pg = -torch.min(ratio * a, ratio.clamp(1 - c.clip, 1 + c.clip) * a).mean()
                vl = 0.5 * (v - ret[i]).pow(2).mean()
                ent = -(logp_all.exp() * logp_all).sum(1).mean()
                loss = pg + c.value_coef * vl - c.entropy_coef * ent
                self.opt.zero_grad(set_to_none=True)
                loss.backward()
                torch.nn.utils.clip_grad_norm_(self.net.parameters(), c.max_grad_norm)
                self.opt.step()
                losses.append(float(loss.detach()))
                ents.append(float(ent.detach()))
        self.step += 1
        self.last_loss = float(np.mean(losses))
        self.curve.append({"step": self.step, **roll["stats"],
                           "entropy": round(float(np.mean(ents)), 4)})
        return self.last_loss

    def export(self) -> PolicyWeights:
        """The inference weights with their metadata (training settings, curve)."""
        params = {k: v.detach().cpu().numpy() for k, v in self.net.state_dict().items()}
        meta = {"policy": self.config.policy_name, "train": self.train_meta(curve_every=10),
                "curve": self.curve}
        return PolicyWeights(self.config.arch, params, meta)


def warm_start(net: ExploreNet, weights: PolicyWeights) -> ExploreNet:
    """Copy trained weights into ``net``. From a ``ppo`` network into a ``ppo-semantic`` one
    (same sizes), the first convolution's goal-class inputs start at zero, so the new network
    begins as the old policy and learns what the goal channel adds."""
    a, b = weights.arch, net.arch
    if (a.local_cells, a.wide_cells, a.input_size, a.channels, a.hidden) != (
            b.local_cells, b.wide_cells, b.input_size, b.channels, b.hidden):
        raise PolicyWeightsError("--init", "the weights to start from have another architecture")
    state = {k: torch.from_numpy(v) for k, v in weights.params.items()}
    w = state["conv.0.weight"]
    if a.semantic != b.semantic:
        if a.semantic:
            raise PolicyWeightsError("--init", "cannot start a ppo policy from ppo-semantic")
        per = a.in_channels // 2  # channels per window: obstacles, explored, agent, trajectory
        z = torch.zeros(w.shape[0], 1, *w.shape[2:])
        state["conv.0.weight"] = torch.cat([w[:, :per], z, w[:, per:], z], dim=1)
    net.load_state_dict(state)
    return net
