"""Baselines from the source studies, for comparison with the (ID-)PHD filters.

Both assume what their source's sensors give and this project's lidar does not: **identified**
range-bearing measurements (IR-UKF study: per-robot IR modulation frequencies; Lee 2012:
signatures). In ``swarm-phd evaluate`` they get the identity of each lidar detection from the
simulator's ground truth (an oracle standing in for that hardware); the PHD filters get the
same detections anonymously. Each is a small class with the shape of the other localizers:
``predict(own_odometry, teammate_odometry)``, ``update({id: (range_m, bearing_rad)})``,
``estimate() -> {id: pose}`` and ``mixture`` (one unit-weight component per tracked teammate).

- :class:`UKFTracker` (:mod:`~localization.baselines.ukf`, IR-UKF study): one unscented Kalman
  filter per teammate, state ``(x, y, psi)`` in the observer frame, differential-drive motion
  from the teammate's communicated odometry composed with the observer's own, range-bearing
  measurement with a wrapped angle residual.
- :class:`ParticleFilterTracker` (:mod:`~localization.baselines.particle`, Lee 2012): one
  particle cloud per teammate, damped constant-velocity drift, range-bearing likelihood,
  resample 90 % with replacement, re-seed 10 % uniformly, diffuse.

The IR-UKF study's swarm-level pair (:mod:`~localization.baselines.direct`: SLSQP direct estimation
with no initial state and Kabsch alignment; :class:`CentralizedUKF`: one UKF per robot in one
global frame) run in ``swarm-phd seed003``, not per observer.

``docs/concepts/localizers.md`` ("ID-PHD and baselines") lists what was adapted from the studies.
"""

from __future__ import annotations

from .centralized_ukf import CentralizedUKF, CentralizedUKFConfig
from .direct import DirectResult, align_poses, direct_estimate, kabsch
from .particle import ParticleConfig, ParticleFilterTracker
from .ukf import UKFConfig, UKFTracker

__all__ = [
    "CentralizedUKF",
    "CentralizedUKFConfig",
    "DirectResult",
    "ParticleConfig",
    "ParticleFilterTracker",
    "UKFConfig",
    "UKFTracker",
    "align_poses",
    "direct_estimate",
    "kabsch",
]
