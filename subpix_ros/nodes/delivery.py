"""How late camera frames reach a node: its clock at reception minus the frame's stamp.

Frames that travel intact but late are invisible to the node's own latency (measured from
reception), e.g. large frames published reliably from a process on Fast DDS's default
shared-memory segment, which arrive in bursts (docs/design-notes.md, "Frame -> shift p99: the
camera's Fast DDS segment"). The meter here makes that visible in /diagnostics; it holds no ROS
objects (the node passes its clock's time).
"""

from __future__ import annotations

import collections

__all__ = ["DeliveryDelay"]


class DeliveryDelay:
    """The delays of the last ``history`` frames: reception time minus stamp.

    Parameters
    ----------
    history : int
        Frames kept for the median and maximum.
    same_clock_s : float
        A delay beyond +- this many seconds means the stamps are not on the node's clock (a bag
        replayed without ``--clock``, a camera stamping with its own clock, a node on sim time
        before the first /clock): such a frame is counted, not measured.

    Notes
    -----
    delay = t_received - t_stamp (s), both on the node's clock (ROS time: sim time under
    ``use_sim_time``). It includes the camera's own time from exposure to publication; a clock
    offset between the camera's machine and this one adds to it (negative delays are kept).
    """

    def __init__(self, history: int = 200, same_clock_s: float = 10.0) -> None:
        self.same_clock_s = float(same_clock_s)
        self._delays: collections.deque[float] = collections.deque(maxlen=history)
        self.unmeasured = 0
        self.last_offset_s: float | None = None  # the last unmeasurable delay, s

    def add(self, stamp_ns: int, now_ns: int) -> float | None:
        """Record one frame; return its delay in s, or None when the clocks differ."""
        delay = (int(now_ns) - int(stamp_ns)) * 1e-9
        if abs(delay) > self.same_clock_s:
            self.unmeasured += 1
            self.last_offset_s = delay
            return None
        self._delays.append(delay)
        return delay

    def values(self) -> dict[str, str]:
        """Return the /diagnostics values: ``camera_delay_ms_p50``, ``_max`` (or why not measured).

        ``camera_delay_unmeasured`` counts the frames stamped on another clock, when there are any.
        """
        out: dict[str, str] = {}
        if self.unmeasured:
            out["camera_delay_unmeasured"] = str(self.unmeasured)
        if self._delays:
            d = sorted(self._delays)
            out["camera_delay_ms_p50"] = f"{1000 * d[len(d) // 2]:.1f}"
            out["camera_delay_ms_max"] = f"{1000 * d[-1]:.1f}"
        elif self.unmeasured:
            why = f"n/a (stamps {self.last_offset_s:+.0f} s from this node's clock)"
            out["camera_delay_ms_p50"] = out["camera_delay_ms_max"] = why
        return out

    @staticmethod
    def problem(delay_s: float | None, limit_s: float) -> str | None:
        """Return the warning for a frame ``delay_s`` late, if it is over ``limit_s`` (else None)."""
        if delay_s is None or not delay_s > limit_s:
            return None
        return (
            f"camera frame received {1000 * delay_s:.0f} ms after its stamp (over "
            f"camera_delay_warn_ms {1000 * limit_s:g}): frames arrive late; a camera publishing "
            "large frames reliably from a process without the package's Fast DDS profile "
            "delivers them in bursts (README: Camera frames between processes)"
        )
