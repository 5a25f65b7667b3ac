"""The Deep Sets extractor's last ReLU and its two poolings, fused into one compiled pass each way.

:class:`agents.sb3.features.NeighbourSetExtractor` encodes every table row with ``phi`` and
pools the rows twice: weighted by the PHD weights and by a masked max. Written with torch ops
(:func:`pool_reference`), that is about ten passes over a ``(B, K, H)`` tensor per training
minibatch (ReLU, two masks, a sum, a max, and their backward passes). On one CPU thread they
cost about as much as the extractor's matrix products. Measured on 512 real PHD tables of 16
rows (``benchmarks/bench_set_pooling.py``), the extractor's forward and backward took 7.5 ms
with torch ops and 4.3 ms with this module.

:func:`relu_masked_pool` computes the same values and gradients, **bit for bit** but for the
sign of a zero (the float32 sums run over the rows in the order torch's ``sum(dim=1)`` takes,
and the max keeps the first of equal rows, as torch's does). torch itself gives ``+0.0`` or
``-0.0`` for the same sum depending on the tensor's shape; no later sum or product with a
nonzero term can tell the two apart, so a saved model acts as before.
``tests/agents/test_set_pooling.py`` checks this against :func:`pool_reference`, including
ties, empty tables, NaN and float64. Other devices and dtypes use the reference.

The kernels are single-threaded numba functions, so they run on the thread that calls them:
the trainer's one torch thread (see ``docs/agents.md``, Threads).
"""

from __future__ import annotations

import numpy as np
import torch
from numba import njit


def pool_reference(
    z: torch.Tensor, valid: torch.Tensor, w: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """The torch formula (the reference for the compiled path).

    ``z`` (B, K, H): ``phi``'s pre-activations; ``valid`` (B, K): 1.0 for a real row and 0.0
    for padding; ``w`` (B, K): the pooling weights. Returns the weighted sum
    ``sum_k w_k valid_k relu(z_k)`` and the masked max ``max_k valid_k relu(z_k)``, each (B, H).
    Since ``relu >= 0``, padded rows (zeros) never win the max over a real row, and a table
    with no real row pools to zeros.
    """
    masked = torch.relu(z) * valid.unsqueeze(-1)
    return (masked * w.unsqueeze(-1)).sum(dim=1), masked.max(dim=1).values


@njit(cache=True)
def _pool_forward(z, valid, w, weighted, maxed, argmax):  # pragma: no cover - compiled
    """Fill ``weighted``, ``maxed`` (B, H) and ``argmax`` (B, H), the row that won the max."""
    n_tables, n_rows, width = z.shape  # n_rows >= 1
    zero = z.dtype.type(0.0)
    for b in range(n_tables):
        for j in range(width):
            weighted[b, j] = zero
            maxed[b, j] = -np.inf
            argmax[b, j] = 0
        for k in range(n_rows):
            v = valid[b, k]
            wk = w[b, k]
            for j in range(width):
                x = z[b, k, j]
                masked = (zero if x < zero else x) * v  # relu keeps NaN, as torch's does
                weighted[b, j] += masked * wk
                best = maxed[b, j]
                # The first of equal rows wins, and a NaN wins and stays (torch's max).
                if best == best and (masked > best or masked != masked):
                    maxed[b, j] = masked
                    argmax[b, j] = k


@njit(cache=True)
def _pool_backward(z, valid, w, argmax, grad_weighted, grad_maxed, grad_z):  # pragma: no cover
    """Fill ``grad_z`` (B, K, H) from the gradients of both pooled outputs (B, H)."""
    n_tables, n_rows, width = z.shape
    zero = z.dtype.type(0.0)
    for b in range(n_tables):
        for k in range(n_rows):
            v = valid[b, k]
            wk = w[b, k]
            for j in range(width):
                from_max = grad_maxed[b, j] if argmax[b, j] == k else zero
                grad = (grad_weighted[b, j] * wk + from_max) * v
                grad_z[b, k, j] = zero if z[b, k, j] <= zero else grad


class _ReluMaskedPool(torch.autograd.Function):
    @staticmethod
    def forward(ctx, z, valid, w):  # noqa: D102 - see relu_masked_pool
        z_np = z.detach().numpy()
        n_tables, _, width = z_np.shape
        weighted = np.empty((n_tables, width), dtype=z_np.dtype)
        maxed = np.empty((n_tables, width), dtype=z_np.dtype)
        argmax = np.empty((n_tables, width), dtype=np.int64)
        _pool_forward(z_np, valid.detach().numpy(), w.detach().numpy(), weighted, maxed, argmax)
        ctx.save_for_backward(z, valid, w, torch.from_numpy(argmax))
        return torch.from_numpy(weighted), torch.from_numpy(maxed)

    @staticmethod
    def backward(ctx, grad_weighted, grad_maxed):  # noqa: D102
        z, valid, w, argmax = ctx.saved_tensors
        grad_z = grad_w = None
        if ctx.needs_input_grad[0]:
            grad_np = np.empty(z.shape, dtype=z.detach().numpy().dtype)
            _pool_backward(
                z.detach().numpy(),
                valid.detach().numpy(),
                w.detach().numpy(),
                argmax.numpy(),
                grad_weighted.contiguous().numpy(),
                grad_maxed.contiguous().numpy(),
                grad_np,
            )
            grad_z = torch.from_numpy(grad_np)
        if ctx.needs_input_grad[2]:  # only when the observation itself requires grad
            masked = torch.relu(z.detach()) * valid.unsqueeze(-1)
            grad_w = (grad_weighted.unsqueeze(1) * masked).sum(dim=-1)
        return grad_z, None, grad_w


def relu_masked_pool(
    z: torch.Tensor, valid: torch.Tensor, w: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`pool_reference`'s values and gradients, compiled (CPU float32/float64 tensors).

    ``z`` (B, K, H), ``valid`` and ``w`` (B, K), all of one dtype; returns the weighted sum
    and the masked max, each (B, H). Other devices or dtypes, or a ``valid`` that requires
    grad, go through the reference.
    """
    if (
        z.device.type != "cpu"
        or z.dtype not in (torch.float32, torch.float64)
        or valid.dtype != z.dtype
        or w.dtype != z.dtype
        or z.dim() != 3
        or z.shape[1] == 0
        or valid.requires_grad
    ):
        return pool_reference(z, valid, w)
    return _ReluMaskedPool.apply(z.contiguous(), valid.contiguous(), w.contiguous())
