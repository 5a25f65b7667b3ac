"""Message time stamps: integer nanoseconds (ROS ``builtin_interfaces/Time``) and float seconds,
converted the same way everywhere (the live bridge, the bag replay, the UAV's frames)."""

from __future__ import annotations

#: Nanoseconds per second.
NS_PER_S = 1_000_000_000


def ns_to_s(stamp_ns: int) -> float:
    """Integer nanoseconds to float seconds (whole seconds and the remainder apart, so a large
    stamp loses no nanosecond before the final addition)."""
    return (stamp_ns // NS_PER_S) + (stamp_ns % NS_PER_S) * 1e-9


def s_to_ns(stamp_s: float) -> int:
    """Float seconds to integer nanoseconds (rounded)."""
    return int(round(stamp_s * 1e9))
