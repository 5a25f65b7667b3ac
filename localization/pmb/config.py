"""Configuration of the robot-centric Poisson multi-Bernoulli (PMB) localizer.

:class:`PMBConfig` holds the shared sensor, motion, birth and reduction models as a
:class:`~localization.PHDConfig` (field ``phd``), so ``PMBConfig(phd=cfg)`` runs the PMB on
exactly the models the GM-PHD ``RobotCentricPHD(cfg)`` uses, plus the few parameters that only a
multi-Bernoulli filter has (gating, loopy belief propagation, recycling, the track cap).

Shared fields used from ``phd``: the mode (LC / LO), the missed-detection rule, ``prediction``,
``births``, ``lidar`` and ``camera`` (but ``lidar.missed_moments``), and ``reduction`` for the
Poisson intensity.

References
----------
.. [1] J. L. Williams, "Marginal multi-Bernoulli filters: RFS derivation of MHT, JIPDA and
   association-based MeMBer", IEEE Trans. Aerospace and Electronic Systems, 51(3), 2015.
.. [2] J. L. Williams and R. A. Lau, "Approximate evaluation of marginal association
   probabilities with belief propagation", IEEE Trans. Aerospace and Electronic Systems,
   50(4), 2014.
.. [3] J. L. Williams, "Hybrid Poisson and multi-Bernoulli filters", Proc. FUSION 2012
   (recycling of low-existence Bernoulli components into the Poisson intensity).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

from ..config import MOVED_FIELDS, REMOVED_FIELDS, PHDConfig, replace_fields

__all__ = ["PMBConfig", "pmb_config"]


@dataclass(frozen=True, slots=True)
class PMBConfig:
    """Parameters of :class:`~localization.pmb.RobotCentricPMB` and
    :class:`~localization.pmb.PMBBank`.

    Attributes
    ----------
    phd : PHDConfig
        Every model shared with the GM-PHD (see the module docstring). Default ``PHDConfig()``
        (the simulator presets' model); pass the same object the GM-PHD gets so that ``pmb-lc``
        and ``phd-lc`` see identical sensor models.
    gate_sigma : float
        A (track or Poisson component, measurement) pair whose squared Mahalanobis distance of
        the innovation exceeds ``gate_sigma**2`` gets likelihood 0. Default 4: such a pair's
        likelihood is below ``exp(-8) = 3.4e-4`` of its peak, and a true association falls
        outside with probability ``exp(-8) = 3.4e-4`` (2-D lidar) or 6.3e-5 (1-D bearing), so
        the gate removes no association that could matter while keeping the loopy belief
        propagation sparse. (Not tuned.)
    bp_max_iterations : int
        Cap on the loopy belief-propagation sweeps (Williams & Lau 2014). Their messages
        contract (the paper proves convergence); in our problems (a few tracks in each
        measurement's gate) the 1e-12 tolerance is reached in fewer than ~20 sweeps. 100 is a
        safety bound on the cost, not a tuning. (Not tuned.)
    bp_tolerance : float
        Stop when no measurement-to-track message changes by more than this (messages are in
        ``(0, 1]``). 1e-12 puts the marginals at round-off level, so the compiled bank and the
        numpy reference agree to 1e-10 even if they stop one sweep apart. (Not tuned.)
    recycle_threshold : float
        After each update, Bernoulli tracks with existence ``r`` below this move into the
        Poisson intensity as a component of weight ``r`` (Williams 2012 "recycling"; 0.1 is the
        value used there). A Bernoulli below 0.1 is not reported by the Perera 2021 study's metric
        (weight > 0.1) nor by any extraction threshold in use, and in the Poisson it is
        merged/pruned like any PHD component; when it is detected again it comes back as a new
        Bernoulli with ``r = e / (kappa + e)``. (Not tuned.)
    max_tracks : int
        Cap on the number of Bernoulli tracks (the largest ``r`` are kept; the others are
        recycled, so no mass is lost). Default 32: an observer in Perera 2021's 20-robot swarm has
        at most 19 teammates, and the cap leaves room for obstacle tracks (decoys, walls).
        Also the width of :class:`~localization.pmb.PMBBank`'s padded track table. (Not tuned.)
    """

    phd: PHDConfig = field(default_factory=PHDConfig)
    gate_sigma: float = 4.0
    bp_max_iterations: int = 100
    bp_tolerance: float = 1e-12
    recycle_threshold: float = 0.1
    max_tracks: int = 32

    def __post_init__(self) -> None:
        if not isinstance(self.phd, PHDConfig):
            raise ValueError(f"PMBConfig.phd must be a PHDConfig, got {self.phd!r}")
        for name in ("gate_sigma", "bp_tolerance", "recycle_threshold"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ValueError(f"PMBConfig.{name} must be a number, got {value!r}")
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"PMBConfig.{name} must be finite and > 0, got {value!r}")
        if self.recycle_threshold >= 1.0:
            raise ValueError(
                f"PMBConfig.recycle_threshold must be in (0, 1), got {self.recycle_threshold!r}"
            )
        for name in ("bp_max_iterations", "max_tracks"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"PMBConfig.{name} must be an int >= 1, got {value!r}")

    @property
    def gate_mahalanobis2(self) -> float:
        """Squared Mahalanobis gate ``gate_sigma**2``."""
        return float(self.gate_sigma) ** 2


_PHD_FIELDS = {f.name for f in dataclasses.fields(PHDConfig)}


def pmb_config(config: Any = None, overrides: dict[str, Any] | None = None) -> PMBConfig:
    """A :class:`PMBConfig` from ``None`` (defaults), a ``PMBConfig`` or a ``PHDConfig`` (the
    shared models, PMB defaults), with ``overrides`` naming PMB or PHD fields replaced (a PHD
    component takes a dict of its fields: ``{"lidar": {"noise_std_m": 0.04}}``).

    Raises
    ------
    ValueError
        If ``config`` has another type or an override names no field.
    """
    if config is None:
        config = PMBConfig()
    elif isinstance(config, PHDConfig):
        config = PMBConfig(phd=config)
    elif not isinstance(config, PMBConfig):
        raise ValueError(f"config must be a PMBConfig or PHDConfig, got {type(config).__name__}")
    overrides = dict(overrides or {})
    # PHD fields (and the flat names of earlier releases, refused with their new place)
    shared = _PHD_FIELDS | set(MOVED_FIELDS) | set(REMOVED_FIELDS)
    phd_over = {k: overrides.pop(k) for k in list(overrides) if k in shared}
    if phd_over:
        overrides["phd"] = replace_fields(overrides.get("phd", config.phd), phd_over)
    return replace_fields(config, overrides) if overrides else config
