"""The per-robot GM-PHD filter: :class:`RobotCentricPHD`.

The orchestrator only validates inputs, calls the pure functions of :mod:`localization.phd`,
:mod:`localization.detection` and :mod:`localization.reducer`, and swaps in the new component
table. Every public method validates all of its inputs before touching any state, so a call
that raises leaves the filter exactly as it was.

Each step reads like Stone Soup's tracker loop::

    predict:       P_s -> frame change + Q (+ pending measurement births)
    update_lidar:  (+ fixed birth) -> P_d (range x blind x occlusion x interference)
                   -> GM-PHD update (birth keeps detected copies only) -> reduce
    update_camera: P_d (range x occlusion) -> EKF bearing GM-PHD update
                   (+ ray births from unexplained bearings) -> reduce
    missed copies: (1 - P_d) w, or the exact Bernoulli weight (missed_detection)
    estimate:      components with weight >= threshold

References
----------
.. [1] B.-N. Vo and W.-K. Ma, "The Gaussian Mixture Probability Hypothesis Density Filter",
   IEEE Trans. Signal Processing, 54(11):4091-4104, 2006.
.. [2] Perera 2021, chapter 3.
.. [3] B. Ristic, D. Clark, B.-N. Vo, B.-T. Vo, "Adaptive target birth intensity for PHD and
   CPHD filters", IEEE Trans. Aerospace and Electronic Systems, 48(2), 2012 (measurement births).
.. [4] B. Ristic, B.-T. Vo, B.-N. Vo, A. Farina, "A tutorial on Bernoulli filters: theory,
   implementation and applications", IEEE Trans. Signal Processing, 61(13), 2013 (the
   Bernoulli missed-detection weight).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from swarm_core.validation import as_float_array

from . import object_clutter, phd
from .config import PHDConfig, config_with_overrides
from .detection import DetectionModel
from .frames import bearings_to_filter_frame, points_to_filter_frame
from .mixture import N_ROWS, ROW_PXX, ROW_W, ROW_X, ROW_Y, GaussianMixture, empty_table
from .reducer import reduce
from .scan_memory import (
    MEMORY_LEN,
    N_BINS,
    WIDE_OBJECTS_AT,
    move_scan_pose,
    scan_memory_from_state,
)

__all__ = ["RobotCentricFilter", "RobotCentricPHD", "estimate_table"]


class RobotCentricFilter:
    """What the robot-centric reference filters share (:class:`RobotCentricPHD`, the PMB's
    ``RobotCentricPMB``): their state is a few ``(6, N)`` tables (:attr:`TABLES`, the first
    the one shown as :attr:`mixture` / :attr:`table`), pending measurement births, a
    process-noise clock and a scan memory; tables are never written in place (each call builds
    new ones), so a shallow copy is an independent filter. Instances are picklable and
    deep-copyable."""

    __slots__ = ()
    #: The state's tables: ``name`` is the ``__getstate__`` key, ``"_" + name`` the attribute.
    TABLES: tuple[str, ...] = ("table",)

    @property
    def mixture(self) -> GaussianMixture:
        """The first table as a read-only :class:`GaussianMixture` (cached until the next call)."""
        if self._mixture is None:
            self._mixture = GaussianMixture.from_table(self._shown())
        return self._mixture

    @property
    def total_weight(self) -> float:
        """Sum of the first table's weights (the expected number of teammates it holds)."""
        return float(self._shown()[ROW_W].sum())

    def __len__(self) -> int:
        return int(self._shown().shape[1])

    def __getstate__(self) -> dict[str, Any]:
        state = {"config": self.config}
        state.update((name, getattr(self, "_" + name)) for name in self.TABLES)
        state.update(
            pending_births=self._pending_births,
            clock=self._clock.as_array(),
            scan_memory=self._scan,
        )
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__init__(state["config"])  # type: ignore[misc]
        for name in self.TABLES:
            setattr(self, "_" + name, np.array(state[name], dtype=float).reshape(N_ROWS, -1))
        self._pending_births = np.array(state["pending_births"], dtype=float).reshape(-1, 2)
        if "clock" in state:  # absent from states pickled before the clock existed
            self._clock = phd.ProcessClock.from_array(state["clock"])
        if "scan_memory" in state:  # absent from states pickled before the scan memory
            self._scan = scan_memory_from_state(state["scan_memory"])

    def __copy__(self) -> Any:
        new = object.__new__(type(self))
        for name in self.__slots__:
            setattr(new, name, getattr(self, name))
        return new

    def __deepcopy__(self, memo: dict[int, Any]) -> Any:
        new = self.__copy__()
        for name in self.__slots__:
            value = getattr(new, name)
            if isinstance(value, np.ndarray):
                setattr(new, name, value.copy())
        new._mixture = None
        return new

    def _shown(self) -> np.ndarray:
        return getattr(self, "_" + self.TABLES[0])

    def _predict_clock(self, cfg: PHDConfig) -> float:
        """The process-noise clock's time update: the variance ``q`` of its ``Q = q I``."""
        self._clock, q = self._clock.predict(
            cfg.prediction.process_noise_std_m**2,
            cfg.prediction.time_update == "measurement",
        )
        return q

    def _advance_clock(self, stamp_s: float, cfg: PHDConfig) -> float:
        """The clock moved to ``stamp_s`` (checked): the process-noise variance accrued."""
        stamp = _checked_stamp(stamp_s)
        self._clock, var = self._clock.advance(
            stamp,
            cfg.prediction.process_noise_std_m**2,
            cfg.prediction.process_noise_interval_s,
            cfg.prediction.time_update == "measurement",
        )
        return var

    def _predicted_with_births(
        self, table: np.ndarray, odo: np.ndarray, q: float, cfg: PHDConfig
    ) -> np.ndarray:
        """``table`` after the time update (:func:`phd.predict`, ``Q = q I``, weights times
        ``P_s``), with the pending measurement births joined (``P_s = 1``): adaptive births
        were measured in the previous frame, so they move with the frame and the next update
        confirms or drops them. Reduced past ``max_components``. The GM-PHD's time update,
        and the PMB's of its Poisson intensity."""
        survival = self._model.survival(table)
        if self._pending_births.shape[0]:
            births = phd.birth_components(
                self._pending_births,
                cfg.births.measurement_cov_scale * cfg.lidar.noise_var_m2,
                cfg.births.measurement_weight,
            )
            table = np.concatenate((table, births), axis=1)
            survival = np.concatenate((survival, np.ones(births.shape[1])))
        table = phd.predict(table, odo, survival, q)
        if table.shape[1] > cfg.reduction.max_components:
            table = reduce(
                table,
                cfg.reduction.prune_threshold,
                cfg.reduction.merge_threshold,
                cfg.reduction.max_components,
            )
        return table

    def _after_predict(self, odo: np.ndarray) -> None:
        """The scan memory's pose moves with the frame; the pending births are spent."""
        if self._scan[0]:  # the scan was taken from a place the frame has moved away from
            self._scan = self._scan.copy()
            self._scan[1:4] = move_scan_pose(self._scan[1:4], odo)
        self._pending_births = np.empty((0, 2))
        self._mixture = None


def lidar_inputs(
    points: Any, null_bearings: Any, sensor_pose: Any, scan_profile: Any
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None, np.ndarray | None]:
    """A lidar call's checked inputs (``ValueError`` naming the bad one): ``points (M, 2)``
    and ``null_bearings (B,)`` (or None) moved into the filter's frame from ``sensor_pose``
    (:mod:`localization.frames`), the pose ``(3,)`` and the scan profile (or None)."""
    pts = _checked_points(points)
    profile = None if scan_profile is None else checked_scan_profile(scan_profile)
    nulls = None if null_bearings is None else _checked_angles(null_bearings, "null_bearings")
    pose = checked_pose(sensor_pose)
    if pose is not None:
        pts = points_to_filter_frame(pts, pose)
        nulls = None if nulls is None else bearings_to_filter_frame(nulls, pose)
    return pts, nulls, pose, profile


def read_only(table: np.ndarray) -> np.ndarray:
    """A zero-copy read-only view of ``table`` (the filters never write into an array they
    have handed out: each call builds a new table)."""
    view = table.view()
    view.flags.writeable = False
    return view


class RobotCentricPHD(RobotCentricFilter):
    """Robot-centric GM-PHD filter for teammate positions in the observer's own frame.

    Parameters
    ----------
    config : PHDConfig, optional
        Filter configuration; the Perera 2021 study's defaults if omitted.
    **overrides
        Field values replacing those of ``config`` (``RobotCentricPHD(mode="lidar-only")``).
        Unknown names raise ``ValueError``.

    Notes
    -----
    The state is a Gaussian mixture over teammate positions ``[x_m, y_m]`` in the robot frame
    (x forward, y left). Calls are asynchronous: ``predict`` at the odometry rate,
    ``update_lidar`` / ``update_camera`` whenever a scan / frame arrives, in any order.
    Instances are picklable and deep-copyable.

    Examples
    --------
    >>> import numpy as np
    >>> f = RobotCentricPHD()
    >>> f.predict(np.array([0.02, 0.0, 0.01]))
    >>> f.update_lidar(np.array([[1.0, 0.5]]))
    >>> positions, weights = f.estimate()
    """

    __slots__ = (
        "config",
        "_model",
        "_table",
        "_pending_births",
        "_mixture",
        "_fixed_birth",
        "_clock",
        "_scan",
    )

    def __init__(self, config: PHDConfig | None = None, **overrides: Any) -> None:
        self.config = config = config_with_overrides(config, PHDConfig, overrides)
        self._model = DetectionModel(config)
        self._fixed_birth = phd.birth_components(
            np.asarray([config.births.mean_m], dtype=float),
            config.births.std_m**2,
            config.births.weight,
        )
        self._table = empty_table()
        self._pending_births = np.empty((0, 2))
        self._mixture: GaussianMixture | None = None
        self._clock = phd.ProcessClock()
        # The last lidar scan (localization.scan_memory): [has_scan, x, y, psi, profile,
        # wide objects (localization.object_clutter)].
        self._scan = np.zeros(MEMORY_LEN)

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Forget everything: back to the empty prior (no components, no pending births)."""
        self._table = empty_table()
        self._pending_births = np.empty((0, 2))
        self._mixture = None
        self._clock = phd.ProcessClock()
        self._scan = np.zeros(MEMORY_LEN)

    def set_mixture(self, mixture: GaussianMixture) -> None:
        """Replace the current PHD (e.g. to start from a known prior or replay a log).

        Parameters
        ----------
        mixture : GaussianMixture
            Weights must be finite and >= 0, means finite, covariances finite, symmetric and
            positive definite.

        Raises
        ------
        ValueError
            If the mixture violates the above (the filter is left unchanged).
        """
        if not isinstance(mixture, GaussianMixture):
            raise ValueError(f"mixture must be a GaussianMixture, got {type(mixture).__name__}")
        table = mixture.to_table()
        if not np.isfinite(table).all():
            raise ValueError("mixture must be finite")
        if table.shape[1] > self.config.reduction.max_components:
            raise ValueError(
                f"mixture has {table.shape[1]} components, more than max_components "
                f"{self.config.reduction.max_components}"
            )
        # The bound every measurement obeys, for the state too (the bank's kernels rely on it).
        check_magnitude(table[ROW_X : ROW_Y + 1], "mixture means")
        check_magnitude(np.sqrt(np.abs(table[ROW_PXX:])), "mixture covariances (as stds)")
        if (table[ROW_W] < 0).any():
            raise ValueError(f"mixture weights must be >= 0, got {mixture.weights.tolist()}")
        if not np.allclose(mixture.covs, mixture.covs.transpose(0, 2, 1), rtol=1e-9, atol=1e-12):
            raise ValueError("mixture covariances must be symmetric")
        pxx, pxy, pyy = table[ROW_PXX:]
        if ((pxx <= 0) | (pxx * pyy - pxy * pxy <= 0)).any():
            raise ValueError("mixture covariances must be positive definite")
        self._table = table
        self._pending_births = np.empty((0, 2))
        self._mixture = None

    @property
    def table(self) -> np.ndarray:
        """Current component table, shape ``(6, N)``, rows ``w, x, y, Pxx, Pxy, Pyy`` (a
        zero-copy read-only view, :func:`read_only`)."""
        return read_only(self._table)

    def __repr__(self) -> str:
        return (
            f"RobotCentricPHD(mode={self.config.mode!r}, components={len(self)}, "
            f"total_weight={self.total_weight:.3f})"
        )

    # ------------------------------------------------------------------ steps
    def predict(self, odometry: np.ndarray) -> None:
        """Time update with the observer's own motion (Perera 2021 eqs. 7-10).

        Parameters
        ----------
        odometry : array_like, shape (3,)
            ``[dx_m, dy_m, dpsi_rad]``: own motion over the interval, in the robot frame at
            the *start* of the interval.

        Raises
        ------
        ValueError
            If ``odometry`` is not 3 finite numbers.
        """
        odo = _checked_odometry(odometry)
        cfg = self.config
        process_var = self._predict_clock(cfg)
        self._table = self._predicted_with_births(self._table, odo, process_var, cfg)
        self._after_predict(odo)

    def advance(self, stamp_s: float) -> None:
        """Time update of the process noise alone, to ``stamp_s`` (s), before a measurement
        taken then (``PHDConfig.prediction.time_update == "measurement"``; else only the clock
        moves).
        Means and weights are unchanged: the ego-motion comes with the next :meth:`predict`.

        Raises
        ------
        ValueError
            If ``stamp_s`` is not a finite number.
        """
        var = self._advance_clock(stamp_s, self.config)
        if var > 0.0 and self._table.shape[1]:
            self._table = phd.diffuse(self._table, var)
            self._mixture = None

    def update_lidar(
        self,
        points: np.ndarray,
        null_bearings: np.ndarray | None = None,
        sensor_pose: np.ndarray | None = None,
        scan_profile: np.ndarray | None = None,
    ) -> None:
        """GM-PHD measurement update with lidar detections (Perera 2021 eqs. 12-23), then reduce.

        Parameters
        ----------
        points : array_like, shape (M, 2)
            Robot-like detections ``[x_m, y_m]`` in the robot frame; ``M = 0`` is a valid
            scan with no detection (the missed-detection factor ``1 - P_d`` still applies).
        null_bearings : array_like, shape (B,), optional
            Bearings (rad, robot frame) of zero-intensity returns, for the interference factor.
        sensor_pose : array_like, shape (3,), optional
            ``[x_m, y_m, psi_rad]``: where the robot scanned from, in the filter's frame (it
            moved since the last time update); points and null bearings are moved into the
            filter's frame first (:mod:`localization.frames`).
        scan_profile : array_like, shape (N_BINS,), optional
            The scan's :func:`~localization.scan_memory.scan_profile` (m, 0 = unknown).
            With ``config.reads_scans`` it becomes the filter's scan memory, with its wide
            objects (:mod:`localization.object_clutter`) where ``models_wide_objects``: later
            camera frames take their clutter from it. Without one the filter has no scan until
            the next.

        Raises
        ------
        ValueError
            If an argument has the wrong shape or non-finite values.
        """
        pts, nulls, pose, profile = lidar_inputs(points, null_bearings, sensor_pose, scan_profile)
        if self.config.reads_scans:  # the memory is kept only where it is used
            self._scan = scan_memory_of(profile, pose, self.config.models_wide_objects)
        cfg = self.config
        table = self._table
        bernoulli = cfg.missed_detection == "bernoulli"
        if pts.shape[0] == 0:
            pd = self._model.lidar(table, nulls)
            missed = self._lidar_missed(table, pd)
            out = (table if missed is None else missed[1]).copy()
            out[ROW_W] = self._missed_only(table, pd if missed is None else missed[0])
            explained = np.empty(0)
        else:
            n = table.shape[1]
            fixed_birth = cfg.births.model == "fixed"
            if fixed_birth:
                # Perera 2021's birth component (eq. 11) joins the prior of every lidar update.
                table = np.concatenate((table, self._fixed_birth), axis=1)
            pd = self._model.lidar(table, nulls)
            out, explained = phd.lidar_update(
                table,
                pts,
                pd,
                cfg.lidar.noise_var_m2,
                cfg.lidar.clutter_intensity,
                bernoulli,
                self._lidar_missed(table, pd),
            )
            if fixed_birth:
                # Its missed-detection copy is dropped (weight 0, pruned): kept, a 2 m-wide
                # component would be merged into the heaviest track at every reduction
                # (Vo & Ma's gate uses the candidate's covariance) and inflate its covariance.
                out[ROW_W, n] = 0.0
        if cfg.births.model == "measurement":
            self._pending_births = pts[explained < cfg.births.measurement_max_explained]
        self._table = self._reduce(out)
        self._mixture = None

    def update_camera(self, bearings: np.ndarray, sensor_pose: np.ndarray | None = None) -> None:
        """GM-PHD measurement update with camera bearings (Perera 2021 eqs. 24-30), then reduce.

        A no-op (after validation) when ``config.mode == "lidar-only"``.

        Parameters
        ----------
        bearings : array_like, shape (M,)
            Bearings of detected teammates (rad, robot frame); ``M = 0`` is a valid frame.
        sensor_pose : array_like, shape (3,), optional
            ``[x_m, y_m, psi_rad]``: where the camera was in the filter's frame, if the robot
            moved since the last time update. Bearings are rotated by ``psi``
            (:func:`localization.frames.bearings_to_filter_frame`), and the bearing model
            ``atan2(y - y_s, x - x_s)`` and the camera ``P_d`` are evaluated from ``(x_s,
            y_s)``: a bearing has no range to move it by, so its parallax belongs in the model.
            3 cm of sideways motion is about 3.6 sigma of the simulated camera's measured
            bearing noise, at any range (both scale as 1 / range).

        Raises
        ------
        ValueError
            If ``bearings`` has the wrong shape or non-finite values.
        """
        brg = _checked_angles(bearings, "bearings")
        pose = checked_pose(sensor_pose)
        cfg = self.config
        if cfg.mode == "lidar-only":
            return
        if pose is not None:
            brg = bearings_to_filter_frame(brg, pose)
        offset = None if pose is None else pose[:2]
        if offset is None or not offset.any():
            self._camera_update(brg, np.zeros(2))
            return
        # The update is translation-equivariant but for the sensor's own position: run it on
        # the mixture seen from the camera, and move the result back.
        self._table = _shifted(self._table, -offset)
        try:
            self._camera_update(brg, offset)
        finally:
            self._table = _shifted(self._table, offset)
            self._mixture = None

    def _camera_update(self, brg: np.ndarray, offset: np.ndarray) -> None:
        """The update of ``self._table``, whose frame is the filter's shifted by ``-offset``
        (the camera's view; the scan memory's pose is read alike)."""
        cfg = self.config
        table = self._table
        detection_prob = self._model.camera(table)
        if brg.shape[0] == 0:
            out = table.copy()
            out[ROW_W] = self._missed_only(table, detection_prob)
        else:
            out, explained = phd.camera_update(
                table,
                brg,
                detection_prob,
                cfg.camera_bearing_var(np.hypot(table[ROW_X], table[ROW_Y])),
                object_clutter.camera_clutter(cfg, brg, self._scan, offset),
                cfg.reduction.min_range_m,
                cfg.missed_detection == "bernoulli",
            )
            if cfg.births.camera == "ray":
                # Bearings the mixture does not explain start tracks along their rays; they
                # join this frame's posterior (the bearing is their own update).
                unexplained = brg[explained < cfg.births.camera_max_explained]
                if unexplained.shape[0]:
                    births = phd.camera_ray_births(cfg, unexplained)
                    out = np.concatenate((out, births), axis=1)
        self._table = self._reduce(out)
        self._mixture = None

    def estimate(self, threshold: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
        """Extract neighbour position estimates (:func:`estimate_table` of the current table)."""
        return estimate_table(self._table, threshold)

    def _lidar_missed(self, table: np.ndarray, pd: np.ndarray):
        """The lidar missed copies' ``P_d`` and shape (``lidar_missed_moments``), or None."""
        cfg = self.config
        if not cfg.lidar.missed_moments or cfg.lidar.pd_model != "seed":
            return None
        return phd.missed_moments(
            table,
            pd,
            cfg.lidar.pd_offset,
            cfg.lidar.pd_slope_per_m,
            cfg.lidar.pd_midpoint_m,
            cfg.reduction.min_range_m,
        )

    def _missed_only(self, table: np.ndarray, detection_prob: np.ndarray) -> np.ndarray:
        """Weights after a scan or frame without measurements, shape ``(N,)``."""
        if self.config.missed_detection == "bernoulli":
            return phd.missed_weights(table[ROW_W], detection_prob)
        return table[ROW_W] * (1.0 - detection_prob)

    def _reduce(self, table: np.ndarray) -> np.ndarray:
        cfg = self.config
        return reduce(
            table,
            cfg.reduction.prune_threshold,
            cfg.reduction.merge_threshold,
            cfg.reduction.max_components,
        )


# ---------------------------------------------------------------------- input checks
#: Largest magnitude of any measurement or odometry input (m or rad). Beyond it a value is a
#: fault (a relative position of a kilometre is already none), and squares of it would overflow
#: the filters' covariances; the compiled banks and the references refuse the same values.
MAX_INPUT_MAGNITUDE = 1e4

#: Cost guard: the most detections (or bearings) one scan (or frame) may hand a filter. The
#: update is O(components x measurements), and 20,000 detections took the reference over
#: 100 s; a real scan holds a few tens (a 720-beam lidar yields at most ~240 clusters).
MAX_MEASUREMENTS_PER_CALL = 4096


def estimate_table(table: np.ndarray, threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """Extract neighbour position estimates from a ``(6, N)`` GM-PHD table (Vo & Ma 2006,
    Table III).

    Every component with ``w >= threshold`` is reported ``max(1, floor(w + 0.5))`` times
    (a component holding the mass of two close teammates counts as two), each copy
    carrying weight ``w / count``. Rows are sorted by decreasing weight.

    Parameters
    ----------
    table : ndarray, shape (6, N)
        Rows ``w, x, y, Pxx, Pxy, Pyy``.
    threshold : float
        Extraction threshold on component weights.

    Returns
    -------
    positions : ndarray, shape (K, 2)
        Estimated teammate positions ``[x_m, y_m]`` in the robot frame.
    weights : ndarray, shape (K,)

    Raises
    ------
    ValueError
        If ``threshold`` is not finite.
    """
    w = table[ROW_W]
    keep = ranked_above(w, threshold)
    wk = w[keep]
    counts = np.maximum(np.floor(wk + 0.5), 1.0).astype(np.intp)
    positions = np.repeat(table[ROW_X : ROW_Y + 1, keep].T, counts, axis=0)
    return positions, np.repeat(wk / counts, counts)


def ranked_above(weights: np.ndarray, threshold: float) -> np.ndarray:
    """Indices of the ``weights`` at or above ``threshold``, heaviest first (ties: lower index).

    Raises
    ------
    ValueError
        If ``threshold`` is not finite.
    """
    threshold = float(threshold)
    if not math.isfinite(threshold):
        raise ValueError(f"threshold must be finite, got {threshold!r}")
    keep = np.flatnonzero(weights >= threshold)
    return keep[np.argsort(-weights[keep], kind="stable")]


def check_magnitude(values: np.ndarray, name: str) -> None:
    """``ValueError`` naming ``name`` and the value unless every entry is finite and within
    :data:`MAX_INPUT_MAGNITUDE`."""
    if values.size == 0 or np.abs(values).max() <= MAX_INPUT_MAGNITUDE:  # NaN compares False
        return
    rule = f"{name} must be finite and within +-{MAX_INPUT_MAGNITUDE:g} (m or rad), got"
    if values.ndim == 1 and values.size <= 8:  # a pose or an odometry increment: show it all
        raise ValueError(f"{rule} {values.tolist()}")
    flat = values.reshape(values.shape[0], -1) if values.ndim > 1 else values[:, None]
    bad = int(np.flatnonzero(~(np.abs(flat) <= MAX_INPUT_MAGNITUDE).all(axis=1))[0])
    shown = values[bad].tolist() if values.ndim > 1 else repr(values[bad])
    raise ValueError(f"{rule} {name}[{bad}] = {shown}")


def checked_scan_profile(value: Any) -> np.ndarray:
    """A scan profile (:mod:`localization.scan_memory`): ``(N_BINS,)`` finite ranges >= 0 m
    (0 = unknown), within the input bound."""
    profile = as_float_array(value, "scan_profile")
    if profile.shape != (N_BINS,):
        raise ValueError(
            f"scan_profile must have shape ({N_BINS},) (localization.scan_memory), got shape "
            f"{profile.shape}"
        )
    check_magnitude(profile, "scan_profile")
    if (profile < 0.0).any():
        bad = float(profile[profile < 0.0][0])
        raise ValueError(f"scan_profile ranges must be >= 0 m (0 = unknown), got {bad!r}")
    return profile


def scan_memory_of(
    profile: np.ndarray | None, pose: np.ndarray | None, with_wide_objects: bool
) -> np.ndarray:
    """A filter's scan memory ``(MEMORY_LEN,)`` (:mod:`localization.scan_memory`) after a
    lidar call: ``[1, x, y, psi]`` of the pose the scan was taken from (the filter's origin
    without one), its ``profile (N_BINS,)`` and, ``with_wide_objects``, the profile's wide
    objects (:func:`localization.object_clutter.wide_objects`). A call without a profile
    leaves no scan (all zeros): an older one would be judged from the wrong place and time."""
    memory = np.zeros(MEMORY_LEN)
    if profile is None:
        return memory
    memory[0] = 1.0
    memory[1:4] = 0.0 if pose is None else pose
    memory[4:WIDE_OBJECTS_AT] = profile
    if with_wide_objects:
        objects = object_clutter.wide_objects(profile)
        memory[WIDE_OBJECTS_AT] = objects.shape[0]
        memory[WIDE_OBJECTS_AT + 1 : WIDE_OBJECTS_AT + 1 + objects.size] = objects.ravel()
    return memory


def checked_pose(value: Any) -> np.ndarray | None:
    """Optional sensor pose ``[x_m, y_m, psi_rad]``: finite, within the input bound."""
    if value is None:
        return None
    return _checked_triple(value, "sensor_pose", "[x_m, y_m, psi_rad]")


def _shifted(table: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """``table`` (6, N) with every mean moved by ``offset`` (2,) (a new array)."""
    out = table.copy()
    out[ROW_X] += offset[0]
    out[ROW_Y] += offset[1]
    return out


def _checked_stamp(value: Any) -> float:
    """A stamp: one finite real number of seconds (any clock: sim time or ROS time)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(
        value, (int, float, np.integer, np.floating)
    ):
        raise ValueError(f"stamp_s must be a real number of seconds, got {value!r}")
    if not math.isfinite(float(value)):
        raise ValueError(f"stamp_s must be finite, got {value!r}")
    return float(value)


def _checked_odometry(odometry: Any) -> np.ndarray:
    return _checked_triple(odometry, "odometry", "[dx_m, dy_m, dpsi_rad]")


def _checked_triple(value: Any, name: str, layout: str) -> np.ndarray:
    """``value`` as a finite float array of shape (3,) within the input bound; the
    ``ValueError`` names ``name`` and the expected ``layout``."""
    arr = as_float_array(value, name)
    if arr.shape != (3,):
        raise ValueError(f"{name} must have shape (3,) {layout}, got shape {arr.shape}")
    check_magnitude(arr, name)
    return arr


def _checked_points(points: Any) -> np.ndarray:
    pts = as_float_array(points, "points")
    if pts.ndim != 2 or pts.shape[1] != 2:
        if pts.size == 0:
            return np.empty((0, 2))
        raise ValueError(f"points must have shape (M, 2), got shape {pts.shape}")
    _check_count(pts.shape[0], "points")
    check_magnitude(pts, "points")
    return pts


def _check_count(n: int, name: str) -> None:
    if n > MAX_MEASUREMENTS_PER_CALL:
        raise ValueError(
            f"{name} holds {n} measurements, more than MAX_MEASUREMENTS_PER_CALL "
            f"({MAX_MEASUREMENTS_PER_CALL}) in one call"
        )


def _checked_angles(angles: Any, name: str) -> np.ndarray:
    arr = as_float_array(angles, name)
    if arr.ndim != 1:
        if arr.size == 0:
            return np.empty(0)
        raise ValueError(f"{name} must have shape (M,), got shape {arr.shape}")
    _check_count(arr.shape[0], name)
    check_magnitude(arr, name)
    return arr
