"""The exploration policy's network and its input, a multi-channel crop of the episode map.

**Input** (:class:`Observer`): two square windows of the :class:`~kgnav.agent.mapping.EpisodeMap`
centred on the agent, in the episode frame: ``local_cells`` (240 cells = 12 m) and
``wide_cells`` (960 cells = 48 m, a whole Matterport3D-size house), each reduced to
``input_size`` (60) pixels. Per window four channels, as Active Neural SLAM's: obstacles
(max-pooled, so a thin wall survives), explored share (mean-pooled), the agent's position, and
its trajectory (the polyline through the poses the policy was asked at: the policy sees the
map, not every step). The semantic variant adds the goal class's evidence channel per window
(SemExp). Cells outside the map read unknown.

**Network** (:class:`ExploreNet`), the paper's "5 Conv Layers with the ReLU activations and
MaxPooling2D": conv–ReLU–maxpool, conv–ReLU–maxpool, then three conv–ReLU, leaving a
``grid × grid`` (15 × 15) feature map over the input. The **action** is a long-term goal: one
cell of that grid over the local window (0.8 m each), from a 1 × 1 convolution over the features
and a broadcast global feature (a categorical distribution: it can keep several frontiers in
mind at once, where a Gaussian over a point averages them). The **critic** reads the pooled
features.

>>> import torch
>>> net = ExploreNet(ExploreArch())
>>> logits, value = net(torch.zeros(2, 8, 60, 60))
>>> tuple(logits.shape), tuple(value.shape)
((2, 225), (2,))
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
import torch
from torch import nn

from kgnav.agent.mapping import EpisodeMap
from kgnav.nets.training import ConfigDict


@dataclass(frozen=True)
class ExploreArch(ConfigDict):
    """Architecture and input geometry of an :class:`ExploreNet` (stored with the weights)."""

    local_cells: int = 240  # side of the local window (map cells of 5 cm)
    wide_cells: int = 960  # side of the wide window
    input_size: int = 60  # pixels a side the windows are reduced to
    semantic: bool = False  # add the goal class's channel (ppo-semantic)
    channels: tuple[int, ...] = (32, 64, 64, 64, 32)  # the five conv layers
    hidden: int = 64  # width of the global feature and of the critic

    def __post_init__(self):
        if len(self.channels) != 5 or min(self.channels) < 1:
            raise ValueError("five positive conv widths expected")
        s = self.input_size
        if s < 8 or s % 4 or self.local_cells % s or self.wide_cells % s:
            raise ValueError(f"input_size {s} must divide both windows and be a multiple of 4")

    @property
    def in_channels(self) -> int:
        return 2 * (5 if self.semantic else 4)

    @property
    def grid(self) -> int:
        """Goal cells a side (two 2× poolings of the input)."""
        return self.input_size // 4

    @property
    def n_actions(self) -> int:
        return self.grid * self.grid

    def goal_offset(self, action: int) -> tuple[int, int]:
        """Map-cell offset (rows, cols) of a goal action from the agent's cell: the centre of
        its grid cell within the local window."""
        a, b = divmod(int(action), self.grid)
        k = self.local_cells // self.grid
        half = self.local_cells // 2
        return a * k + k // 2 - half, b * k + k // 2 - half


class ExploreNet(nn.Module):
    """Actor-critic over :class:`Observer` inputs: ``forward(x) -> (logits (N, A), value (N,))``."""

    def __init__(self, arch: ExploreArch):
        super().__init__()
        self.arch = arch
        c = arch.channels
        self.conv = nn.Sequential(
            nn.Conv2d(arch.in_channels, c[0], 3, padding=1), nn.ReLU(), nn.MaxPool2d(2),
            nn.Conv2d(c[0], c[1], 3, padding=1), nn.ReLU(), nn.MaxPool2d(2),
            nn.Conv2d(c[1], c[2], 3, padding=1), nn.ReLU(),
            nn.Conv2d(c[2], c[3], 3, padding=1), nn.ReLU(),
            nn.Conv2d(c[3], c[4], 3, padding=1), nn.ReLU(),
        )
        self.glob = nn.Linear(2 * c[4], arch.hidden)
        self.actor = nn.Conv2d(c[4] + arch.hidden, 1, 1)
        self.critic = nn.Sequential(nn.Linear(arch.hidden, arch.hidden), nn.ReLU(),
                                    nn.Linear(arch.hidden, 1))

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        f = self.conv(x)
        pooled = torch.cat([f.amax(dim=(2, 3)), f.mean(dim=(2, 3))], dim=1)
        g = torch.relu(self.glob(pooled))
        n, _, h, w = f.shape
        logits = self.actor(torch.cat([f, g[:, :, None, None].expand(n, -1, h, w)], dim=1))
        return logits.flatten(1), self.critic(g).squeeze(1)


def init_weights(net: ExploreNet) -> ExploreNet:
    """Orthogonal initialisation (the PPO custom); a near-uniform first policy."""
    for m in net.modules():
        if isinstance(m, nn.Conv2d | nn.Linear):
            nn.init.orthogonal_(m.weight, math.sqrt(2))
            nn.init.zeros_(m.bias)
    nn.init.orthogonal_(net.actor.weight, 0.01)
    nn.init.orthogonal_(net.critic[-1].weight, 1.0)
    return net


class Observer:
    """Builds the network input from an :class:`EpisodeMap`, remembering the trajectory.

    Call :meth:`reset` at an episode's start and :meth:`__call__` at every decision (it adds the
    pose to the trajectory). Poses are episode-frame (x, y, theta); the trajectory is kept in
    metres, so it survives the map growing.

    >>> from kgnav.agent.camera import Camera
    >>> from kgnav.agent.mapping import MapBuilder
    >>> m = MapBuilder(Camera(), size=240).reset()
    >>> obs = Observer(ExploreArch())(m, (0.0, 0.0, 0.0), "chair")
    >>> obs.shape, obs.dtype
    ((8, 60, 60), dtype('float32'))
    """

    def __init__(self, arch: ExploreArch):
        self.arch = arch
        self.trajectory: list[tuple[float, float]] = []

    def reset(self) -> None:
        self.trajectory = []

    def __call__(self, m: EpisodeMap, pose, goal_class: str | None) -> np.ndarray:
        self.trajectory.append((float(pose[0]), float(pose[1])))
        agent = m.to_cell(pose[0], pose[1])
        cls = None
        if self.arch.semantic and goal_class is not None and goal_class in m.classes:
            cls = m.classes.index(goal_class)
        planes = []
        for side in (self.arch.local_cells, self.arch.wide_cells):
            planes.extend(self._window(m, agent, side, cls))
        return np.stack(planes)

    def _window(self, m: EpisodeMap, agent, side: int, cls: int | None) -> list[np.ndarray]:
        s = self.arch.input_size
        k = side // s
        i0, j0 = agent[0] - side // 2, agent[1] - side // 2
        H, W = m.shape
        a0, a1, b0, b1 = max(i0, 0), min(i0 + side, H), max(j0, 0), min(j0 + side, W)
        obst = np.zeros((side, side), np.uint8)
        expl = np.zeros((side, side), np.uint8)
        goal = np.zeros((side, side), np.uint8) if self.arch.semantic else None
        if a0 < a1 and b0 < b1:
            crop = (a0, a1, b0, b1)
            dst = (slice(a0 - i0, a1 - i0), slice(b0 - j0, b1 - j0))
            obst[dst] = m.blocked(crop)
            known = m.explored[a0:a1, b0:b1]
            if m.prior_explored is not None:
                known = known | m.prior_explored[a0:a1, b0:b1]
            expl[dst] = known
            if goal is not None and cls is not None:
                goal[dst] = m.semantic[cls, a0:a1, b0:b1] > 0
        out = [_pool(obst, k, np.max), _pool(expl, k, np.mean)]
        agent_plane = np.zeros((s, s), np.float32)
        c = s // 2
        agent_plane[c - 1:c + 1, c - 1:c + 1] = 1.0
        traj = np.zeros((s, s), np.float32)
        if self.trajectory:
            pts = np.array([m.to_cell(x, y) for x, y in self.trajectory], np.float64)
            # (row, col) map cells -> (x, y) pixels of this window, in 1/16 px fixed point
            xy = np.stack([(pts[:, 1] - j0 + 0.5) / k, (pts[:, 0] - i0 + 0.5) / k], axis=1)
            fixed = np.round(np.clip(xy, -4 * s, 5 * s) * 16).astype(np.int32)
            cv2.polylines(traj, [fixed.reshape(-1, 1, 2)], False, 1.0, 1, cv2.LINE_8, 4)
        out += [agent_plane, traj]
        if goal is not None:
            out.append(_pool(goal, k, np.max))
        return out


def _pool(a: np.ndarray, k: int, fn) -> np.ndarray:
    n = a.shape[0] // k
    return fn(a.reshape(n, k, n, k), axis=(1, 3)).astype(np.float32)
