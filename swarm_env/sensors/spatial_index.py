"""A uniform grid (cell list) over shapes, so a sensor reading visits only nearby shapes.

The sensors' brute-force kernels test every reading against every shape of the scene, which
costs ``readings x shapes``: with the Perera 2021 study's density kept (the arena grows with the
swarm) that is O(N^2) per step, although each robot only ever sees a disc of fixed size (lidar
reach ~10 m, camera ~5 m). A :class:`CellGrid` bins the shapes once per sensor call (a counting
sort, O(M)); a reading then gathers the shapes of the cells that reach within its radius, and runs
exactly the brute-force tests on them. The index only decides which shapes are *tested*, never what
a test answers: every shape it leaves out fails the reading's own range test, so the results are
bit for bit those of the brute-force kernels (``tests/swarm_env/test_spatial_index.py``).

Layout: each shape is binned by its centre ``xy`` (circle centre, segment midpoint) and has an
``extent`` (circle radius, half a segment's length): every point of it lies within ``extent``
of its centre. Shapes wider than a cell (walls) or with a non-finite centre or extent go to one
extra "always" cell, visited by every query. Shapes also carry a ``slot`` (the instant of a
time-stacked scene: 0 for static shapes, ``t + 1`` for instant t), and a query names the slots
it wants. The CSR arrays order the items by ``(slot, cell, index)``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

#: Default cell side, m: ~ a robot's neighbourhood at Perera 2021's density (0.56 robots / m^2).
CELL_M = 1.0
#: At most this many cells along a side: a scene with a far outlier does not allocate a huge
#: grid (the cells grow instead).
MAX_CELLS_PER_SIDE = 128
#: Added to every query radius, m: covers the rounding of a centre's cell and of a rectangle
#: distance (~1e-15 m); it only ever adds shapes to a query, never removes one.
MARGIN_M = 1e-6


def build_grid(
    xy: np.ndarray,
    extent: np.ndarray,
    slot: np.ndarray | None = None,
    n_slots: int = 1,
    cell_m: float = CELL_M,
) -> tuple:
    """Bin M shapes into a uniform grid.

    Parameters
    ----------
    xy : ndarray, shape (M, 2)
        Shape centres, world frame, m.
    extent : ndarray, shape (M,)
        Every point of shape m lies within ``extent[m]`` of ``xy[m]``, m (>= 0).
    slot : ndarray, shape (M,), int, optional
        Slot of each shape in ``[0, n_slots)`` (default: all 0).
    n_slots : int
    cell_m : float
        Cell side, m (grown if the shapes' bounding box would need more than
        :data:`MAX_CELLS_PER_SIDE` cells along a side).

    Returns
    -------
    tuple
        ``(start, items, x0, y0, cell, nx, ny, reach_extent)``, the form the kernels take:
        ``start`` (n_slots (nx ny + 1) + 1,) CSR bounds of the items of key
        ``slot (nx ny + 1) + cell`` (key ``slot (nx ny + 1) + nx ny``: the slot's "always"
        cell), ``items`` (M,) shape indices, ``(x0, y0)`` the grid's lower-left corner, m,
        ``cell`` its cell side, m, ``nx, ny`` its cells, ``reach_extent`` the largest extent of
        a binned (not "always") shape, m.
    """
    xy = np.ascontiguousarray(xy, dtype=np.float64).reshape(-1, 2)
    extent = np.ascontiguousarray(extent, dtype=np.float64).reshape(-1)
    m = xy.shape[0]
    if extent.shape[0] != m:
        raise ValueError(f"build_grid: extent {extent.shape} must have one entry per shape ({m})")
    if slot is None:
        slot = np.zeros(m, dtype=np.intp)
    slot = np.ascontiguousarray(slot, dtype=np.intp).reshape(-1)
    if slot.shape[0] != m or (m and (slot.min() < 0 or slot.max() >= n_slots)):
        raise ValueError(f"build_grid: slot must be (M,) = ({m},) in [0, {n_slots})")
    if not (math.isfinite(cell_m) and cell_m > 0.0):
        raise ValueError(f"build_grid: cell_m must be finite and > 0, got {cell_m!r}")
    finite = np.isfinite(xy).all(axis=1) & np.isfinite(extent) & (extent <= cell_m)
    if finite.any():
        lo, hi = xy[finite].min(axis=0), xy[finite].max(axis=0)
    else:
        lo = hi = np.zeros(2)
    span = float(max(hi[0] - lo[0], hi[1] - lo[1]))
    cell = max(float(cell_m), span / (MAX_CELLS_PER_SIDE - 1))
    nx = int(math.floor((hi[0] - lo[0]) / cell)) + 1
    ny = int(math.floor((hi[1] - lo[1]) / cell)) + 1
    start, items, reach_extent = _bin(
        xy, extent, slot, finite, n_slots, float(lo[0]), float(lo[1]), cell, nx, ny
    )
    return start, items, float(lo[0]), float(lo[1]), cell, nx, ny, reach_extent


@njit(cache=True)
def _bin(xy, extent, slot, binned, n_slots, x0, y0, cell, nx, ny):
    """Counting sort of the shapes by ``(slot, cell)``, stable (index order within a key)."""
    m = xy.shape[0]
    n_cells = nx * ny
    stride = n_cells + 1
    key = np.empty(m, dtype=np.intp)
    counts = np.zeros(n_slots * stride + 1, dtype=np.intp)
    inv = 1.0 / cell
    reach_extent = 0.0
    for i in range(m):
        if binned[i]:
            ix = min(max(int(math.floor((xy[i, 0] - x0) * inv)), 0), nx - 1)
            iy = min(max(int(math.floor((xy[i, 1] - y0) * inv)), 0), ny - 1)
            key[i] = slot[i] * stride + iy * nx + ix
            reach_extent = max(reach_extent, extent[i])
        else:
            key[i] = slot[i] * stride + n_cells
        counts[key[i] + 1] += 1
    start = np.cumsum(counts)
    fill = start[:-1].copy()
    items = np.empty(m, dtype=np.intp)
    for i in range(m):
        items[fill[key[i]]] = i
        fill[key[i]] += 1
    return start, items, reach_extent


@njit(cache=True)
def gather(grid, slot, px, py, radius, out, n):
    """Append to ``out[n:]`` the shapes of ``slot`` that may come within ``radius`` m of
    ``(px, py)``: those of every cell whose rectangle lies within ``radius + reach_extent +``
    :data:`MARGIN_M`, and the slot's "always" shapes. Returns the new count.

    ``out`` must have room for every shape of the slot. The order is by cell, not by index:
    callers whose result depends on order sort it (or use an order-free rule).
    """
    start, items, x0, y0, cell, nx, ny, reach_extent = grid
    stride = nx * ny + 1
    base = slot * stride
    r = radius + reach_extent + MARGIN_M
    r2 = r * r
    if math.isfinite(px) and math.isfinite(py) and math.isfinite(r):
        # Clamped as floats first: a far point must not overflow the int conversion.
        ix0 = int(max(math.floor((px - r - x0) / cell), 0.0))
        ix1 = int(min(math.floor((px + r - x0) / cell), nx - 1.0))
        iy0 = int(max(math.floor((py - r - y0) / cell), 0.0))
        iy1 = int(min(math.floor((py + r - y0) / cell), ny - 1.0))
    else:  # a non-finite point or radius: every cell (the tests then decide, as brute force)
        ix0, ix1, iy0, iy1 = 0, nx - 1, 0, ny - 1
        r2 = math.inf
    for iy in range(iy0, iy1 + 1):
        cy0 = y0 + iy * cell
        dy = max(cy0 - py, py - (cy0 + cell), 0.0)
        if dy * dy > r2:
            continue
        for ix in range(ix0, ix1 + 1):
            cx0 = x0 + ix * cell
            dx = max(cx0 - px, px - (cx0 + cell), 0.0)
            if dx * dx + dy * dy > r2:
                continue
            key = base + iy * nx + ix
            for q in range(start[key], start[key + 1]):
                out[n] = items[q]
                n += 1
    key = base + nx * ny
    for q in range(start[key], start[key + 1]):
        out[n] = items[q]
        n += 1
    return n


def query(grid: tuple, slots, px: float, py: float, radius: float) -> np.ndarray:
    """The shapes of ``slots`` that :func:`gather` returns for one point, sorted (M',).

    For tests and callers outside numba; the kernels call :func:`gather` directly.
    """
    out = np.empty(grid[1].shape[0], dtype=np.intp)
    n = 0
    for s in slots:
        n = gather(grid, int(s), float(px), float(py), float(radius), out, n)
    return np.sort(out[:n])
