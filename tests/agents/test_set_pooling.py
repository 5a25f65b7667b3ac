"""The fused ReLU + pooling kernels against their torch reference, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from agents.sb3.set_pooling import pool_reference, relu_masked_pool


def _same(a: torch.Tensor, b: torch.Tensor) -> bool:
    """Bit for bit, except the sign of a zero: torch's own kernels give +0.0 or -0.0 for the
    same sum depending on the tensor's shape, and no later sum or product with a nonzero term
    can tell the two apart."""
    bits = {torch.float32: torch.int32, torch.float64: torch.int64}[a.dtype]
    nonzero = (a != 0) | (b != 0)
    return torch.equal(a, b) and torch.equal(a[nonzero].view(bits), b[nonzero].view(bits))


def _tables(rng, dtype, n_tables=300, n_rows=16, width=64):
    """Pre-activations with ties, exact zeros and -0.0, padded rows (with nonzero weights, so
    a kernel that forgot the mask in the weighted sum shows), and empty tables."""
    z = rng.normal(size=(n_tables, n_rows, width))
    z[::7, -1] = z[::7, 0]  # duplicate rows: equal positive values tie in the max
    z[::5, :, ::4] = 0.0
    z[1::5, :, 1::4] = -0.0
    n_valid = rng.integers(0, n_rows + 1, n_tables)
    n_valid[: min(10, n_tables // 2)] = 0  # tables with no real row
    valid = (np.arange(n_rows)[None] < n_valid[:, None]).astype(float)
    valid[::3] = valid[::3, rng.permutation(n_rows)]  # padding anywhere, not only at the end
    w = rng.uniform(0, 3, (n_tables, n_rows))
    to = lambda a: torch.tensor(a, dtype=dtype)  # noqa: E731
    return to(z), to(valid), to(w)


def _values_and_grads(pool, z, valid, w, rng):
    """Both outputs and the gradients of z and w under random upstream gradients."""
    upstream = [torch.tensor(rng.normal(size=(len(z), z.shape[2])), dtype=z.dtype) for _ in "am"]
    zz, ww = z.clone().requires_grad_(), w.clone().requires_grad_()
    weighted, maxed = pool(zz, valid, ww)
    ((weighted * upstream[0]).sum() + (maxed * upstream[1]).sum()).backward()
    return weighted.detach(), maxed.detach(), zz.grad, ww.grad


@pytest.mark.parametrize(
    ("dtype", "n_tables", "n_rows", "width"),
    [
        (torch.float32, 300, 16, 64),  # the extractor's default tables, a training minibatch
        (torch.float32, 1, 16, 64),  # one agent's observation
        (torch.float32, 5, 16, 32),
        (torch.float32, 64, 8, 96),
        (torch.float32, 7, 1, 32),
        (torch.float64, 300, 16, 64),
        (torch.float64, 9, 12, 16),
    ],
)
def test_fused_pooling_equals_the_reference_bit_for_bit(dtype, n_tables, n_rows, width):
    from agents.sb3.set_pooling import _in_scope

    rng = np.random.default_rng(2000)
    z, valid, w = _tables(rng, dtype, n_tables, n_rows, width)
    assert _in_scope(z, valid, w)  # the compiled path, not the fallback
    seed = int(rng.integers(1 << 30))
    ref = _values_and_grads(pool_reference, z, valid, w, np.random.default_rng(seed))
    fused = _values_and_grads(relu_masked_pool, z, valid, w, np.random.default_rng(seed))
    for a, b in zip(ref, fused, strict=True):
        assert _same(a, b)
    assert (ref[1][: min(10, n_tables // 2)] == 0).all()  # empty tables pool to zeros


@pytest.mark.parametrize(("n_rows", "width"), [(32, 64), (18, 64), (16, 48), (16, 8)])
def test_tables_outside_the_scope_take_the_reference(n_rows, width):
    """torch adds these rows in another order than one after the other: the compiled sum
    differs from it by a few ulp, so they go through the torch formula itself."""
    from agents.sb3.set_pooling import _in_scope, _ReluMaskedPool

    rng = np.random.default_rng(2004)
    z, valid, w = _tables(rng, torch.float32, 40, n_rows, width)
    assert not _in_scope(z, valid, w)
    # Why the scope stops here (torch 2.13's reduction order): the kernel would not match.
    assert not torch.equal(_ReluMaskedPool.apply(z, valid, w)[0], pool_reference(z, valid, w)[0])
    seed = int(rng.integers(1 << 30))
    ref = _values_and_grads(pool_reference, z, valid, w, np.random.default_rng(seed))
    out = _values_and_grads(relu_masked_pool, z, valid, w, np.random.default_rng(seed))
    for a, b in zip(ref, out, strict=True):
        assert _same(a, b)


def test_broadcast_masks_take_the_reference():
    rng = np.random.default_rng(2005)
    z, valid, w = _tables(rng, torch.float32, 6, 16, 64)
    column = valid[:, :1]  # (B, 1): broadcasts in torch, would be read out of bounds
    for ref, out in zip(pool_reference(z, column, w), relu_masked_pool(z, column, w), strict=True):
        assert torch.equal(ref, out)


def test_a_double_backward_through_the_kernel_raises():
    rng = np.random.default_rng(2006)
    z, valid, w = _tables(rng, torch.float32, 4, 16, 64)
    z.requires_grad_()
    weighted, maxed = relu_masked_pool(z, valid, w)
    (grad,) = torch.autograd.grad((weighted + maxed).pow(2).sum(), z, create_graph=True)
    with pytest.raises(RuntimeError, match="twice|once_differentiable|double"):
        grad.sum().backward()


def test_fused_pooling_without_grad_and_on_one_row():
    rng = np.random.default_rng(2001)
    z, valid, w = _tables(rng, torch.float32, n_tables=5, n_rows=1, width=32)
    with torch.no_grad():
        for ref, fused in zip(
            pool_reference(z, valid, w), relu_masked_pool(z, valid, w), strict=True
        ):
            assert _same(ref, fused)


def test_fused_pooling_passes_nan_on_as_torch_does():
    rng = np.random.default_rng(2002)
    z, valid, w = _tables(rng, torch.float32, n_tables=4, n_rows=6, width=32)
    valid[:] = 1.0
    z[0, 2, 1] = float("nan")
    z[1, 4, 0] = float("nan")
    valid[1, 4] = 0.0  # NaN * 0 is NaN: a padded row's NaN still shows, as in torch
    for ref, fused in zip(pool_reference(z, valid, w), relu_masked_pool(z, valid, w), strict=True):
        assert torch.equal(torch.isnan(ref), torch.isnan(fused))
        assert torch.isnan(fused[0, 1]) and torch.isnan(fused[1, 0])
        finite = ~torch.isnan(ref)
        assert torch.equal(ref[finite], fused[finite])


def test_other_dtypes_take_the_reference():
    z = torch.randn(3, 4, 5, dtype=torch.bfloat16)
    valid = torch.ones(3, 4, dtype=torch.bfloat16)
    w = torch.rand(3, 4, dtype=torch.bfloat16)
    for ref, out in zip(pool_reference(z, valid, w), relu_masked_pool(z, valid, w), strict=True):
        assert out.dtype == torch.bfloat16 and torch.equal(ref, out)


def test_training_with_either_pooling_saves_the_same_model(tmp_path, monkeypatch):
    """Two PPO iterations of ``swarm-phd train`` end with the same weights and Adam state, byte
    for byte, whichever pooling the extractor runs: the fused one changes no training run."""
    import zipfile

    import agents.sb3.features as features
    import agents.sb3.set_pooling as set_pooling
    from swarm_phd.cli import main

    in_scope = set_pooling._in_scope
    compiled = []  # one entry per extractor call of the fused run: took the compiled path?
    monkeypatch.setattr(
        set_pooling, "_in_scope", lambda *t: compiled.append(in_scope(*t)) or compiled[-1]
    )
    saved = {}
    for name in ("fused", "reference"):
        if name == "reference":
            assert compiled and all(compiled)  # the extractor's real tables are in scope
            monkeypatch.setattr(features, "relu_masked_pool", set_pooling.pool_reference)
        out = tmp_path / name
        argv = ["train", "--preset", "lab-3m-4", "--task", "formation", "--observation", "phd"]
        argv += ["--timesteps", "4096", "--n-copies", "4", "--num-cpus", "0", "--seed", "2003"]
        assert main([*argv, "--out", str(out), "--no-progress-bar"]) == 0
        with zipfile.ZipFile(out / "model.zip") as archive:
            saved[name] = {n: archive.read(n) for n in ("policy.pth", "policy.optimizer.pth")}
    assert saved["fused"] == saved["reference"]
