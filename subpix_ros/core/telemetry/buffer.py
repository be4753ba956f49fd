"""Recent telemetry samples sorted by time, interpolated at image stamps."""

from __future__ import annotations

import bisect
import math
import threading
from dataclasses import dataclass, replace

from subpix_ros.core.telemetry.sample import TelemetrySample
from subpix_ros.core.telemetry.validation import validate_sample

__all__ = ["BufferStats", "TelemetryBuffer"]

_TWO_PI = 2.0 * math.pi


def _wrap_pi(a: float) -> float:
    """Wrap an angle to [-pi, pi)."""
    return (a + math.pi) % _TWO_PI - math.pi


def _lerp_angle(a: float | None, b: float | None, f: float, *, positive: bool) -> float | None:
    """Interpolate angles along the short arc (unwrapped); result in [0, 2pi) or [-pi, pi)."""
    if a is None or b is None:
        return None
    x = a + _wrap_pi(b - a) * f
    return x % _TWO_PI if positive else _wrap_pi(x)


def _interpolate(s0: TelemetrySample, s1: TelemetrySample, t: float) -> TelemetrySample:
    """Interpolate linearly at ``t`` between two samples (angles along the short arc)."""
    f = (t - s0.t) / (s1.t - s0.t)
    lin = lambda a, b: a + (b - a) * f  # noqa: E731
    dlon = (s1.lon_deg - s0.lon_deg + 180.0) % 360.0 - 180.0
    lon = (s0.lon_deg + dlon * f + 180.0) % 360.0 - 180.0
    return TelemetrySample(
        t=t,
        lat_deg=lin(s0.lat_deg, s1.lat_deg),
        lon_deg=lon,
        alt_msl_m=lin(s0.alt_msl_m, s1.alt_msl_m),
        height_agl_m=lin(s0.height_agl_m, s1.height_agl_m),
        vel_ned_mps=lin(s0.vel_ned_mps, s1.vel_ned_mps),
        ground_speed_mps=lin(s0.ground_speed_mps, s1.ground_speed_mps),
        course_rad=_lerp_angle(s0.course_rad, s1.course_rad, f, positive=True),  # type: ignore[arg-type]
        roll_rad=_lerp_angle(s0.roll_rad, s1.roll_rad, f, positive=False),
        pitch_rad=_lerp_angle(s0.pitch_rad, s1.pitch_rad, f, positive=False),
        yaw_rad=_lerp_angle(s0.yaw_rad, s1.yaw_rad, f, positive=False),
        time_boot_ms=None,
        system_id=s0.system_id if s0.system_id == s1.system_id else None,
    )


@dataclass
class BufferStats:
    """Counts of what a :class:`TelemetryBuffer` accepted and refused, and the last reason."""

    accepted: int = 0
    invalid: int = 0
    out_of_order: int = 0
    out_of_order_rejected: int = 0
    duplicates: int = 0
    too_old: int = 0
    evicted: int = 0
    last_reason: str = ""


class TelemetryBuffer:
    """Recent telemetry samples, sorted by time, interpolated at image stamps.

    Thread-safe (one lock): a reader thread may :meth:`add` while a node
    callback calls :meth:`at`.

    Parameters
    ----------
    max_age_s : float
        Samples older than the newest minus ``max_age_s`` are dropped, s.
    stale_after_s : float
        :meth:`at` refuses a time more than this after the newest sample, or
        inside a gap between samples longer than this, s.
    max_samples : int
        At most this many samples are kept (oldest evicted).
    out_of_order : {"reorder", "reject"}
        ``"reorder"`` inserts a late sample at its place in time, ``"reject"``
        refuses it; both are counted. A sample with the same ``t`` as a stored
        one is refused as a duplicate. Samples failing
        :func:`~subpix_ros.core.telemetry.validate_sample` are refused and counted.

    Raises
    ------
    ValueError
        On a non-positive age or staleness, ``max_samples < 2`` or an unknown
        ``out_of_order`` policy.
    """

    def __init__(
        self,
        max_age_s: float = 30.0,
        stale_after_s: float = 1.0,
        *,
        max_samples: int = 10000,
        out_of_order: str = "reorder",
    ) -> None:
        if not (math.isfinite(max_age_s) and max_age_s > 0):
            raise ValueError(f"max_age_s must be > 0, got {max_age_s}")
        if not (math.isfinite(stale_after_s) and stale_after_s > 0):
            raise ValueError(f"stale_after_s must be > 0, got {stale_after_s}")
        if max_samples < 2:
            raise ValueError(f"max_samples must be >= 2, got {max_samples}")
        if out_of_order not in ("reorder", "reject"):
            raise ValueError(f"out_of_order must be 'reorder' or 'reject', got {out_of_order!r}")
        self.max_age_s = float(max_age_s)
        self.stale_after_s = float(stale_after_s)
        self.max_samples = int(max_samples)
        self.out_of_order = out_of_order
        self._samples: list[TelemetrySample] = []
        self._times: list[float] = []
        self._lock = threading.Lock()
        self.stats = BufferStats()

    def __len__(self) -> int:
        with self._lock:
            return len(self._samples)

    def clear(self) -> None:
        """Forget all samples (e.g. after a backwards time jump); stats are kept."""
        with self._lock:
            self._samples.clear()
            self._times.clear()

    def add(self, sample: TelemetrySample) -> tuple[bool, str]:
        """Insert a sample at its place in time.

        Parameters
        ----------
        sample : TelemetrySample
            The new sample.

        Returns
        -------
        accepted : bool
            Whether the sample was stored.
        reason : str
            Why it was refused, a note when it was reordered, '' on a plain append.
        """
        ok, reason = validate_sample(sample)
        with self._lock:
            st = self.stats
            if not ok:
                st.invalid += 1
                st.last_reason = reason
                return False, reason
            note = ""
            if self._times and sample.t <= self._times[-1]:
                i = bisect.bisect_left(self._times, sample.t)
                if i < len(self._times) and self._times[i] == sample.t:
                    st.duplicates += 1
                    st.last_reason = f"duplicate timestamp {sample.t:.6f}"
                    return False, st.last_reason
                st.out_of_order += 1
                if self.out_of_order == "reject":
                    st.out_of_order_rejected += 1
                    st.last_reason = (
                        f"out-of-order timestamp {sample.t:.6f} < newest {self._times[-1]:.6f}"
                    )
                    return False, st.last_reason
                if sample.t < self._times[-1] - self.max_age_s:
                    st.too_old += 1
                    st.last_reason = (
                        f"sample {self._times[-1] - sample.t:.3f} s older than newest (> max_age_s)"
                    )
                    return False, st.last_reason
                self._times.insert(i, sample.t)
                self._samples.insert(i, sample)
                note = "out of order: reordered"
            else:
                self._times.append(sample.t)
                self._samples.append(sample)
            st.accepted += 1
            self._evict()
            return True, note

    def _evict(self) -> None:
        """Drop samples older than ``max_age_s`` before the newest, and beyond ``max_samples``."""
        cutoff = self._times[-1] - self.max_age_s
        drop = bisect.bisect_left(self._times, cutoff)
        drop = max(drop, len(self._times) - self.max_samples)
        if drop > 0:
            del self._times[:drop]
            del self._samples[:drop]
            self.stats.evicted += drop

    def _why_empty(self) -> str:
        """Say why there is no sample: none came, or every one was refused as invalid."""
        st = self.stats
        if st.invalid and not st.accepted:
            return (
                f"telemetry unusable: all {st.invalid} sample(s) refused as invalid "
                f"(last: {st.last_reason})"
            )
        return "no telemetry received"

    def latest(self) -> TelemetrySample | None:
        """Return the newest sample, or None when empty."""
        with self._lock:
            return self._samples[-1] if self._samples else None

    def is_stale(self, now: float) -> bool:
        """Tell whether the newest sample is over ``stale_after_s`` older than ``now`` (or none)."""
        last = self.latest()
        return last is None or now - last.t > self.stale_after_s

    def time_range(self) -> tuple[float, float] | None:
        """Return the times (POSIX s) of the oldest and newest samples, or None when empty."""
        with self._lock:
            return (self._times[0], self._times[-1]) if self._times else None

    def at(self, t: float) -> tuple[TelemetrySample | None, str]:
        """Return the vehicle state at a time.

        Parameters
        ----------
        t : float
            Query time, POSIX s.

        Returns
        -------
        sample : TelemetrySample or None
            The state at ``t``, None when refused.
        note : str
            Why it was refused, or a note (e.g. the newest sample was held);
            '' otherwise.

        Notes
        -----
        Inside the buffer: linear interpolation between the two neighbours
        (lat/lon, altitude, height, velocity, speed linear; course and
        attitude along the short arc), refused if they are more than
        ``stale_after_s`` apart. After the newest sample by at most
        ``stale_after_s``: the newest sample held (re-stamped ``t``, the note
        says so; no extrapolation). Before the oldest sample, or later than
        that: refused. An empty buffer says whether no sample came or every one was invalid.
        """
        if not math.isfinite(t):
            return None, f"non-finite query time {t}"
        with self._lock:
            if not self._samples:
                return None, self._why_empty()
            t0, t1 = self._times[0], self._times[-1]
            if t < t0:
                return None, f"time {t:.3f} is {t0 - t:.3f} s before the oldest telemetry sample"
            if t > t1:
                age = t - t1
                if age > self.stale_after_s:
                    return (
                        None,
                        f"telemetry stale: newest sample {age:.3f} s before {t:.3f} "
                        f"(> {self.stale_after_s:g} s)",
                    )
                return replace(
                    self._samples[-1], t=t, time_boot_ms=None
                ), f"held newest sample ({age:.3f} s old)"
            i = bisect.bisect_left(self._times, t)
            if self._times[i] == t:
                return self._samples[i], ""
            s0, s1 = self._samples[i - 1], self._samples[i]
        gap = s1.t - s0.t
        if gap > self.stale_after_s:
            return None, f"telemetry gap of {gap:.3f} s around {t:.3f} (> {self.stale_after_s:g} s)"
        return _interpolate(s0, s1, t), ""
