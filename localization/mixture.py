"""Gaussian-mixture containers.

Two representations of the same thing:

* :class:`GaussianMixture` is the public, read-only snapshot: ``weights (N,)``, ``means (N, 2)``,
  ``covs (N, 2, 2)``, in the observer's robot frame (metres, m^2).
* The *component table* is what the filter math works on: one float64 array of shape ``(6, N)``
  whose rows are ``w, x, y, Pxx, Pxy, Pyy`` (``ROW_*`` below). Rows are contiguous, so every
  per-component quantity is one cheap view, and pruning/capping/concatenation move one array
  instead of three. Storing only the three distinct covariance entries makes every
  covariance symmetric by construction.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "GaussianMixture",
    "ROW_W",
    "ROW_X",
    "ROW_Y",
    "ROW_PXX",
    "ROW_PXY",
    "ROW_PYY",
    "N_ROWS",
    "empty_table",
    "table_from_arrays",
    "arrays_from_table",
]

ROW_W, ROW_X, ROW_Y, ROW_PXX, ROW_PXY, ROW_PYY = range(6)
N_ROWS = 6


def empty_table() -> np.ndarray:
    """Return an empty component table, shape ``(6, 0)``."""
    return np.empty((N_ROWS, 0))


def table_from_arrays(weights: np.ndarray, means: np.ndarray, covs: np.ndarray) -> np.ndarray:
    """Pack ``weights (N,)``, ``means (N, 2)``, ``covs (N, 2, 2)`` into a ``(6, N)`` table.

    The off-diagonal is taken as the average of ``covs[:, 0, 1]`` and ``covs[:, 1, 0]``
    (symmetrisation guard: a slightly asymmetric input becomes the nearest symmetric matrix).
    """
    weights = np.asarray(weights, dtype=float)
    means = np.asarray(means, dtype=float)
    covs = np.asarray(covs, dtype=float)
    _check_shapes(weights, means, covs)
    table = np.empty((N_ROWS, weights.shape[0]))
    table[ROW_W] = weights
    table[ROW_X] = means[:, 0]
    table[ROW_Y] = means[:, 1]
    table[ROW_PXX] = covs[:, 0, 0]
    table[ROW_PXY] = 0.5 * (covs[:, 0, 1] + covs[:, 1, 0])
    table[ROW_PYY] = covs[:, 1, 1]
    return table


def arrays_from_table(table: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unpack a ``(6, N)`` table into new ``weights (N,)``, ``means (N, 2)``, ``covs (N, 2, 2)``.

    Returns
    -------
    weights, means, covs : ndarray
        Fresh arrays (the table is not referenced).
    """
    n = table.shape[1]
    weights = table[ROW_W].copy()
    means = table[ROW_X : ROW_Y + 1].T.copy()
    covs = np.empty((n, 2, 2))
    covs[:, 0, 0] = table[ROW_PXX]
    covs[:, 0, 1] = table[ROW_PXY]
    covs[:, 1, 0] = table[ROW_PXY]
    covs[:, 1, 1] = table[ROW_PYY]
    return weights, means, covs


def _check_shapes(weights: np.ndarray, means: np.ndarray, covs: np.ndarray) -> None:
    if weights.ndim != 1:
        raise ValueError(f"weights must have shape (N,), got {weights.shape}")
    n = weights.shape[0]
    if means.shape != (n, 2):
        raise ValueError(f"means must have shape ({n}, 2) to match weights, got {means.shape}")
    if covs.shape != (n, 2, 2):
        raise ValueError(f"covs must have shape ({n}, 2, 2) to match weights, got {covs.shape}")


@dataclass(frozen=True, slots=True)
class GaussianMixture:
    """A read-only 2-D Gaussian mixture (a PHD intensity) in the observer's robot frame.

    Parameters
    ----------
    weights : ndarray, shape (N,)
        Component weights; their sum is the expected number of teammates.
    means : ndarray, shape (N, 2)
        Component means ``[x_m, y_m]`` in the robot frame (x forward, y left).
    covs : ndarray, shape (N, 2, 2)
        Component covariances in m^2 (symmetric positive definite).

    Notes
    -----
    Writeable input arrays are copied (as float64) and the stored arrays are flagged
    read-only, so a snapshot never changes under its reader; build a new mixture instead of
    editing one. Shapes are checked in ``__post_init__``.
    """

    weights: np.ndarray
    means: np.ndarray
    covs: np.ndarray

    def __post_init__(self) -> None:
        for name in ("weights", "means", "covs"):
            array = getattr(self, name)
            if not isinstance(array, np.ndarray) or array.flags.writeable or array.dtype != float:
                array = np.array(array, dtype=float)
                array.flags.writeable = False
                object.__setattr__(self, name, array)
        _check_shapes(self.weights, self.means, self.covs)

    @classmethod
    def empty(cls) -> GaussianMixture:
        """Return a mixture with no components."""
        return cls(np.empty(0), np.empty((0, 2)), np.empty((0, 2, 2)))

    @classmethod
    def from_table(cls, table: np.ndarray) -> GaussianMixture:
        """Build a snapshot from a ``(6, N)`` component table (copies the data)."""
        arrays = arrays_from_table(table)
        for array in arrays:
            array.flags.writeable = False  # fresh private copies: no second copy needed
        return cls(*arrays)

    def to_table(self) -> np.ndarray:
        """Return the ``(6, N)`` component table of this mixture (a new array)."""
        return table_from_arrays(self.weights, self.means, self.covs)

    def __len__(self) -> int:
        return int(self.weights.shape[0])

    @property
    def total_weight(self) -> float:
        """Sum of the weights: the expected number of targets (teammates)."""
        return float(self.weights.sum())
