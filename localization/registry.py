"""Every localizer family by name: one registry for the env, ``swarm-phd evaluate``, the bridge
and the replay.

>>> from localization.registry import make_localizer, LOCALIZERS
>>> loc = make_localizer("phd-lc", n_robots=20)      # the compiled GM-PHD bank, LC mode
>>> sorted(LOCALIZERS)[:3]
['id-phd', 'pf', 'phd']

Every entry builds a :class:`~localization.protocol.Localizer` from ``(n_robots, phd, seed)``:
``phd`` is the :class:`~localization.PHDConfig` holding the sensor models of the World the
localizer runs on (``PHDConfig()``, the simulator presets' model, or the Perera 2021 study's
``PHDConfig.perera2021()`` for real robots); the ``-lc`` / ``-lo`` names set its ``mode``, the
bare family names (``phd``, ``phd-reference``) keep it. :func:`register` adds a family (see
``docs/how-to/add-a-localizer-family.md``).

Each family's bound on total weight and cardinality is in its class docstring and in
``docs/concepts/localizers.md`` ("Bounds on weight and cardinality"), checked after every filter
call by
``tests/localization/test_localizer_bounds.py``.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from swarm_core.records import LidarRecord, OdometryRecord

from .bank import FilterBank, PHDBank
from .config import PHDConfig
from .feed import SwarmFeed
from .filter import (
    RobotCentricPHD,
    _checked_angles,
    _checked_odometry,
    _checked_points,
    _checked_stamp,
    check_magnitude,
    estimate_table,
)
from .id_phd import IDPHD, IDPHDConfig
from .mixture import GaussianMixture
from .pmb.bank import PMBBank
from .protocol import Localizer, LocalizerBase, tables_from_mixtures

__all__ = [
    "LOCALIZERS",
    "LocalizerSpec",
    "register",
    "make_localizer",
    "descriptions",
    "bank_family",
    "ReferenceLocalizer",
    "IdentityLocalizer",
    "run_calls",
]

Builder = Callable[[int, PHDConfig, int], Localizer]


@dataclass(frozen=True)
class LocalizerSpec:
    """A registry entry: ``build(n_robots, phd, seed)`` returns the localizer;
    ``needs_comms``: it reads ``SwarmFeed.comms`` (``swarm-phd evaluate`` switches the radio
    on, and refuses a config with the radio off)."""

    name: str
    description: str
    build: Builder
    needs_comms: bool = False


#: name -> :class:`LocalizerSpec`, in registration order.
LOCALIZERS: dict[str, LocalizerSpec] = {}


def register(name: str, description: str, build: Builder, needs_comms: bool = False) -> None:
    """Add (or replace) the family ``name``."""
    if not isinstance(name, str) or not name:
        raise ValueError(f"localizer name must be a non-empty str, got {name!r}")
    LOCALIZERS[name] = LocalizerSpec(name, description, build, bool(needs_comms))


def descriptions() -> dict[str, str]:
    """``{name: one-line description}`` of every registered localizer."""
    return {name: spec.description for name, spec in LOCALIZERS.items()}


def make_localizer(
    name: str, n_robots: int, phd: PHDConfig | None = None, seed: int = 0
) -> Localizer:
    """Build the localizer ``name`` for ``n_robots`` robots.

    Raises ``ValueError`` naming the value for an unknown name, a bad robot count or config.
    """
    spec = LOCALIZERS.get(name)
    if spec is None:
        raise ValueError(f"localizer must be one of {sorted(LOCALIZERS)}, got {name!r}")
    if isinstance(n_robots, bool) or not isinstance(n_robots, (int, np.integer)) or n_robots < 1:
        raise ValueError(f"n_robots must be an int >= 1, got {n_robots!r}")
    phd = PHDConfig() if phd is None else phd
    if not isinstance(phd, PHDConfig):
        raise ValueError(f"phd must be a PHDConfig, got {type(phd).__name__}")
    localizer = spec.build(int(n_robots), phd, int(seed))
    localizer.name = name
    return localizer


# ---------------------------------------------------------------------- compiled banks
def bank_family(bank_class: type[FilterBank], mode: str | None = None) -> Builder:
    """The builder of a compiled bank family: ``bank_class(phd, n_robots)`` (the family's
    :meth:`~localization.bank.FilterBank.checked_config` turns the World's ``PHDConfig`` into
    its own config), with ``phd.mode`` set to ``mode`` unless it is None. A compiled bank is
    itself the :class:`~localization.protocol.Localizer`: its class docstring states its
    bounds on weight and cardinality. The ``pmb-lo`` entry, for one, is
    ``register("pmb-lo", "...", bank_family(PMBBank, "lidar-only"))``.
    """
    if not (isinstance(bank_class, type) and issubclass(bank_class, FilterBank)):
        raise ValueError(f"bank_class must be a FilterBank subclass, got {bank_class!r}")
    set_mode = _with_mode(mode)

    def build(n: int, phd: PHDConfig, seed: int) -> Localizer:
        return bank_class(set_mode(phd), n)

    return build


def _check_records(robot: int, records: Any, stale: tuple[str, ...]) -> None:
    """The anonymous banks' input checks (finite, within ``MAX_INPUT_MAGNITUDE``, finite
    stamps) on one robot's records, for the families that read records directly."""
    try:
        if "odometry" not in stale:
            for rec in records.odometry:
                _checked_stamp(rec.stamp_s)
                _checked_odometry(rec.delta)
                check_magnitude(np.asarray(rec.velocity, dtype=float), "odometry velocity")
        if "lidar" not in stale:
            for rec in records.lidar:
                _checked_stamp(rec.stamp_s)
                _checked_points(rec.detections)
                _checked_angles(rec.null_bearings_rad, "null_bearings")
    except ValueError as exc:
        raise ValueError(f"robot {robot}: {exc}") from None


def run_calls(f: Any, calls: list[tuple]) -> None:
    """Run one robot's calls (:func:`localization.feed.localizer_calls`) on a single filter
    with the ``RobotCentricPHD`` / ``RobotCentricPMB`` methods (which move posed measurements
    with :mod:`localization.frames`, as the compiled banks do inside their kernels)."""
    for call in calls:
        kind = call[0]
        if kind == "predict":
            f.predict(call[1])
        elif kind == "lidar":
            f.update_lidar(
                call[1],
                call[2],
                sensor_pose=call[3] if len(call) > 3 else None,
                scan_profile=call[4] if len(call) > 4 else None,
            )
        elif kind == "camera":
            f.update_camera(call[1], sensor_pose=call[2] if len(call) > 2 else None)
        elif kind == "advance":
            f.advance(call[1])
        else:
            raise ValueError(f"unknown filter call kind {kind!r}")


class ReferenceLocalizer(LocalizerBase):
    """One pure-numpy single filter per robot (``filter_class``: the GM-PHD's
    :class:`~localization.RobotCentricPHD` or the PMB's ``RobotCentricPMB``): the readable
    reference of a compiled bank, same math, tens of times slower. Same bounds on weight and
    cardinality as its compiled bank (:class:`~localization.PHDBank`,
    :class:`~localization.pmb.PMBBank`)."""

    def __init__(self, config: PHDConfig, n_robots: int, filter_class: type = RobotCentricPHD):
        self.config = config
        self.n_robots = n_robots
        self.filters = [filter_class(config) for _ in range(n_robots)]
        if filter_class is not RobotCentricPHD:
            self.weight_meaning = "existence"

    def reset(self, robots: Sequence[int] | None = None) -> None:
        for r in self._robots(robots):
            self.filters[r].reset()

    def step(self, feed: SwarmFeed) -> None:
        self._check_feed(feed)
        # Every robot's calls run on copies, kept only if all succeed: a bad record for robot k
        # must not leave robots 0..k-1 (or robot k's earlier calls) advanced.
        trial = [copy.deepcopy(f) for f in self.filters]
        for f, calls in zip(trial, feed.calls(), strict=True):
            run_calls(f, calls)
        self.filters = trial

    def padded_tables(self) -> tuple[np.ndarray, np.ndarray]:
        return tables_from_mixtures([f.mixture for f in self.filters])

    def mixture(self, robot: int) -> GaussianMixture:
        return self.filters[self._robot(robot)].mixture

    def estimate(self, robot: int, threshold: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
        return self.filters[self._robot(robot)].estimate(threshold)


# ---------------------------------------------------------------------- identity families
#: A lidar detection within this distance of a true robot is attributed to it (oracle IDs).
ORACLE_GATE_M = 0.2


class IdentityLocalizer(LocalizerBase):
    """One identity-aware filter per robot (``id-phd``, ``ukf`` or ``pf``).

    Robot ``r``'s odometry records drive ``predict(own, {j: teammate j's record})``: each
    robot's odometry records of the step stand for its radio messages (the simulated robots
    sample odometry in lockstep, so the k-th records of a step share a stamp); a robot whose
    odometry is stale sends no message. Lidar records go to ``update_lidar`` (ID-PHD,
    anonymous) or, for ``ukf`` / ``pf``, to ``update({j: (range, bearing)})`` with the identity
    of the true robot within :data:`ORACLE_GATE_M` of each detection (an oracle standing in for
    the IR-UKF / Lee 2012 studies' identifying sensors; needs ``feed.truth``). Camera records are
    not used.

    Bounds (``docs/concepts/localizers.md``, "Bounds on weight and cardinality"): ``id-phd`` as
    :class:`~localization.id_phd.IDPHD` documents (its table holds the teammate-tagged part of
    that mass); ``ukf`` / ``pf``: one unit-weight component per identified teammate, so
    weight = count ``<= n_robots - 1``.
    """

    has_identities = True

    def __init__(self, filters: list[Any], oracle_identities: bool) -> None:
        self.filters = filters
        self.n_robots = len(filters)
        self.oracle_identities = oracle_identities

    def reset(self, robots: Sequence[int] | None = None) -> None:
        for r in self._robots(robots):
            self.filters[r].reset()

    def step(self, feed: SwarmFeed) -> None:
        self._check_feed(feed)
        if self.oracle_identities and feed.truth is None:
            raise ValueError(f"{self.name} needs ground truth for its oracle identities")
        records, stale = feed.measurements, feed.stale
        for r in range(self.n_robots):  # the compiled banks' input checks, before any work
            _check_records(r, records[r], stale[r])
        filters = [copy.deepcopy(f) for f in self.filters]  # kept only if every call succeeds
        odometry = [
            [] if "odometry" in stale[r] else [rec.delta for rec in records[r].odometry]
            for r in range(self.n_robots)
        ]
        for r, f in enumerate(filters):
            k_odo = 0
            for rec in records[r].in_time_order():
                if isinstance(rec, OdometryRecord):
                    if "odometry" in stale[r]:
                        continue
                    team = {
                        j: odometry[j][k_odo]
                        for j in range(self.n_robots)
                        if j != r and k_odo < len(odometry[j])
                    }
                    f.predict(rec.delta, team)
                    k_odo += 1
                elif isinstance(rec, LidarRecord) and "lidar" not in stale[r]:
                    if self.oracle_identities:
                        f.update(oracle_range_bearing(rec.detections, feed.truth, r))
                    else:
                        f.update_lidar(rec.detections, rec.null_bearings_rad)
        self.filters = filters

    def padded_tables(self) -> tuple[np.ndarray, np.ndarray]:
        return tables_from_mixtures([_teammates(f) for f in self.filters])

    def mixture(self, robot: int) -> GaussianMixture:
        return _teammates(self.filters[self._robot(robot)])

    def estimate(self, robot: int, threshold: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
        # The GM-PHD's extraction (Vo & Ma) on this robot's teammate components.
        return estimate_table(self.mixture(robot).to_table(), threshold)

    def identities(self, robot: int) -> dict[int, np.ndarray]:
        """ID-PHD: the mean of each ID's highest-weight component, whatever its weight (as
        Stegagno 2013 defines the estimate; the static class is left out)."""
        f = self.filters[self._robot(robot)]
        if isinstance(f, IDPHD):
            return {i: p for i, p in f.estimate(min_weight=0.0).items() if i >= 0}
        return f.estimate()


def _teammates(f: Any) -> GaussianMixture:
    """The components of ``f`` that stand for a teammate: ID-PHD's tagged ones (its static
    class, decoys and obstacles, and its not-yet-split births are left out); every component
    of the per-teammate baselines."""
    mixture = f.mixture
    if isinstance(f, IDPHD):
        keep = np.asarray(f.tags) >= 0
        return GaussianMixture(mixture.weights[keep], mixture.means[keep], mixture.covs[keep])
    return mixture


def oracle_range_bearing(detections: np.ndarray, truth: Any, observer: int) -> dict:
    """Each detection within :data:`ORACLE_GATE_M` of a true robot, as ``{id: (r, bearing)}``
    (one-to-one, by the Hungarian assignment on distance). The truth is the step's end, up to
    one odometry period after the scan: a turning observer's far detections can miss the gate
    (a bias against the oracle baselines, not for them)."""
    from scipy.optimize import linear_sum_assignment

    det = np.asarray(detections, dtype=float).reshape(-1, 2)
    if not det.shape[0] or truth is None:
        return {}
    rel = truth.relative_xy[observer]
    dist = np.hypot(det[:, None, 0] - rel[None, :, 0], det[:, None, 1] - rel[None, :, 1])
    dist[:, observer] = np.inf
    cost = np.where(np.isfinite(dist), dist, 1e6)
    rows, cols = linear_sum_assignment(cost)
    return {
        int(j): np.array([math.hypot(*det[i]), math.atan2(det[i, 1], det[i, 0])])
        for i, j in zip(rows, cols, strict=True)
        if dist[i, j] <= ORACLE_GATE_M
    }


def idphd_config(phd: PHDConfig) -> IDPHDConfig:
    """ID-PHD with the World's lidar models (noise, clutter, detection) from ``phd``."""
    return IDPHDConfig(
        detection=phd,
        lidar_noise_std_m=phd.lidar.noise_std_m,
        lidar_clutter_intensity_per_m2=phd.lidar.clutter_intensity,
    )


# ---------------------------------------------------------------------- the entries
def _with_mode(mode: str | None) -> Callable[[PHDConfig], PHDConfig]:
    return lambda phd: phd if mode is None else dataclasses.replace(phd, mode=mode)


_MODES = {"": None, "-lc": "lidar-camera", "-lo": "lidar-only"}
_MODE_TEXT = {
    "": "in the config's mode",
    "-lc": "lidar + camera",
    "-lo": "lidar only",
}

for _suffix, _mode in _MODES.items():
    _set_mode = _with_mode(_mode)
    register(
        f"phd{_suffix}",
        f"GM-PHD, {_MODE_TEXT[_suffix]} (compiled bank of every robot's filter)",
        bank_family(PHDBank, _mode),
    )
    register(
        f"phd-reference{_suffix}",
        f"GM-PHD, {_MODE_TEXT[_suffix]} (pure-numpy reference filter per robot)",
        lambda n, phd, seed, _m=_set_mode: ReferenceLocalizer(_m(phd), n),
    )
register(
    "id-phd",
    "ID-PHD, Stegagno 2013 (lidar + teammates' communicated odometry; identities)",
    lambda n, phd, seed: IdentityLocalizer(
        [IDPHD(idphd_config(phd)) for _ in range(n)], oracle_identities=False
    ),
)


def _ukf(n: int, phd: PHDConfig, seed: int) -> Localizer:
    from .baselines import UKFTracker

    return IdentityLocalizer([UKFTracker() for _ in range(n)], oracle_identities=True)


def _particle(n: int, phd: PHDConfig, seed: int) -> Localizer:
    from .baselines import ParticleFilterTracker

    filters = [ParticleFilterTracker(seed=seed * 1000 + r) for r in range(n)]
    return IdentityLocalizer(filters, oracle_identities=True)


register("ukf", "IR-UKF study's UKF per teammate (oracle-identified range-bearing)", _ukf)
register(
    "pf", "Lee 2012 particle filter per teammate (oracle-identified range-bearing)", _particle
)


def _pmb_reference(mode: str | None) -> Builder:
    def build(n: int, phd: PHDConfig, seed: int) -> Localizer:
        from .pmb import RobotCentricPMB

        return ReferenceLocalizer(_with_mode(mode)(phd), n, filter_class=RobotCentricPMB)

    return build


for _suffix, _mode in _MODES.items():
    register(
        f"pmb{_suffix}",
        f"Poisson multi-Bernoulli, {_MODE_TEXT[_suffix]} (compiled bank; w = existence)",
        bank_family(PMBBank, _mode),
    )
    register(
        f"pmb-reference{_suffix}",
        f"Poisson multi-Bernoulli, {_MODE_TEXT[_suffix]} (pure-numpy reference per robot)",
        _pmb_reference(_mode),
    )


# ------------------------------------------------------- Stegagno 2012 thesis (mutual)
def _mutual(method: str, **config: Any) -> Builder:
    def build(n: int, phd: PHDConfig, seed: int) -> Localizer:
        from .mutual.localizer import METHODS, MutualLocalizer

        cfg = METHODS[method].config_type(**config) if config else None
        return MutualLocalizer(method, n, seed, config=cfg)

    return build


for _name, _method, _config, _text in (
    ("p-multireg", "p-multireg", {}, "P-MultiReg, Stegagno 2012 ch. 6 (lidar registration"),
    ("fastslam-mc", "fastslam-mc", {}, "FastSLAM-MC, Stegagno 2012 ch. 5 (lidar"),
    ("p-multibeareg", "p-multibeareg", {}, "P-MultiBeaReg, Stegagno 2012 ch. 10 (camera bearings"),
    (
        "p-multibeareg-lidar",
        "p-multibeareg",
        {"features": "lidar"},
        "P-MultiBeaReg on the lidar detections' bearings, the thesis's own detector (lidar",
    ),
):
    register(
        _name,
        f"{_text} + radio; teammates' poses, identities)",
        _mutual(_method, **_config),
        needs_comms=True,
    )
