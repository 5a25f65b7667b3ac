"""Robot-centric GM-PHD relative localization (numpy reference, numba-compiled swarm bank).

Each robot runs its own :class:`RobotCentricPHD` on its own anonymous measurements (wheel
odometry, lidar detections, camera bearings) and estimates, in its own body frame, how many
teammates are around it and where. Nothing here knows about the simulator, PettingZoo or ROS.

>>> from localization import PHDConfig, RobotCentricPHD
>>> f = RobotCentricPHD(PHDConfig())  # the simulator's model; PHDConfig.perera2021(): the study's

Modules: :mod:`~localization.config` (``PHDConfig`` and its components),
:mod:`~localization.mixture` (``GaussianMixture`` and the component table),
:mod:`~localization.gaussian` (Kalman/EKF math), :mod:`~localization.detection` (``P_s``,
``P_d``), :mod:`~localization.phd` (time and
measurement updates), :mod:`~localization.reducer` (prune/merge/cap),
:mod:`~localization.filter` (the orchestrator), :mod:`~localization.bank` (``PHDBank``: every
robot's filter advanced in one compiled call, :mod:`~localization.kernels`),
:mod:`~localization.frames` (measurements moved into the filter's frame) and
:mod:`~localization.metrics`.
:mod:`~localization.id_phd` (``IDPHD``: teammate identities from communicated odometry,
Stegagno 2013) and :mod:`~localization.baselines` (the IR-UKF study's UKF and Lee 2012's
particle filter, on identified range-bearing measurements) are the identity-aware localizers.

References
----------
.. [1] B.-N. Vo and W.-K. Ma, "The Gaussian Mixture Probability Hypothesis Density Filter",
   IEEE Trans. Signal Processing, 54(11):4091-4104, 2006.
.. [2] Perera 2021 (PHD-filter relative localization with lidar and camera), chapter 3.
"""

from __future__ import annotations

import swarm_core  # noqa: F401  (kernel threading defaults, before numba loads OpenMP)

from . import metrics
from .bank import PHDBank
from .config import PHDConfig
from .filter import RobotCentricPHD
from .id_phd import IDPHD, IDPHDConfig
from .mixture import GaussianMixture

__all__ = [
    "PHDConfig",
    "RobotCentricPHD",
    "PHDBank",
    "GaussianMixture",
    "metrics",
    "IDPHD",
    "IDPHDConfig",
]
