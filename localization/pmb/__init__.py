"""Robot-centric Poisson multi-Bernoulli (PMB) localizer, beside the GM-PHD.

:class:`RobotCentricPMB` is the numpy reference (one filter); :class:`PMBBank` runs every
robot's filter in one numba-compiled call, with the interface of :class:`localization.PHDBank`.
Both take a :class:`PMBConfig` (whose ``phd`` field holds the sensor models shared with the
GM-PHD) or a plain :class:`~localization.PHDConfig` (PMB defaults for the rest).

The filter's recursion and its references are in :mod:`localization.pmb.filter`.
"""

from __future__ import annotations

from .config import PMBConfig, pmb_config
from .filter import RobotCentricPMB, Tracks

__all__ = ["PMBConfig", "pmb_config", "RobotCentricPMB", "Tracks", "PMBBank"]


def __getattr__(name: str):
    # The bank imports numba; load it only when asked for.
    if name == "PMBBank":
        from . import bank

        return getattr(bank, name)
    raise AttributeError(name)
