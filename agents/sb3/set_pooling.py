"""The Deep Sets extractor's last ReLU and its two poolings, fused into one compiled pass each way.

:class:`agents.sb3.features.NeighbourSetExtractor` encodes every table row with ``phi`` and
pools the rows twice: weighted by the PHD weights and by a masked max. Written with torch ops
(:func:`pool_reference`), that is about ten passes over a ``(B, K, H)`` tensor per training
minibatch (ReLU, two masks, a sum, a max, and their backward passes). On one CPU thread they
cost about as much as the extractor's matrix products. Measured on 512 real PHD tables of 16
rows (``benchmarks/bench_set_pooling.py``), the extractor's forward and backward took 6.3-7.5
ms with torch ops and 4.0-4.3 ms with this module.

:func:`relu_masked_pool` computes the same values and gradients **bit for bit** (but for the
sign of a zero, which no later sum or product with a nonzero term can tell apart), within a
scope: float32 tables of at most 16 rows whose width is a multiple of 32 (float64: of 16),
such as the extractor's default 16 rows x 64. There torch's CPU ``sum(dim=1)`` adds the rows
one after the other, as the kernel does, and the max keeps the first of equal rows, as
torch's does. For more rows or other widths torch adds the rows in another order (blocks of
16, interleaved accumulators for the columns past a multiple of 32), so those tables, and
other devices, dtypes or shapes, go through :func:`pool_reference`: every extractor computes
exactly what the torch formula computes. ``tests/agents/test_set_pooling.py`` checks the
scope against the reference (ties, empty tables, padding with nonzero weights, NaN,
float64); a torch whose reduction order changed would fail it.

The kernels are single-threaded numba functions, so they run on the thread that calls them:
the trainer's one torch thread (see ``docs/concepts/architecture.md``, Threads). They call no
other module's
kernel and read no module constant, so numba's own cache stamp (this file's) is enough: they
need not share the project stamp of ``swarm_core.kernel_stamp.PACKAGES`` (add ``agents``
there and in ``swarm_env.kernel_cache.PACKAGES`` if they ever do).
"""

from __future__ import annotations

import numpy as np
import torch
from numba import njit
from torch.autograd.function import once_differentiable


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
    masked = _masked(z, valid)
    return (masked * w.unsqueeze(-1)).sum(dim=1), masked.max(dim=1).values


def _masked(z: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """``valid_k relu(z_k)`` (B, K, H)."""
    return torch.relu(z) * valid.unsqueeze(-1)


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
    @once_differentiable  # the kernel's gradient has no graph: a double backward must raise
    def backward(ctx, grad_weighted, grad_maxed):  # noqa: D102
        z, valid, w, argmax = ctx.saved_tensors
        grad_z = grad_w = None
        if ctx.needs_input_grad[0]:
            grad_z = torch.empty_like(z)
            _pool_backward(
                z.detach().numpy(),
                valid.detach().numpy(),
                w.detach().numpy(),
                argmax.numpy(),
                grad_weighted.contiguous().numpy(),
                grad_maxed.contiguous().numpy(),
                grad_z.numpy(),
            )
        if ctx.needs_input_grad[2]:  # only when the observation itself requires grad
            grad_w = (grad_weighted.unsqueeze(1) * _masked(z.detach(), valid)).sum(dim=-1)
        return grad_z, None, grad_w


def relu_masked_pool(
    z: torch.Tensor, valid: torch.Tensor, w: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`pool_reference`'s values and gradients: compiled within the scope where they
    are bit for bit the reference's (see the module docstring), the reference elsewhere.

    ``z`` (B, K, H), ``valid`` and ``w`` (B, K), all of one dtype; returns the weighted sum
    and the masked max, each (B, H). The compiled path gives first derivatives only (a double
    backward raises).
    """
    if _in_scope(z, valid, w):
        return _ReluMaskedPool.apply(z.contiguous(), valid.contiguous(), w.contiguous())
    return pool_reference(z, valid, w)


#: The widths (columns) the compiled sum matches torch's bit for bit at: multiples of these.
#: torch's CPU sum kernel reduces 4 SIMD vectors of columns at a time (4 x 8 float32 or 4 x 4
#: float64 lanes in its AVX2 build, which it also runs on AVX-512 hosts) row after row, and
#: the leftover columns another way; a torch built otherwise fails the bit-for-bit test.
_WIDTH_STEP = {torch.float32: 32, torch.float64: 16}
#: ... and the most rows (torch adds more rows in blocks, in another order).
_MAX_ROWS = 16


def _in_scope(z: torch.Tensor, valid: torch.Tensor, w: torch.Tensor) -> bool:
    """CPU tensors of one float dtype, shaped (B, K, H) and (B, K) (no broadcasting: the kernel
    indexes them), 1 <= K <= 16 and H a multiple of the dtype's step, a mask without grad."""
    step = _WIDTH_STEP.get(z.dtype)
    return (
        step is not None
        and z.device.type == "cpu"
        and valid.dtype == w.dtype == z.dtype
        and z.dim() == 3
        and 1 <= z.shape[1] <= _MAX_ROWS
        and z.shape[2] % step == 0
        and valid.shape == w.shape == z.shape[:2]
        and valid.device == w.device == z.device
        and not valid.requires_grad
    )
