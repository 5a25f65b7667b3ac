"""The simulated radio: robots broadcast their odometry and anonymous detections to teammates.

The Stegagno 2012 thesis's mutual localization (ch. 5-6, 10) and the Stegagno 2013 study's
ID-PHD need what teammates say about themselves: their own odometry since start and their
anonymous feature sets. A real radio loses packets, delivers them late, and reaches only so far;
the channel here models the three, per (sender, receiver) pair, with its own random stream so
that switching the radio on never changes the sensors' noise.

The channel is generic over receivers: the UGVs hear each other, and an aerial supervisor (or
any listener at a known position) can be added as an extra receiver.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from swarm_core.geometry import integrate_body_delta
from swarm_core.records import Broadcast
from swarm_core.validation import (
    check_non_negative,
    check_number_fields,
    check_positive,
    check_probability,
)


@dataclass(frozen=True, slots=True)
class CommsConfig:
    """The robots' radio.

    Attributes
    ----------
    enabled : bool
        Off by default: no broadcasts, no random draws, rollouts as without a radio.
    rate_hz : float
        Broadcasts per second per robot (each robot with its own phase, drawn at reset).
    loss_probability : float
        Probability that one receiver misses one broadcast, independently per pair.
    latency_s : float
        Fixed part of the delivery delay (s).
    latency_jitter_s : float
        Extra delay, uniform in ``[0, latency_jitter_s]`` per delivery (s). Deliveries can
        therefore arrive out of send order, as UDP broadcasts do.
    radius_m : float
        Receivers further than this from the sender at send time hear nothing (m).
    """

    enabled: bool = False
    rate_hz: float = 10.0
    loss_probability: float = 0.0
    latency_s: float = 0.0
    latency_jitter_s: float = 0.0
    radius_m: float = 100.0

    def __post_init__(self) -> None:
        check_number_fields(self, "comms")
        if not isinstance(self.enabled, bool):
            raise ValueError(f"comms.enabled must be a bool, got {self.enabled!r}")
        check_positive("comms.rate_hz", self.rate_hz)
        check_probability("comms.loss_probability", self.loss_probability)
        check_non_negative("comms.latency_s", self.latency_s)
        check_non_negative("comms.latency_jitter_s", self.latency_jitter_s)
        check_positive("comms.radius_m", self.radius_m)
        if self.latency_s + self.latency_jitter_s > 60.0:
            raise ValueError(
                f"comms.latency_s + comms.latency_jitter_s must be <= 60 s, got "
                f"{self.latency_s!r} + {self.latency_jitter_s!r}"
            )


class CommsChannel:
    """A lossy, delayed, range-limited broadcast channel.

    Parameters
    ----------
    config : CommsConfig
    sender_ids : sequence of str
        Who may send, in the row order of ``sender_xy`` in :meth:`exchange`.
    """

    def __init__(self, config: CommsConfig, sender_ids: tuple[str, ...]) -> None:
        self.config = config
        self.sender_ids = tuple(sender_ids)
        self._rng: np.random.Generator | None = None
        self._next_send_s = np.zeros(len(self.sender_ids))
        self._clear()

    def _clear(self) -> None:
        # In flight, one entry per (message, receiver): arrival time, send order (ties),
        # receiver id index and message; parallel arrays, delivered in (arrival, order) order.
        self._arrive = np.zeros(0)
        self._order = np.zeros(0, dtype=np.int64)
        self._receiver = np.zeros(0, dtype=np.int64)
        self._messages: dict[int, Broadcast] = {}  # send order -> message
        self._receiver_index: dict[str, int] = {}
        self._receiver_names: list[str] = []
        self._sent = 0

    def reset(self, rng: np.random.Generator, time_s: float = 0.0) -> None:
        """Forget everything in flight; draw each sender's phase from ``rng`` (the channel's own
        stream)."""
        self._rng = rng
        period = 1.0 / self.config.rate_hz
        self._next_send_s = time_s + rng.uniform(0.0, period, len(self.sender_ids))
        self._clear()

    def due_senders(self, time_s: float) -> np.ndarray:
        """Rows of the senders whose next broadcast falls due by ``time_s`` (and schedule the
        one after it). At most one broadcast per sender per call: a sender that fell behind
        skips, as a real radio's queue would drop stale state."""
        due = np.flatnonzero(self._next_send_s <= time_s + 1e-9)
        period = 1.0 / self.config.rate_hz
        # At least one period on: a send due only within the tolerance has floor(...) = -1.
        behind = np.maximum(np.floor((time_s - self._next_send_s[due]) / period) + 1.0, 1.0)
        self._next_send_s[due] += behind * period
        return due

    def exchange(
        self,
        time_s: float,
        outgoing: list[Broadcast],
        sender_xy: np.ndarray,
        receiver_ids: tuple[str, ...],
        receiver_xy: np.ndarray,
    ) -> dict[str, list[Broadcast]]:
        """Send ``outgoing`` at ``time_s`` and return what each receiver gets by ``time_s``.

        Parameters
        ----------
        time_s : float
            Now (s); deliveries due at or before it are returned.
        outgoing : list of Broadcast
            Sent now, one per sending robot; ``sender_xy`` holds their positions, same order.
        sender_xy : ndarray, shape (S, 2)
            World positions of the senders at send time (m), for the radius.
        receiver_ids : tuple of str
            Everyone listening (a robot never hears itself).
        receiver_xy : ndarray, shape (M, 2)
            Their world positions at send time (m).

        Returns
        -------
        dict
            ``receiver id -> list of Broadcast`` delivered by ``time_s``, oldest delivery first.
        """
        if self._rng is None:
            raise RuntimeError("CommsChannel.exchange() called before reset()")
        cfg = self.config
        if outgoing:
            sender_xy = np.asarray(sender_xy, dtype=np.float64).reshape(len(outgoing), 2)
            receiver_xy = np.asarray(receiver_xy, dtype=np.float64).reshape(-1, 2)
            # One uniform per (message, receiver) for loss and one for jitter, drawn whatever
            # the geometry, so the stream's use does not depend on where the robots are.
            shape = (len(outgoing), len(receiver_ids))
            lost = self._rng.random(shape) < cfg.loss_probability
            delay = cfg.latency_s + cfg.latency_jitter_s * self._rng.random(shape)
            dist = np.linalg.norm(sender_xy[:, None, :] - receiver_xy[None, :, :], axis=-1)
            senders = np.array([m.sender for m in outgoing])
            own = senders[:, None] == np.asarray(receiver_ids)[None, :]
            k, j = np.nonzero(~lost & ~own & (dist <= cfg.radius_m))
            receivers = np.array([self._receiver_slot(r) for r in receiver_ids], dtype=np.int64)
            self._arrive = np.concatenate([self._arrive, time_s + delay[k, j]])
            self._order = np.concatenate([self._order, self._sent + k])
            self._receiver = np.concatenate([self._receiver, receivers[j]])
            for q, message in enumerate(outgoing):
                self._messages[self._sent + q] = message
            self._sent += len(outgoing)
        delivered: dict[str, list[Broadcast]] = {rid: [] for rid in receiver_ids}
        due = self._arrive <= time_s + 1e-9
        if due.any():
            picked = np.flatnonzero(due)
            picked = picked[np.lexsort((self._order[picked], self._arrive[picked]))]
            names, messages = self._receiver_names, self._messages
            for r, o in zip(
                self._receiver[picked].tolist(), self._order[picked].tolist(), strict=True
            ):
                delivered.setdefault(names[r], []).append(messages[o])
            keep = ~due
            self._arrive, self._order = self._arrive[keep], self._order[keep]
            self._receiver = self._receiver[keep]
            pending = set(np.unique(self._order).tolist())
            self._messages = {o: m for o, m in messages.items() if o in pending}
        return delivered

    def _receiver_slot(self, receiver: str) -> int:
        slot = self._receiver_index.get(receiver)
        if slot is None:
            slot = self._receiver_index[receiver] = len(self._receiver_names)
            self._receiver_names.append(receiver)
        return slot


class SwarmRadio:
    """The robots' side of the radio in the simulator.

    Each robot integrates its own wheel odometry (what it would report: drift included), keeps
    its latest lidar detections and its latest camera frame's bearings (body frame; the camera
    sits at the body origin), and broadcasts the three when its next send falls due. The radio
    reads the records the sensors already drew: it never touches their random streams.

    Parameters
    ----------
    config : CommsConfig
    robot_ids : tuple of str
        The agents, in the rows of the positions passed to :meth:`step`.
    """

    def __init__(self, config: CommsConfig, robot_ids: tuple[str, ...]) -> None:
        self.robot_ids = tuple(robot_ids)
        self.channel = CommsChannel(config, self.robot_ids)
        self.odometry_pose = np.zeros((len(self.robot_ids), 3))
        self._detections: list[np.ndarray] = []
        self._detections_stamp = np.full(len(self.robot_ids), np.nan)
        self._bearings: list[np.ndarray] = []
        self._bearings_stamp = np.full(len(self.robot_ids), np.nan)

    def reset(self, rng: np.random.Generator) -> None:
        """Odometry back to the origin, nothing in flight; ``rng`` is the radio's own stream."""
        self.channel.reset(rng)
        self.odometry_pose[:] = 0.0
        self._detections = [np.zeros((0, 2)) for _ in self.robot_ids]
        self._detections_stamp[:] = np.nan
        self._bearings = [np.zeros(0) for _ in self.robot_ids]
        self._bearings_stamp[:] = np.nan

    def step(
        self,
        time_s: float,
        measurements: dict,
        robot_xy: np.ndarray,
        listeners: tuple[tuple[str, ...], np.ndarray] | None = None,
    ) -> dict[str, list[Broadcast]]:
        """Absorb one period's records, send what is due at ``time_s``, return the deliveries.

        Parameters
        ----------
        time_s : float
            End of the period (s).
        measurements : dict
            ``robot id -> RobotMeasurements`` of the period.
        robot_xy : ndarray, shape (N, 2)
            The robots' world positions now (m), for the radius.
        listeners : (ids, xy), optional
            Receivers beyond the robots (e.g. a UAV), with their positions (M, 2).
        """
        for i, rid in enumerate(self.robot_ids):
            records = measurements.get(rid)
            if records is None:
                continue
            for odo in records.odometry:
                self.odometry_pose[i] = integrate_body_delta(self.odometry_pose[i], odo.delta)
            if records.lidar:
                self._detections[i] = records.lidar[-1].detections
                self._detections_stamp[i] = records.lidar[-1].stamp_s
            if records.camera:
                self._bearings[i] = records.camera[-1].bearings_rad
                self._bearings_stamp[i] = records.camera[-1].stamp_s
        due = self.channel.due_senders(time_s)
        outgoing = [
            Broadcast(
                self.robot_ids[i],
                time_s,
                self.odometry_pose[i].copy(),
                self._detections[i],
                float(self._detections_stamp[i]),
                self._bearings[i],
                float(self._bearings_stamp[i]),
            )
            for i in due
        ]
        receiver_ids, receiver_xy = self.robot_ids, np.asarray(robot_xy, dtype=np.float64)
        if listeners is not None:
            receiver_ids = receiver_ids + tuple(listeners[0])
            receiver_xy = np.vstack([receiver_xy, np.asarray(listeners[1]).reshape(-1, 2)])
        return self.channel.exchange(time_s, outgoing, receiver_xy[due], receiver_ids, receiver_xy)
