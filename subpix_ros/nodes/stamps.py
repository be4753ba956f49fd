"""builtin_interfaces/Time stamps to and from integer nanoseconds; timers on the steady clock."""

from __future__ import annotations

from typing import Callable

__all__ = ["stamp_to_ns", "ns_to_stamp", "steady_timer"]


def stamp_to_ns(stamp) -> int:
    """Convert a builtin_interfaces/Time to integer nanoseconds."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def ns_to_stamp(ns: int, cls):
    """Build a ``cls`` stamp (builtin_interfaces/Time) from integer nanoseconds."""
    return cls(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))


def steady_timer(node, period_s: float, callback: Callable[[], None]):
    """Create a timer of ``node`` that runs on the steady (wall) clock, not the node's clock.

    With ``use_sim_time`` the node's clock is /clock: it stands still before a replay starts
    and once it ends, and a timer on it no longer fires. A node's housekeeping (flushing what
    it holds when its input stops, publishing what it has, checking the graph, a link's
    figures) must go on then.

    Parameters
    ----------
    node : rclpy.node.Node
        The node that owns the timer (it runs in the node's executor).
    period_s : float
        The period (s, wall time).
    callback : callable
        Called with no argument every ``period_s``.

    Returns
    -------
    rclpy.timer.Timer
        The timer (``cancel()``, ``node.destroy_timer()``).
    """
    from rclpy.clock import Clock, ClockType

    return node.create_timer(period_s, callback, clock=Clock(clock_type=ClockType.STEADY_TIME))
