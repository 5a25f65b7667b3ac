"""Wheel odometry: encoder pulses of the true wheel motion, with slip, as U = [dx, dy, dpsi].

Perera 2021's Cherokey has 16-pulse encoders behind a 120:1 gearbox, i.e. 1920 pulses per wheel
revolution (Perera 2021, sec. 5.3). The wheels turn as the motor controller drives them (the
acceleration-limited command), so when the body is blocked by a wall or pushed by a teammate the
encoders keep counting: that is wheel slip, and it shows up in the odometry exactly as on a real
robot. Small random slip is added on every physics substep.

Equations (31)-(32) of Perera 2021, with the sign of (32) fixed for REP-103: the study writes
``P_L - P_R`` (clockwise positive); a left turn (counter-clockwise, positive yaw) has the right
wheel travelling further, so ``dpsi = 2 pi r_w (P_R - P_L) / (1920 w_ax)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from swarm_core.validation import check_int_range, check_number_fields, check_positive


@dataclass(frozen=True, slots=True)
class OdometryConfig:
    """Encoder odometry.

    Attributes
    ----------
    rate_hz : float
        Odometry sample rate (one filter time update per sample).
    pulses_per_revolution : int
        Encoder pulses per wheel revolution (16 per motor rev x 120:1 gearbox).
    slip_noise_std : float
        Std of the multiplicative slip on each wheel's rotation per physics substep (fraction).
    """

    rate_hz: float = 10.0
    pulses_per_revolution: int = 1920
    slip_noise_std: float = 0.02

    def __post_init__(self) -> None:
        check_number_fields(self)
        check_positive("odometry.rate_hz", self.rate_hz)
        check_int_range("odometry.pulses_per_revolution", self.pulses_per_revolution, 1, 10**7)
        if not 0.0 <= self.slip_noise_std < 0.5:
            raise ValueError(
                f"odometry.slip_noise_std must be in [0, 0.5), got {self.slip_noise_std!r}"
            )


def pulses_to_delta(
    pulses: np.ndarray, wheel_radius_m: float, axle_width_m: float, pulses_per_revolution: int
) -> np.ndarray:
    """Perera 2021 eqs. (31)-(32): pulse counts to body-frame displacement.

    Parameters
    ----------
    pulses : ndarray, shape (N, 2), int
        ``[P_L, P_R]`` counted over the interval.

    Returns
    -------
    ndarray, shape (N, 3)
        ``[dx_m, dy_m, dpsi_rad]`` in the body frame at the start of the interval. The chord of a
        constant-curvature arc of length D turning by theta points at theta/2.
    """
    pulses = np.ascontiguousarray(pulses, dtype=np.float64).reshape(-1, 2)
    metres_per_pulse = 2.0 * np.pi * wheel_radius_m / pulses_per_revolution
    return _pulses_to_delta(pulses, metres_per_pulse, float(axle_width_m))


@njit(cache=True)
def _pulses_to_delta(pulses, metres_per_pulse, axle_width_m):
    """:func:`pulses_to_delta` for ``pulses`` (N, 2) float: (N, 3) ``[dx_m, dy_m, dpsi_rad]``."""
    out = np.empty((pulses.shape[0], 3))
    for i in range(pulses.shape[0]):
        distance = metres_per_pulse * 0.5 * (pulses[i, 0] + pulses[i, 1])
        dpsi = metres_per_pulse * (pulses[i, 1] - pulses[i, 0]) / axle_width_m
        # Chord length of the arc: D * sinc(theta/2); sinc -> 1 for straight motion.
        half = 0.5 * dpsi
        chord = distance * (math.sin(half) / half if half != 0.0 else 1.0)
        out[i, 0] = chord * math.cos(half)
        out[i, 1] = chord * math.sin(half)
        out[i, 2] = dpsi
    return out


class WheelEncoders:
    """Accumulates each robot's wheel rotation and samples pulse counts at the odometry rate.

    Parameters
    ----------
    config : OdometryConfig
    n_robots : int
    wheel_radius_m, axle_width_m : float
        From the robot config.
    """

    def __init__(
        self, config: OdometryConfig, n_robots: int, wheel_radius_m: float, axle_width_m: float
    ) -> None:
        self.config = config
        self.wheel_radius_m = wheel_radius_m
        self.axle_width_m = axle_width_m
        self._rad_per_pulse = 2.0 * np.pi / config.pulses_per_revolution
        half_axle = 0.5 * axle_width_m
        self._to_wheels = np.array([[1.0, 1.0], [-half_axle, half_axle]])
        self.wheel_angle_rad = np.zeros((n_robots, 2))  # continuous shaft angle [left, right]
        self._last_count = np.zeros((n_robots, 2), dtype=np.int64)
        self._last_stamp_s = 0.0

    def reset(self, time_s: float) -> None:
        self.wheel_angle_rad[:] = 0.0
        self._last_count[:] = 0
        self._last_stamp_s = time_s

    def advance(
        self, body_speeds: np.ndarray, dt_s: float, rng: np.random.Generator
    ) -> np.ndarray:
        """Turn the wheels for S consecutive substeps.

        Parameters
        ----------
        body_speeds : ndarray, shape (S, N, 2)
            The motor-driven ``[v_mps, omega_radps]`` (acceleration-limited command) of each
            substep.
        dt_s : float
            Substep length, seconds.
        rng : numpy.random.Generator
            Draws one slip factor per wheel and substep, substep by substep.

        Returns
        -------
        ndarray, shape (S, N, 2)
            Shaft angles ``[left, right]`` (rad) after each substep; pass one to :meth:`sample`.
        """
        # [v_L, v_R] = [v - omega w/2, v + omega w/2], as one (..., 2) @ (2, 2) product.
        wheel_mps = body_speeds @ self._to_wheels
        slip = 1.0 + self.config.slip_noise_std * rng.standard_normal(wheel_mps.shape)
        angles = self.wheel_angle_rad + np.cumsum(
            wheel_mps * (dt_s / self.wheel_radius_m) * slip, 0
        )
        self.wheel_angle_rad = angles[-1].copy()
        return angles

    def sample(
        self, time_s: float, wheel_angle_rad: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Read the encoders: pulses since the last sample -> (delta (N,3), velocity (N,2)).

        ``wheel_angle_rad`` (N, 2): the shaft angles at ``time_s`` (one row block of what
        :meth:`advance` returned for several substeps); default the current ones.
        """
        angle = self.wheel_angle_rad if wheel_angle_rad is None else wheel_angle_rad
        count = np.floor(angle / self._rad_per_pulse).astype(np.int64)
        pulses = count - self._last_count
        self._last_count = count
        delta = pulses_to_delta(
            pulses, self.wheel_radius_m, self.axle_width_m, self.config.pulses_per_revolution
        )
        dt = max(time_s - self._last_stamp_s, 1e-9)
        self._last_stamp_s = time_s
        velocity = np.empty((pulses.shape[0], 2))
        velocity[:, 0] = self.wheel_radius_m * self._rad_per_pulse * 0.5 * pulses.sum(axis=1)
        velocity[:, 0] /= dt
        velocity[:, 1] = delta[:, 2] / dt
        return delta, velocity
