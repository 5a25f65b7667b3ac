"""Many robots' PMB localizers advanced together: :class:`PMBBank`.

The PMB family of the compiled banks (:class:`localization.bank.FilterBank`, the driver it
shares with :class:`localization.PHDBank`): the same ``step(feed)``, ``apply(calls)`` with the
same call tuples, ``predict`` / ``update_lidar`` / ``update_camera(robots, ...)``,
``reset()``, ``padded_tables()``, ``views[r]``, pickling; both banks accept and reject exactly
the same input. The padded table it shows holds the **Bernoulli tracks** (weight row =
existence ``r``), so an observation encoder written for the GM-PHD's table reads the PMB's
unchanged; the Poisson intensity of undetected teammates is its second table
(:meth:`PMBBank.poisson_table`).

Every robot gets what its own :class:`~localization.pmb.RobotCentricPMB` computes for the same
calls (to 1e-10, ``tests/localization/test_pmb_bank.py``).

>>> import numpy as np
>>> from localization.pmb import PMBBank, PMBConfig
>>> bank = PMBBank(PMBConfig(), n_robots=20)
>>> bank.apply([[("predict", np.zeros(3)), ("lidar", np.array([[1.0, 0.5]]), None)]] + [[]] * 19)
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..bank import BankTable, FilterBank
from ..mixture import GaussianMixture
from . import kernels
from .config import PMBConfig, pmb_config
from .filter import RobotCentricPMB, estimate_table

__all__ = ["PMBBank"]


class PMBBank(FilterBank):
    """``n_robots`` robot-centric PMB filters sharing one config, updated in batches
    (:class:`~localization.bank.FilterBank`; per robot the math of
    :class:`~localization.pmb.RobotCentricPMB`).

    Parameters
    ----------
    config : PMBConfig or PHDConfig
        Configuration of every filter (a ``PHDConfig``: shared models, PMB defaults).
    n_robots : int
        Number of filters ``R``.

    Notes
    -----
    Tables: the tracks ``(6, R, max_tracks)`` (shown by :meth:`padded_tables`, ``w`` =
    existence) and the Poisson intensities ``(6, R, phd.reduction.max_components)``. Bounds per
    robot and filter call: ``sum r + sum Poisson w`` obeys the GM-PHD's time-update bound, and
    ``<= sum r + sum (1 - P_d) w_Poisson + M`` (or ``K`` bearings) per update; every existence
    in ``[0, 1]``, at most ``max_tracks`` tracks.
    """

    name = "pmb"
    weight_meaning = "existence"
    tables = (
        BankTable("tracks", "track_counts", lambda c: c.max_tracks),
        BankTable("poisson", "poisson_counts", lambda c: c.phd.reduction.max_components),
    )
    reference = RobotCentricPMB
    pack_params = staticmethod(kernels.pack_pmb_params)
    kernel = staticmethod(kernels.apply_calls)
    estimate_table = staticmethod(estimate_table)

    @classmethod
    def checked_config(cls, config: Any) -> PMBConfig:
        try:
            return pmb_config(config)
        except ValueError as exc:
            raise ValueError(f"config must be a PMBConfig or PHDConfig, got {config!r}") from exc

    @property
    def reads_scans(self) -> bool:
        """Whether the lidar calls' scan profiles are used (``PHDConfig.reads_scans``). A
        :class:`~localization.feed.SwarmFeed` packs them only then."""
        return self.config.phd.reads_scans

    def filter_with_mixture(self, mixture: GaussianMixture) -> RobotCentricPMB:
        """A reference filter whose tracks are ``mixture`` (weights = existences in
        ``[0, 1]``) and whose Poisson intensity is empty."""
        f = RobotCentricPMB(self.config)
        f.set_state(mixture)
        return f

    def poisson_table(self, robot: int) -> np.ndarray:
        """Robot ``robot``'s Poisson intensity, ``(6, K)`` (a new array)."""
        return self._table_of(1, self._robot(robot))
