"""Mutual localization from anonymous measurements and the radio (Stegagno 2012).

Each robot estimates its teammates' relative poses ``(x, y, theta)`` and identities from its own
wheel odometry, its own anonymous lidar detections and what teammates broadcast (their
dead-reckoned odometry and their anonymous detections, :class:`swarm_core.records.Broadcast`).

- :mod:`~localization.mutual.se2`: the pose algebra (chapter 2).
- :mod:`~localization.mutual.symmetry`: rotational symmetry and the number of solutions
  (chapter 4, Lemma 1, Propositions 1-4).
- :mod:`~localization.mutual.registration`: binary registration, RANSAC + least squares.
- :mod:`~localization.mutual.multireg`: P-MultiReg, Algorithm 1 (chapter 6.1).
- :mod:`~localization.mutual.particles`: one particle filter per teammate (chapter 6.2).
- :mod:`~localization.mutual.pmultireg`: the P-MultiReg system of one observer.
- :mod:`~localization.mutual.fastslam`: robot-centric FastSLAM with Monte-Carlo data
  association and orientation banks (chapter 5), the thesis's baseline.
- :mod:`~localization.mutual.links`: own odometry and teammates' broadcasts, time alignment.

``swarm-phd mutual`` runs them in the simulator; ``docs/how-to/studies/stegagno2012.md`` explains
them.
"""

from __future__ import annotations

from .fastslam import FastSLAMConfig, FastSLAMLocalizer
from .multireg import MultiRegConfig, MultiRegResult, multi_register
from .particles import MotionNoise, TeammateParticles
from .pmultireg import PMultiRegConfig, PMultiRegLocalizer
from .registration import Registration, register_pair
from .symmetry import (
    is_rotationally_symmetric,
    number_of_solutions,
    symmetric_partition,
    symmetry_order,
)

__all__ = [
    "FastSLAMConfig",
    "FastSLAMLocalizer",
    "MotionNoise",
    "MultiRegConfig",
    "MultiRegResult",
    "PMultiRegConfig",
    "PMultiRegLocalizer",
    "Registration",
    "TeammateParticles",
    "is_rotationally_symmetric",
    "multi_register",
    "number_of_solutions",
    "register_pair",
    "symmetric_partition",
    "symmetry_order",
]
