"""builtin_interfaces/Time stamps to and from integer nanoseconds."""

from __future__ import annotations

__all__ = ["stamp_to_ns", "ns_to_stamp"]


def stamp_to_ns(stamp) -> int:
    """Convert a builtin_interfaces/Time to integer nanoseconds."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def ns_to_stamp(ns: int, cls):
    """Build a ``cls`` stamp (builtin_interfaces/Time) from integer nanoseconds."""
    return cls(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))
