"""``swarm_phd_msgs/EstimateStamped``: one robot's teammate estimate, as its on-board filter
publishes it (``ros/swarm_phd_msgs/msg/EstimateStamped.msg``).

A Gaussian mixture in the publishing robot's body frame (REP-103: x forward, y left, metres):
per component a weight (a PHD intensity, or a Bernoulli's existence probability), a mean and a
2x2 covariance, stamped with the time the estimate refers to. On the wire the arrays are flat
(``means`` 2N, ``covariances`` 4N row-major), as rosidl wants fixed element types; here they are
``(N,)``, ``(N, 2)`` and ``(N, 2, 2)``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from hardware_bridge.messages import (
    InvalidMessage,
    _get,
    _number_array,
    _root,
    header,
    parse_stamp,
)

ROS_TYPE = "swarm_phd_msgs/EstimateStamped"
BAG_TYPE = "swarm_phd_msgs/msg/EstimateStamped"
# ROS 2 .msg syntax of the fields (the package's file adds comments only).
ESTIMATE_STAMPED_MSG = """uint8 WEIGHT_INTENSITY=0
uint8 WEIGHT_EXISTENCE=1
std_msgs/Header header
string localizer
uint8 weight_kind
float64[] weights
float64[] means
float64[] covariances
"""
WEIGHT_INTENSITY = 0
WEIGHT_EXISTENCE = 1
WEIGHT_KINDS = {"intensity": WEIGHT_INTENSITY, "existence": WEIGHT_EXISTENCE}
#: Components a message may carry (a filter caps its mixture far below this).
MAX_COMPONENTS = 4096
#: Symmetry and positive semi-definiteness tolerance of a covariance, m^2.
_COV_TOL = 1e-9


@dataclass(frozen=True, slots=True)
class Estimate:
    """A validated ``EstimateStamped``.

    Attributes
    ----------
    stamp_ns : int
    frame_id : str
        The publishing robot's body frame.
    localizer : str
    weight_kind : str
        ``"intensity"`` (PHD) or ``"existence"`` (multi-Bernoulli).
    weights : ndarray, shape (N,)
    means_m : ndarray, shape (N, 2)
        Body frame, metres.
    covariances_m2 : ndarray, shape (N, 2, 2)
    """

    stamp_ns: int
    frame_id: str
    localizer: str
    weight_kind: str
    weights: np.ndarray
    means_m: np.ndarray
    covariances_m2: np.ndarray


def _mixture(weights, means, covariances) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Check shapes and values; raise ValueError naming the field."""
    w = np.asarray(weights, dtype=np.float64).reshape(-1)
    m = np.asarray(means, dtype=np.float64)
    p = np.asarray(covariances, dtype=np.float64)
    n = w.shape[0]
    if n == 0 and m.size == 0 and p.size == 0:  # an empty mixture, in any empty shape
        m, p = m.reshape(0, 2), p.reshape(0, 2, 2)
    if n > MAX_COMPONENTS:
        raise ValueError(f"weights: {n} components > {MAX_COMPONENTS}")
    if m.shape != (n, 2):
        raise ValueError(f"means: expected shape ({n}, 2) for {n} weights, got {m.shape}")
    if p.shape != (n, 2, 2):
        raise ValueError(f"covariances: expected shape ({n}, 2, 2), got {p.shape}")
    for name, arr in (("weights", w), ("means", m), ("covariances", p)):
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{name}: contains non-finite values")
    if np.any(w < 0.0):
        raise ValueError(f"weights: negative value {w[w < 0.0][0]!r}")
    if np.any(np.abs(p[:, 0, 1] - p[:, 1, 0]) > _COV_TOL):
        raise ValueError("covariances: not symmetric (xy != yx)")
    det = p[:, 0, 0] * p[:, 1, 1] - p[:, 0, 1] * p[:, 1, 0]
    if np.any(p[:, 0, 0] < -_COV_TOL) or np.any(p[:, 1, 1] < -_COV_TOL) or np.any(det < -_COV_TOL):
        raise ValueError("covariances: not positive semi-definite")
    return w, m, p


def estimate_stamped_msg(
    stamp_ns: int,
    weights: np.ndarray,
    means_m: np.ndarray,
    covariances_m2: np.ndarray,
    *,
    localizer: str,
    weight_kind: str = "intensity",
    frame_id: str = "base_link",
) -> dict[str, Any]:
    """The rosbridge JSON object of an ``EstimateStamped`` (shapes as :class:`Estimate`)."""
    if weight_kind not in WEIGHT_KINDS:
        raise ValueError(f"weight_kind must be one of {sorted(WEIGHT_KINDS)}, got {weight_kind!r}")
    if type(stamp_ns) is not int or stamp_ns <= 0:
        raise ValueError(f"stamp_ns must be a positive int (ns), got {stamp_ns!r}")
    w, m, p = _mixture(weights, means_m, covariances_m2)
    return {
        "header": header(stamp_ns, frame_id),
        "localizer": str(localizer),
        "weight_kind": WEIGHT_KINDS[weight_kind],
        "weights": w.tolist(),
        "means": m.reshape(-1).tolist(),
        "covariances": p.reshape(-1).tolist(),
    }


def parse_estimate_stamped(msg: Any) -> Estimate:
    """Validate an ``EstimateStamped`` JSON object; :class:`InvalidMessage` names the field."""
    msg = _root(msg)
    stamp_ns = parse_stamp(msg)
    frame_id = _get(msg, "header.frame_id")
    localizer = _get(msg, "localizer")
    for path, value in (("header.frame_id", frame_id), ("localizer", localizer)):
        if not isinstance(value, str):
            raise InvalidMessage(path, f"expected a string, got {type(value).__name__}")
    kind = _get(msg, "weight_kind")
    names = {code: name for name, code in WEIGHT_KINDS.items()}
    if type(kind) is not int or kind not in names:
        raise InvalidMessage("weight_kind", f"expected one of {sorted(names)}, got {kind!r}")
    w = _number_array(_get(msg, "weights"), "weights", max_len=MAX_COMPONENTS)
    n = w.size
    m = _number_array(_get(msg, "means"), "means", max_len=2 * n, exact_len=2 * n)
    p = _number_array(_get(msg, "covariances"), "covariances", max_len=4 * n, exact_len=4 * n)
    try:
        w, m, p = _mixture(w, m.reshape(n, 2), p.reshape(n, 2, 2))
    except ValueError as exc:
        field, _, reason = str(exc).partition(": ")
        raise InvalidMessage(field, reason) from None
    return Estimate(stamp_ns, frame_id, localizer, names[kind], w, m, p)


def estimate_topic(robot: str) -> str:
    """The topic a robot's on-board filter publishes its ``EstimateStamped`` on."""
    return f"/{robot}/swarm_phd/estimate"


def estimate_frame(robot: str) -> str:
    """The body frame an estimate of ``robot`` must name (``header.frame_id``)."""
    return f"{robot}/base_link"


def weight_kind_of(localizer_weight_meaning: str) -> str:
    """``Localizer.weight_meaning`` (``phd-weight`` / ``existence``) as an estimate's
    ``weight_kind`` (``intensity`` / ``existence``)."""
    return "existence" if localizer_weight_meaning == "existence" else "intensity"


class ReceivedEstimates:
    """Every robot's teammate estimate as its on-board filter published it, read like a
    :class:`~localization.protocol.Localizer` (the env's encoders, the task's estimate terms
    and the evaluation read it through the same calls as a filter bank).

    ``step(feed)`` ignores the feed's records (the robots filtered them on board) and takes,
    for every robot, the newest estimate ``source()`` returns (``{robot: Estimate}``, the last
    world step's, see :meth:`hardware_bridge.world.RealWorld.step_estimates`). A robot whose
    estimate did not arrive in the step (stale) keeps its last one; ``reset`` empties them.

    Parameters
    ----------
    robot_ids : sequence of str
        In agent order.
    name : str
        The family the robots run (``phd-lc``, ``pmb-lc``...): the env's ``config.localizer``.
    weight_meaning : str
        ``"phd-weight"`` or ``"existence"``, what the robots' weights mean.
    source : callable
        ``() -> {robot: Estimate}``.
    """

    has_identities = False

    def __init__(self, robot_ids, name: str, weight_meaning: str, source) -> None:
        from localization.mixture import GaussianMixture

        self.robot_ids = tuple(robot_ids)
        self.n_robots = len(self.robot_ids)
        self.name = str(name)
        if weight_meaning not in ("phd-weight", "existence"):
            raise ValueError(
                f"weight_meaning must be 'phd-weight' or 'existence', got {weight_meaning!r}"
            )
        self.weight_meaning = weight_meaning
        self._source = source
        self._index = {r: i for i, r in enumerate(self.robot_ids)}
        self._empty = GaussianMixture.empty()
        self._mixtures = [self._empty] * self.n_robots
        self._tables: tuple[np.ndarray, np.ndarray] | None = None
        #: Stamp (ns) of each robot's estimate in use (0 before the first).
        self.stamps_ns = np.zeros(self.n_robots, dtype=np.int64)

    @property
    def views(self):
        from localization.protocol import LocalizerView

        return [LocalizerView(self, r) for r in range(self.n_robots)]

    def _robot(self, robot: int) -> int:
        from localization.protocol import robot_index

        return robot_index(robot, self.n_robots)

    def reset(self, robots=None) -> None:
        for r in range(self.n_robots) if robots is None else [self._robot(r) for r in robots]:
            self._mixtures[r] = self._empty
            self.stamps_ns[r] = 0
        self._tables = None

    def step(self, feed: Any) -> None:
        from localization.feed import SwarmFeed
        from localization.mixture import GaussianMixture

        if not isinstance(feed, SwarmFeed):
            raise ValueError(f"{self.name}: step() takes a SwarmFeed, got {type(feed).__name__}")
        for robot, est in self._source().items():
            i = self._index.get(robot)
            if i is None:
                raise ValueError(
                    f"an estimate of unknown robot {robot!r} (robots: {self.robot_ids})"
                )
            self._mixtures[i] = GaussianMixture(est.weights, est.means_m, est.covariances_m2)
            self.stamps_ns[i] = est.stamp_ns
        self._tables = None

    def padded_tables(self) -> tuple[np.ndarray, np.ndarray]:
        if self._tables is None:
            from localization.protocol import tables_from_mixtures

            table, counts = tables_from_mixtures(self._mixtures)
            table.flags.writeable = False
            counts.flags.writeable = False
            self._tables = (table, counts)
        return self._tables

    def mixture(self, robot: int):
        return self._mixtures[self._robot(robot)]

    def estimate(self, robot: int, threshold: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
        """As the robots' family extracts: GM-PHD components ``round(w)`` times, Bernoulli
        tracks once each (see :meth:`localization.protocol.Localizer.estimate`)."""
        from localization.filter import estimate_table, ranked_above

        m = self._mixtures[self._robot(robot)]
        if self.weight_meaning == "existence":
            keep = ranked_above(m.weights, threshold)
            return m.means[keep].copy(), m.weights[keep].copy()
        return estimate_table(m.to_table(), threshold)

    def identities(self, robot: int) -> dict[int, np.ndarray]:
        self._robot(robot)
        return {}
