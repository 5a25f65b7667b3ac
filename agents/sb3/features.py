"""A permutation-invariant feature extractor for the neighbour table (Deep Sets).

The observation's table is a *set* of Gaussian components (or true neighbours) sorted by weight
(PHD) or distance (truth): when two components swap rank, a plain MLP sees two rows swap and
has to relearn the same geometry for every slot. Here one small network ``phi`` encodes every
row, and the rows are pooled with the PHD's own weights (``sum_k w_k phi(row_k)``, the integral
of ``phi`` against the PHD intensity) and with a masked max. The pooled code, the odometry and
the task features go to SB3's policy and value heads. Everything after the table (the lidar
sector block of ``SwarmConfig.lidar_sectors`` when present, the odometry, the task features) is
passed on divided by its observation-space bound, so sector ranges arrive as ``r / r_max`` in
[0, 1].

With ``critic_dims`` = P > 0 the last P entries of the observation (a centralised critic's
true-state block, :mod:`agents.sb3.central_critic`) are dropped: the actor never reads them.

Row inputs (scaled to O(1)): ``w``, ``x / 2``, ``y / 2``, ``rho / 2``, ``sqrt(sxx)``,
``sqrt(syy)``, ``sxy``, with ``rho = ||(x, y)||``; rows with ``valid = 0`` are masked out.
"""

from __future__ import annotations

import gymnasium as gym
import torch
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn

from agents.sb3.set_pooling import relu_masked_pool
from swarm_env.observation import ESTIMATE_COLUMNS

ROW = len(ESTIMATE_COLUMNS)
_COL = {name: i for i, name in enumerate(ESTIMATE_COLUMNS)}


class NeighbourSetExtractor(BaseFeaturesExtractor):
    """Deep Sets over the ``top_k`` rows of the ``"phd"``/``"truth"`` observation layout."""

    def __init__(
        self,
        observation_space: gym.spaces.Box,
        top_k: int = 16,
        hidden: int = 64,
        critic_dims: int = 0,
    ) -> None:
        n_read = observation_space.shape[0] - critic_dims
        n_extra = n_read - ROW * top_k
        if n_extra < 2:
            raise ValueError(
                f"observation of size {observation_space.shape[0]} does not hold "
                f"{top_k} table rows plus odometry"
            )
        super().__init__(observation_space, features_dim=2 * hidden + n_extra)
        self.top_k = top_k
        self.n_read = n_read  # the entries the extractor reads (the rest: critic-only)
        self.phi = nn.Sequential(
            nn.Linear(ROW, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU()
        )
        high = observation_space.high[ROW * top_k : self.n_read]
        high = torch.as_tensor(high, dtype=torch.float32)
        self.register_buffer("extra_scale", torch.clamp(high.abs(), min=1e-6))

    def row_inputs(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The rows as ``phi`` reads them (B, K, 7), their pooling weights ``w`` clamped to
        [0, 3] (B, K) and their valid mask (B, K), from observations (B, D)."""
        b = obs.shape[0]
        rows = obs[:, : ROW * self.top_k].reshape(b, self.top_k, ROW)
        w, x, y = (rows[..., _COL[c]] for c in ("w", "x_m", "y_m"))
        sxx, sxy, syy, valid = (
            rows[..., _COL[c]] for c in ("sxx_m2", "sxy_m2", "syy_m2", "valid")
        )
        rho = torch.sqrt(x * x + y * y + 1e-9)
        w = w.clamp(0, 3)
        inputs = torch.stack(
            [
                w,
                x / 2,
                y / 2,
                rho / 2,
                torch.sqrt(sxx.clamp(min=0)).clamp(max=3),
                torch.sqrt(syy.clamp(min=0)).clamp(max=3),
                sxy.clamp(-3, 3),
            ],
            dim=-1,
        )
        return inputs, w, valid > 0.5

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        inputs, w, valid = self.row_inputs(obs)
        # The max over the valid rows: relu >= 0, so the invalid rows' zeros never exceed it,
        # and a table with no valid row gives 0. (Until 2026-12-05 the invalid rows were set
        # to -1e4 and an empty table's max replaced by 0: the same values and gradients, bit
        # for bit; tests/agents/test_sb3.py.) phi's last ReLU runs fused with both poolings,
        # compiled where that is pool_reference bit for bit (agents/sb3/set_pooling.py).
        z = self.phi[:-1](inputs)  # (B, K, H), before phi's last layer, its ReLU
        weighted, maxed = relu_masked_pool(z, valid.to(z.dtype), w)
        extra = obs[:, ROW * self.top_k : self.n_read] / self.extra_scale
        return torch.cat([weighted, maxed, extra], dim=1)
