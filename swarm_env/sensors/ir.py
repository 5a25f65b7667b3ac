"""The IR-UKF study's IR range-bearing sensor with identities, simulated from true poses.

The IR-UKF study (Sec. II): each robot carries an IR LED pulsed at its own frequency (the identity,
recovered from the FFT bin) and two phototransistors swept by a servo; one sweep gives, for every
neighbour in view, its identity, bearing (the sweep angle of the peak) and range (from the peak
height through a calibrated power law). Figures taken from the study:

- one sweep per second ("the update rate is approximately 1 Hz");
- neighbours seen up to 1 m ("range and bearing estimates of robots that are 1 m away or closer");
- range noise, measured with two robots 61 cm apart while one rotated in place: sigma 7.2 cm
  without the outliers (readings > 90 cm), 18.6 cm with them (Fig. 5). The outliers come from
  blind spots of the standoffs holding the LED board: a partly hidden LED gives a weaker peak,
  read as a *longer* range. Modelled as a two-part mixture: Gaussian core ``range_std_m`` =
  0.072 m, plus with probability ``outlier_probability`` a positive offset uniform in
  ``outlier_offset_m``. With the defaults (0.08, [0.3, 0.9] m) the mixture's standard deviation is
  0.186 m at any range and every outlier at 0.61 m reads > 0.9 m, as in the study;
- bearing noise "a few degrees" (the IR-UKF study's exact figure is lost from the text we have; its
  reasoning: ~1 s sweep delay times the robots' turn rate). Default 5 deg.

Per-robot calibration error (IR-UKF study, Sec. IV: "accumulated systematic calibration error"
from the per-sensor power-law fits): each observer's ranges are scaled by ``1 + e_i``,
``e_i ~ N(0, range_scale_std)`` drawn at reset. Default 0 (the study gives no figure); the docs
report the effect of a few per cent.

Motion during the sweep (``sweep_motion=True``): the servo takes a whole period to sweep the
circle, so each neighbour is seen at the instant the sweep passes its bearing (from -pi at the
sweep's start to +pi at its end), while the sweep is reported at its end. The seed puts this
delay (0.5 s on average) times the robots' turn rate at the root of its bearing error. With it on,
``step`` reads each pair from the poses it was given at that instant (the latest at or before
it), so the consumer sees the delay. Default off: ``bearing_std_deg`` is the IR-UKF study's *total*
bearing sigma, delay included.

Readings that fall in a blind spot entirely (no peak) are dropped with probability
``dropout_probability``. Each robot sweeps with its own phase (unsynchronised hardware).

Readings are in the observer's body frame, REP-103: ``bearing = atan2(y, x)`` of the target in
the observer's frame, counter-clockwise positive, range in metres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from swarm_core.geometry import wrap_angle
from swarm_core.validation import check_number

__all__ = ["IRConfig", "IRReadings", "IRSensor"]


@dataclass(frozen=True, slots=True)
class IRConfig:
    """The IR sensor of the IR-UKF study (units in the names), validated on construction."""

    rate_hz: float = 1.0
    max_range_m: float = 1.0
    min_range_m: float = 0.0
    range_std_m: float = 0.072
    outlier_probability: float = 0.08
    outlier_offset_m: tuple[float, float] = (0.3, 0.9)
    bearing_std_deg: float = 5.0
    dropout_probability: float = 0.05
    range_scale_std: float = 0.0
    sweep_motion: bool = False

    def __post_init__(self) -> None:
        check_number("ir.rate_hz", self.rate_hz, low=0, above=True, high=100)
        check_number("ir.max_range_m", self.max_range_m, low=0, above=True, high=20)
        check_number("ir.min_range_m", self.min_range_m, low=0, high=self.max_range_m)
        check_number("ir.range_std_m", self.range_std_m, low=0, high=5)
        check_number("ir.outlier_probability", self.outlier_probability, low=0, high=1)
        check_number("ir.bearing_std_deg", self.bearing_std_deg, low=0, high=180)
        check_number("ir.dropout_probability", self.dropout_probability, low=0, high=1)
        check_number("ir.range_scale_std", self.range_scale_std, low=0, high=0.5)
        if not isinstance(self.sweep_motion, bool):
            raise ValueError(f"ir.sweep_motion must be True or False, got {self.sweep_motion!r}")
        off = self.outlier_offset_m
        if (
            not isinstance(off, tuple)
            or len(off) != 2
            or not all(isinstance(v, (int, float)) and math.isfinite(v) for v in off)
            or not 0.0 <= off[0] <= off[1]
        ):
            raise ValueError(
                f"ir.outlier_offset_m must be (low, high) with 0 <= low <= high, got {off!r}"
            )

    @property
    def period_s(self) -> float:
        return 1.0 / self.rate_hz

    @property
    def bearing_std_rad(self) -> float:
        return math.radians(self.bearing_std_deg)

    @property
    def effective_range_std_m(self) -> float:
        """Standard deviation of the whole range-error mixture (core + outliers), m: the value
        the study put in its filter ("the actual skewed value")."""
        p, (a, b) = self.outlier_probability, self.outlier_offset_m
        m, v = 0.5 * (a + b), (b - a) ** 2 / 12.0
        return math.sqrt(self.range_std_m**2 + p * v + p * (1.0 - p) * m * m)


@dataclass(frozen=True, slots=True)
class IRReadings:
    """One batch of identified readings, all arrays shape (K,).

    ``observer``/``target`` robot indices, ``range_m``, ``bearing_rad`` (observer body frame),
    ``stamp_s`` the sweep's end time.
    """

    observer: np.ndarray
    target: np.ndarray
    range_m: np.ndarray
    bearing_rad: np.ndarray
    stamp_s: np.ndarray

    def __len__(self) -> int:
        return int(self.observer.shape[0])

    @staticmethod
    def concatenate(items: list[IRReadings]) -> IRReadings:
        if not items:
            return _empty()
        return IRReadings(
            *(np.concatenate([getattr(r, f) for r in items]) for f in IRReadings.__slots__)
        )


def _empty() -> IRReadings:
    z = np.zeros(0)
    return IRReadings(z.astype(np.int64), z.astype(np.int64), z, z, z)


class IRSensor:
    """Every robot's IR sweep: ``reset(rng, n)``, then ``step(time_s, poses)`` each control
    period returns the readings of the sweeps that completed since the last call.

    One seeded ``numpy.random.Generator`` (the env's or the caller's) drives the phases, noise
    and dropouts: same seed, same readings.
    """

    def __init__(self, config: IRConfig | None = None) -> None:
        self.config = config or IRConfig()
        self._rng: np.random.Generator | None = None
        self._next_s = np.zeros(0)
        self._scale = np.ones(0)
        self._hist_t: list[float] = []
        self._hist_p: list[np.ndarray] = []

    def reset(self, rng: np.random.Generator, n_robots: int, time_s: float = 0.0) -> None:
        if (
            isinstance(n_robots, bool)
            or not isinstance(n_robots, (int, np.integer))
            or n_robots < 1
        ):
            raise ValueError(f"n_robots must be an integer >= 1, got {n_robots!r}")
        self._rng = rng
        # Unsynchronised sweeps: each robot's first one completes within the first period.
        self._next_s = time_s + rng.uniform(0.0, self.config.period_s, int(n_robots))
        self._scale = 1.0 + rng.normal(0.0, self.config.range_scale_std, int(n_robots))
        self._hist_t, self._hist_p = [], []

    def step(self, time_s: float, poses: np.ndarray) -> IRReadings:
        """Readings of every sweep due at or before ``time_s``, taken at the poses ``(N, 3)``
        given (the caller steps often enough that the poses of the sweep instant are these)."""
        if self._rng is None:
            raise RuntimeError("IRSensor.step() called before reset()")
        poses = np.asarray(poses, dtype=np.float64)
        if poses.shape != (self._next_s.shape[0], 3) or not np.isfinite(poses).all():
            raise ValueError(
                f"poses must be finite of shape ({self._next_s.shape[0]}, 3), got {poses.shape}"
            )
        period = self.config.period_s
        if self.config.sweep_motion:  # the poses of the last period, for the sweep instants
            self._hist_t.append(float(time_s))
            self._hist_p.append(poses.copy())
            while len(self._hist_t) > 1 and self._hist_t[1] <= time_s - period - 1e-9:
                del self._hist_t[0], self._hist_p[0]
        due = np.flatnonzero(self._next_s <= time_s + 1e-9)
        if not due.shape[0]:
            return _empty()
        stamps = self._next_s[due].copy()
        self._next_s[due] += period
        if not self.config.sweep_motion:
            return self.measure(poses, due, stamps)
        n = poses.shape[0]
        obs_idx, tgt_idx = np.repeat(due, n), np.tile(np.arange(n), due.shape[0])
        # Each pair's sweep instant from its bearing at the sweep's end (-pi: start, +pi: end).
        d = poses[tgt_idx, :2] - poses[obs_idx, :2]
        c, s = np.cos(poses[obs_idx, 2]), np.sin(poses[obs_idx, 2])
        b = np.arctan2(-s * d[:, 0] + c * d[:, 1], c * d[:, 0] + s * d[:, 1])
        t_pair = np.repeat(stamps, n) - period * (np.pi - b) / (2 * np.pi)
        hist_t = np.asarray(self._hist_t)
        row = np.clip(np.searchsorted(hist_t, t_pair + 1e-9, side="right") - 1, 0, None)
        hist_p = np.stack(self._hist_p)  # (H, N, 3)
        return self._readings(
            hist_p[row, obs_idx], hist_p[row, tgt_idx], obs_idx, tgt_idx, np.repeat(stamps, n)
        )

    def measure(
        self, poses: np.ndarray, observers: np.ndarray, stamps: np.ndarray | None = None
    ) -> IRReadings:
        """One sweep by each of ``observers`` (M,) at the true ``poses`` (N, 3); vectorised over
        all (observer, target) pairs."""
        observers = np.asarray(observers, dtype=np.int64)
        n = poses.shape[0]
        obs_idx = np.repeat(observers, n)
        tgt_idx = np.tile(np.arange(n), observers.shape[0])
        if stamps is None:
            stamps = np.zeros(observers.shape[0])
        stamp = np.repeat(np.asarray(stamps, dtype=np.float64), n)
        return self._readings(poses[obs_idx], poses[tgt_idx], obs_idx, tgt_idx, stamp)

    def _readings(
        self,
        obs_pose: np.ndarray,
        tgt_pose: np.ndarray,
        obs_idx: np.ndarray,
        tgt_idx: np.ndarray,
        stamp: np.ndarray,
    ) -> IRReadings:
        """Readings of K (observer, target) pairs from their poses (K, 3) each."""
        cfg = self.config
        rng = self._rng if self._rng is not None else np.random.default_rng(0)
        d = tgt_pose[:, :2] - obs_pose[:, :2]
        c, s = np.cos(obs_pose[:, 2]), np.sin(obs_pose[:, 2])
        x, y = c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]
        true_r = np.hypot(x, y)
        k = obs_idx.shape[0]
        # Draw every random number for every pair (fixed count per sweep): the stream does not
        # depend on who is in range, so a change of geometry does not reshuffle later noise.
        keep_draw = rng.random(k) >= cfg.dropout_probability
        outlier = rng.random(k) < cfg.outlier_probability
        offset = rng.uniform(cfg.outlier_offset_m[0], cfg.outlier_offset_m[1], k)
        r_noise = rng.normal(0.0, cfg.range_std_m, k)
        b_noise = rng.normal(0.0, cfg.bearing_std_rad, k)
        keep = (
            (obs_idx != tgt_idx)
            & (true_r <= cfg.max_range_m)
            & (true_r >= cfg.min_range_m)
            & keep_draw
        )
        scale = self._scale[obs_idx] if self._scale.shape[0] > obs_idx.max(initial=0) else 1.0
        rng_m = np.maximum(scale * true_r + r_noise + np.where(outlier, offset, 0.0), 0.0)
        brg = wrap_angle(np.arctan2(y, x) + b_noise)
        return IRReadings(obs_idx[keep], tgt_idx[keep], rng_m[keep], brg[keep], stamp[keep])
