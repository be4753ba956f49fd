"""Vehicle telemetry: samples, ROS REP-103 conversions, a time-indexed buffer,
validation, local geodesy and sample trajectories (pure numpy, no ROS).

Telemetry feeds the frame timing of METHODS.md B, eqs. (1)-(2): the ground
speed V, the height above ground H and the ground-track course (which fixes
the angle phi between the detector axis and the velocity). This module holds
the vehicle state those equations need; the equations themselves live with
the timing code.

Frames and sign conventions
---------------------------
* Time ``t``: POSIX seconds (UTC), float.
* Position: WGS-84 latitude/longitude in degrees, altitude above mean sea
  level (``alt_msl_m``) and height above ground (``height_agl_m``) in metres.
* Velocity ``vel_ned_mps``: (north, east, down) in m/s, as MAVLink
  GLOBAL_POSITION_INT (vx, vy, vz).
* ``course_rad``: direction of the ground track, radians clockwise from true
  north in [0, 2 pi) (MAVLink cog/hdg convention): ``atan2(v_east, v_north)``.
* Attitude ``roll_rad, pitch_rad, yaw_rad``: MAVLink ATTITUDE, Euler ZYX of
  the FRD body (x forward, y right, z down) relative to NED; yaw clockwise
  from north, pitch positive nose up, roll positive right wing down. ``None``
  when the source gave no attitude.
* ROS (REP-103/105): ENU world axes (x east, y north, z up) and FLU body axes
  (x forward, y left, z up). ``ned_to_enu`` and ``attitude_quaternion_enu``
  convert, exactly as mavros publishes ``/mavros/imu/data`` and
  ``/mavros/local_position/velocity_local``.
"""

from __future__ import annotations

import bisect
import math
import threading
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np

__all__ = [
    "TelemetrySample",
    "TelemetryBuffer",
    "ned_to_enu",
    "attitude_quaternion_enu",
    "course_from_velocity",
    "validate_sample",
    "timing_usable",
    "enu_offset_m",
    "enu_to_latlon",
    "trajectory_through_fixes",
    "trajectory_straight",
    "WGS84_A",
    "WGS84_E2",
    "MAX_GROUND_SPEED_MPS",
    "MIN_TIMING_SPEED_MPS",
]

# WGS-84 ellipsoid: semi-major axis (m) and first eccentricity squared.
WGS84_A = 6378137.0
WGS84_E2 = 6.69437999014e-3

#: Ground speeds above this (m/s, ~540 km/h) are treated as corrupt data.
MAX_GROUND_SPEED_MPS = 150.0
#: Below this ground speed (m/s) the vehicle hovers: the sample is valid but
#: eq. (1) gives no usable frame interval.
MIN_TIMING_SPEED_MPS = 0.5
#: Heights above ground beyond this (m) are treated as corrupt data.
MAX_HEIGHT_AGL_M = 20000.0

_TWO_PI = 2.0 * math.pi


@dataclass(frozen=True, eq=False)
class TelemetrySample:
    """The vehicle state at one instant (units and frames: see module docstring).

    ``time_boot_ms`` is the autopilot's boot clock of the source message when
    the sample came from MAVLink (used only to order/deduplicate), else None.
    """

    t: float
    lat_deg: float
    lon_deg: float
    alt_msl_m: float
    height_agl_m: float
    vel_ned_mps: np.ndarray
    ground_speed_mps: float
    course_rad: float
    roll_rad: float | None = 0.0
    pitch_rad: float | None = 0.0
    yaw_rad: float | None = 0.0
    time_boot_ms: int | None = None
    system_id: int | None = None

    def __post_init__(self) -> None:
        v = np.asarray(self.vel_ned_mps, dtype=np.float64).reshape(-1)
        if v.shape != (3,):
            raise ValueError(
                f"vel_ned_mps must have 3 components (north, east, down), got shape {v.shape}"
            )
        v.setflags(write=False)
        object.__setattr__(self, "vel_ned_mps", v)

    @property
    def vel_enu_mps(self) -> np.ndarray:
        """Velocity in ENU (x east, y north, z up), m/s (REP-103)."""
        return ned_to_enu(self.vel_ned_mps)

    @property
    def has_attitude(self) -> bool:
        return self.roll_rad is not None and self.pitch_rad is not None and self.yaw_rad is not None

    def orientation_enu(self) -> tuple[float, float, float, float] | None:
        """Body (FLU) orientation w.r.t. ENU as (x, y, z, w), or None without attitude."""
        if not self.has_attitude:
            return None
        return attitude_quaternion_enu(self.roll_rad, self.pitch_rad, self.yaw_rad)  # type: ignore[arg-type]


# --------------------------------------------------------------------------- #
# ROS conversions
# --------------------------------------------------------------------------- #
def ned_to_enu(v: Sequence[float] | np.ndarray) -> np.ndarray:
    """Convert vector(s) from NED to ENU: ``(e, n, u) = (v[1], v[0], -v[2])``.

    Works on a (3,) vector or an (..., 3) array; returns float64.
    """
    a = np.asarray(v, dtype=np.float64)
    if a.shape[-1] != 3:
        raise ValueError(f"expected (..., 3) vectors, got shape {a.shape}")
    return np.stack([a[..., 1], a[..., 0], -a[..., 2]], axis=-1)


def _quat_from_euler_zyx(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Quaternion (x, y, z, w) of R = Rz(yaw) Ry(pitch) Rx(roll) (intrinsic ZYX)."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return np.array(
        [
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
            cr * cp * cy + sr * sp * sy,
        ]
    )


def attitude_quaternion_enu(
    roll: float, pitch: float, yaw: float
) -> tuple[float, float, float, float]:
    """Orientation of the FLU body w.r.t. ENU from MAVLink NED/FRD Euler angles.

    ``q_ENU<-FLU = q_ENU<-NED * q_NED<-FRD(roll, pitch, yaw) * q_FRD<-FLU``
    (what mavros publishes on ``imu/data``). Both frame swaps are 180 deg
    rotations, so in Euler form (ZYX, radians) this is simply
    ``roll_enu = roll``, ``pitch_enu = -pitch``, ``yaw_enu = pi/2 - yaw``:
    yaw 0 in NED (nose north) is yaw +90 deg in ENU (x axis of ENU is east).
    Returns (x, y, z, w) with w >= 0.
    """
    for name, val in (("roll", roll), ("pitch", pitch), ("yaw", yaw)):
        if not math.isfinite(val):
            raise ValueError(f"{name} must be finite, got {val}")
    q = _quat_from_euler_zyx(roll, -pitch, math.pi / 2 - yaw)
    if q[3] < 0:
        q = -q
    return (float(q[0]), float(q[1]), float(q[2]), float(q[3]))


def course_from_velocity(v_north: float, v_east: float) -> float:
    """Ground-track course in [0, 2 pi): ``atan2(v_east, v_north)`` (clockwise from north)."""
    return float(math.atan2(v_east, v_north) % _TWO_PI)


def heading_from_quaternion_enu(x: float, y: float, z: float, w: float) -> float:
    """Compass heading (rad, clockwise from north, [0, 2 pi)) of the body x axis.

    Inverse of the yaw part of :func:`attitude_quaternion_enu`: the ENU yaw
    ``psi = atan2(2 (w z + x y), 1 - 2 (y^2 + z^2))`` (counter-clockwise from
    east) becomes ``pi/2 - psi``.
    """
    psi = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return float((math.pi / 2.0 - psi) % _TWO_PI)


def sample_from_enu(
    t: float,
    vel_enu_mps: Sequence[float],
    height_agl_m: float,
    *,
    lat_deg: float = 0.0,
    lon_deg: float = 0.0,
    alt_msl_m: float = 0.0,
    heading_rad: float | None = None,
) -> TelemetrySample:
    """A :class:`TelemetrySample` from ROS (REP-103) inputs: ENU velocity (m/s),
    height above ground (m) and an optional compass heading (rad); course and
    ground speed follow from the velocity, yaw = heading (course if None),
    roll/pitch unknown (0)."""
    ve, vn, vu = (float(c) for c in vel_enu_mps)
    course = course_from_velocity(vn, ve)
    return TelemetrySample(
        t=t,
        lat_deg=lat_deg,
        lon_deg=lon_deg,
        alt_msl_m=alt_msl_m,
        height_agl_m=float(height_agl_m),
        vel_ned_mps=np.array([vn, ve, -vu]),
        ground_speed_mps=math.hypot(ve, vn),
        course_rad=course,
        yaw_rad=course if heading_rad is None else heading_rad,
    )


# --------------------------------------------------------------------------- #
# Validation
# --------------------------------------------------------------------------- #
def validate_sample(
    s: TelemetrySample,
    *,
    max_ground_speed_mps: float = MAX_GROUND_SPEED_MPS,
    max_height_agl_m: float = MAX_HEIGHT_AGL_M,
) -> tuple[bool, str]:
    """Is ``s`` physically plausible data? Returns (ok, reason); reason is '' when ok.

    Rejected: non-finite fields (NaN/inf), latitude outside [-90, 90],
    longitude outside [-180, 180], negative or absurd height above ground,
    negative or absurd (> ``max_ground_speed_mps``) ground speed, course
    outside [0, 2 pi). A hovering vehicle (ground speed 0) is *valid*: see
    :func:`timing_usable` for whether the sample can time frames.
    """
    scalars = {
        "t": s.t,
        "lat_deg": s.lat_deg,
        "lon_deg": s.lon_deg,
        "alt_msl_m": s.alt_msl_m,
        "height_agl_m": s.height_agl_m,
        "ground_speed_mps": s.ground_speed_mps,
        "course_rad": s.course_rad,
    }
    for name in ("roll_rad", "pitch_rad", "yaw_rad"):
        val = getattr(s, name)
        if val is not None:
            scalars[name] = val
    for name, val in scalars.items():
        if val is None or not math.isfinite(val):
            return False, f"non-finite {name} ({val})"
    if not np.all(np.isfinite(s.vel_ned_mps)):
        return False, f"non-finite vel_ned_mps ({s.vel_ned_mps.tolist()})"
    if not -90.0 <= s.lat_deg <= 90.0:
        return False, f"latitude out of range ({s.lat_deg} deg)"
    if not -180.0 <= s.lon_deg <= 180.0:
        return False, f"longitude out of range ({s.lon_deg} deg)"
    if s.height_agl_m < 0.0:
        return False, f"negative height above ground ({s.height_agl_m:.3f} m)"
    if s.height_agl_m > max_height_agl_m:
        return False, f"absurd height above ground ({s.height_agl_m:.1f} m > {max_height_agl_m:g})"
    if s.ground_speed_mps < 0.0:
        return False, f"negative ground speed ({s.ground_speed_mps:.3f} m/s)"
    if s.ground_speed_mps > max_ground_speed_mps:
        return (
            False,
            f"absurd ground speed ({s.ground_speed_mps:.1f} m/s > {max_ground_speed_mps:g})",
        )
    if not 0.0 <= s.course_rad < _TWO_PI:
        return False, f"course out of range ({s.course_rad} rad, expected [0, 2 pi))"
    return True, ""


def timing_usable(
    s: TelemetrySample,
    *,
    min_ground_speed_mps: float = MIN_TIMING_SPEED_MPS,
    max_ground_speed_mps: float = MAX_GROUND_SPEED_MPS,
) -> tuple[bool, str]:
    """Can ``s`` time frames with METHODS.md eq. (1)? Returns (ok, reason).

    Eq. (1), ``t = a H cos(phi) / (p f V)``, needs a valid sample with
    ``V >= min_ground_speed_mps`` (a hover, V ~ 0, is valid telemetry but
    gives an unbounded interval) and ``H > 0``.
    """
    ok, reason = validate_sample(s, max_ground_speed_mps=max_ground_speed_mps)
    if not ok:
        return False, f"invalid sample: {reason}"
    if s.ground_speed_mps < min_ground_speed_mps:
        return False, (
            f"hovering: ground speed {s.ground_speed_mps:.2f} m/s < {min_ground_speed_mps:g} m/s "
            "(valid telemetry, no frame interval)"
        )
    if s.height_agl_m <= 0.0:
        return False, "height above ground is 0 m (no frame interval)"
    return True, ""


# --------------------------------------------------------------------------- #
# Geodesy (local tangent plane)
# --------------------------------------------------------------------------- #
def _radii(lat_rad: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """WGS-84 meridian (M) and prime-vertical (N) radii of curvature, metres."""
    s2 = np.sin(lat_rad) ** 2
    w = 1.0 - WGS84_E2 * s2
    m = WGS84_A * (1.0 - WGS84_E2) / w**1.5
    n = WGS84_A / np.sqrt(w)
    return m, n


def enu_offset_m(lat0: float, lon0: float, lat, lon) -> tuple[np.ndarray, np.ndarray]:
    """East and north offsets (metres) of (lat, lon) from (lat0, lon0), degrees in.

    Local tangent plane on the WGS-84 ellipsoid:
    ``north = M(lat0) (lat - lat0)``, ``east = N(lat_m) cos(lat_m) (lon - lon0)``
    with angles in radians, M/N the meridian/prime-vertical radii and
    ``lat_m`` the mid latitude. Within 1 km the distance ``hypot(east,
    north)`` matches the ECEF chord to 1e-5 relative and the direction
    matches ECEF-derived ENU at (lat0, lon0) to 1e-4 rad (the remainder is
    meridian convergence, ``d tan(lat) / 2R``). Vectorised; longitude
    differences are wrapped to [-180, 180).
    """
    lat = np.asarray(lat, dtype=np.float64)
    lon = np.asarray(lon, dtype=np.float64)
    phi0 = math.radians(lat0)
    dlat = np.radians(lat - lat0)
    dlon = np.radians((lon - lon0 + 180.0) % 360.0 - 180.0)
    m0, _ = _radii(phi0)
    phim = phi0 + dlat / 2.0
    _, nm = _radii(phim)
    return nm * np.cos(phim) * dlon, m0 * dlat


def enu_to_latlon(lat0: float, lon0: float, east, north) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`enu_offset_m` (exact inverse of the same approximation)."""
    east = np.asarray(east, dtype=np.float64)
    north = np.asarray(north, dtype=np.float64)
    phi0 = math.radians(lat0)
    m0, _ = _radii(phi0)
    dlat = north / m0
    phim = phi0 + dlat / 2.0
    _, nm = _radii(phim)
    dlon = east / (nm * np.cos(phim))
    lon = (lon0 + np.degrees(dlon) + 180.0) % 360.0 - 180.0
    return lat0 + np.degrees(dlat), lon


# --------------------------------------------------------------------------- #
# Buffer
# --------------------------------------------------------------------------- #
def _wrap_pi(a: float) -> float:
    return (a + math.pi) % _TWO_PI - math.pi


def _lerp_angle(a: float | None, b: float | None, f: float, *, positive: bool) -> float | None:
    """Interpolate angles along the short arc (unwrapped); result in [0, 2pi) or [-pi, pi)."""
    if a is None or b is None:
        return None
    x = a + _wrap_pi(b - a) * f
    return x % _TWO_PI if positive else _wrap_pi(x)


def _interpolate(s0: TelemetrySample, s1: TelemetrySample, t: float) -> TelemetrySample:
    """Linear interpolation at ``t`` between two samples (angles unwrapped)."""
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

    * ``max_age_s``: samples older than the newest minus ``max_age_s`` are
      dropped; at most ``max_samples`` are kept (oldest evicted).
    * ``stale_after_s``: :meth:`at` refuses a time more than this after the
      newest sample, or inside a gap between samples longer than this.
    * ``out_of_order``: ``"reorder"`` (default) inserts a late sample at its
      place in time, ``"reject"`` refuses it; both are counted. A sample with
      the same ``t`` as a stored one is refused as a duplicate.
    * Samples failing :func:`validate_sample` are refused and counted.

    Thread-safe (one lock): a reader thread may :meth:`add` while a node
    callback calls :meth:`at`.
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
        """Insert ``sample``; returns (accepted, reason) with reason '' on a plain append."""
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
            cutoff = self._times[-1] - self.max_age_s
            drop = bisect.bisect_left(self._times, cutoff)
            drop = max(drop, len(self._times) - self.max_samples)
            if drop > 0:
                del self._times[:drop]
                del self._samples[:drop]
                st.evicted += drop
            return True, note

    def latest(self) -> TelemetrySample | None:
        with self._lock:
            return self._samples[-1] if self._samples else None

    def is_stale(self, now: float) -> bool:
        """True when the newest sample is more than ``stale_after_s`` older than ``now`` (or none)."""
        last = self.latest()
        return last is None or now - last.t > self.stale_after_s

    def time_range(self) -> tuple[float, float] | None:
        with self._lock:
            return (self._times[0], self._times[-1]) if self._times else None

    def at(self, t: float) -> tuple[TelemetrySample | None, str]:
        """The state at time ``t`` (POSIX s): (sample, note) or (None, reason).

        Inside the buffer: linear interpolation between the two neighbours
        (lat/lon, altitude, height, velocity, speed linear; course and
        attitude along the short arc), refused if they are more than
        ``stale_after_s`` apart. After the newest sample by at most
        ``stale_after_s``: the newest sample held (re-stamped ``t``, note
        says so; no extrapolation). Before the oldest sample, or later than
        that: None with the reason.
        """
        if not math.isfinite(t):
            return None, f"non-finite query time {t}"
        with self._lock:
            if not self._samples:
                return None, "no telemetry received"
            t0, t1 = self._times[0], self._times[-1]
            if t < t0:
                return None, f"time {t:.3f} is {t0 - t:.3f} s before the oldest telemetry sample"
            if t > t1:
                age = t - t1
                if age > self.stale_after_s:
                    return (
                        None,
                        f"telemetry stale: newest sample {age:.3f} s before {t:.3f} (> {self.stale_after_s:g} s)",
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


# --------------------------------------------------------------------------- #
# Trajectories
# --------------------------------------------------------------------------- #
def _natural_cubic_spline(
    x: np.ndarray, y: np.ndarray, xq: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Value and first derivative at ``xq`` of the natural cubic spline through (x, y).

    Second derivatives M solve the standard tridiagonal system
    ``h_{i-1} M_{i-1} + 2 (h_{i-1} + h_i) M_i + h_i M_{i+1} = 6 (d_i - d_{i-1})``
    with ``M_0 = M_{n-1} = 0`` (d the secant slopes). ``y`` may be (n,) or (n, k).
    """
    n = len(x)
    h = np.diff(x)
    d = np.diff(y, axis=0) / h.reshape((-1,) + (1,) * (y.ndim - 1))
    a = np.zeros((n, n))
    rhs = np.zeros((n,) + y.shape[1:])
    a[0, 0] = a[-1, -1] = 1.0
    idx = np.arange(1, n - 1)
    a[idx, idx - 1] = h[:-1]
    a[idx, idx] = 2.0 * (h[:-1] + h[1:])
    a[idx, idx + 1] = h[1:]
    rhs[1:-1] = 6.0 * (d[1:] - d[:-1])
    m = np.linalg.solve(a, rhs)
    k = np.clip(np.searchsorted(x, xq, side="right") - 1, 0, n - 2)
    hk = h[k].reshape((-1,) + (1,) * (y.ndim - 1))
    s = (xq - x[k]).reshape(hk.shape)
    m0, m1, y0, y1 = m[k], m[k + 1], y[k], y[k + 1]
    b = (y1 - y0) / hk - hk * (2.0 * m0 + m1) / 6.0
    val = y0 + b * s + m0 / 2.0 * s**2 + (m1 - m0) / (6.0 * hk) * s**3
    der = b + m0 * s + (m1 - m0) / (2.0 * hk) * s**2
    return val, der


def _samples_from_arrays(
    t: np.ndarray,
    lat: np.ndarray,
    lon: np.ndarray,
    alt: np.ndarray,
    ground_alt_m: float,
    vel_ned: np.ndarray,
) -> list[TelemetrySample]:
    speed = np.hypot(vel_ned[:, 0], vel_ned[:, 1])
    course = np.arctan2(vel_ned[:, 1], vel_ned[:, 0]) % _TWO_PI
    yaw = (course + math.pi) % _TWO_PI - math.pi
    return [
        TelemetrySample(
            t=float(t[i]),
            lat_deg=float(lat[i]),
            lon_deg=float(lon[i]),
            alt_msl_m=float(alt[i]),
            height_agl_m=float(alt[i] - ground_alt_m),
            vel_ned_mps=vel_ned[i],
            ground_speed_mps=float(speed[i]),
            course_rad=float(course[i]),
            roll_rad=0.0,
            pitch_rad=0.0,
            yaw_rad=float(yaw[i]),
        )
        for i in range(len(t))
    ]


def trajectory_through_fixes(
    t: np.ndarray,
    lat_deg: np.ndarray,
    lon_deg: np.ndarray,
    alt_msl_m: np.ndarray,
    ground_alt_m: float = 230.0,
    rate_hz: float = 10.0,
) -> list[TelemetrySample]:
    """A smooth trajectory through GPS fixes taken at known times.

    Parameters
    ----------
    t : ndarray
        Capture times of the fixes, POSIX s, strictly increasing (at least 2).
    lat_deg, lon_deg : ndarray
        WGS-84 latitude and longitude of each fix, degrees.
    alt_msl_m : ndarray
        Altitude of each fix above mean sea level, m.
    ground_alt_m : float
        Ground altitude (flat terrain), m: height above ground = ``alt_msl_m - ground_alt_m``.
    rate_hz : float
        Sample rate of the trajectory, Hz.

    Returns
    -------
    list of TelemetrySample
        Samples at ``t_k = t[0] + k / rate_hz`` up to the last fix.

    Notes
    -----
    East, north (local tangent plane at the first fix, :func:`enu_offset_m`) and
    altitude are each a natural cubic spline of time through the fixes, so the
    trajectory passes exactly through every fix at its capture time; velocity is
    the spline's time derivative (NED, m/s), ground speed its horizontal norm,
    course ``atan2(v_e, v_n)``, yaw = course (camera fixed to the airframe, no
    gimbal), roll = pitch = 0.
    """
    tk = np.asarray(t, dtype=float)
    lat = np.asarray(lat_deg, dtype=float)
    lon = np.asarray(lon_deg, dtype=float)
    alt = np.asarray(alt_msl_m, dtype=float)
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise ValueError(f"rate_hz must be > 0, got {rate_hz}")
    if len(tk) < 2:
        raise ValueError(f"need at least 2 fixes, got {len(tk)}")
    if np.any(np.diff(tk) <= 0):
        raise ValueError(f"capture times must increase strictly (got {tk.tolist()})")
    e, n = enu_offset_m(lat[0], lon[0], lat, lon)
    knots = np.stack([e, n, alt], axis=1)
    count = int(math.floor((tk[-1] - tk[0]) * rate_hz + 1e-9)) + 1
    tq = tk[0] + np.arange(count) / rate_hz
    val, der = _natural_cubic_spline(tk - tk[0], knots, tq - tk[0])
    lat_q, lon_q = enu_to_latlon(lat[0], lon[0], val[:, 0], val[:, 1])
    vel_ned = np.stack([der[:, 1], der[:, 0], -der[:, 2]], axis=1)
    return _samples_from_arrays(tq, lat_q, lon_q, val[:, 2], ground_alt_m, vel_ned)


def trajectory_straight(
    *,
    t0: float = 1370353145.0,
    duration_s: float = 30.0,
    rate_hz: float = 10.0,
    lat0_deg: float = 41.0353080,
    lon0_deg: float = -83.3062512,
    ground_alt_m: float = 230.0,
    height_agl_m: float = 58.0,
    speed_mps: float = 8.0,
    course_rad: float = math.radians(60.0),
) -> list[TelemetrySample]:
    """A straight, level pass at constant ground speed, height and course.

    Position ``(east, north) = speed * (t - t0) * (sin course, cos course)``
    from (lat0, lon0) in the local tangent plane; velocity NED
    ``(speed cos course, speed sin course, 0)``; yaw = course, roll = pitch
    = 0. Defaults: the start fix and capture time (2013-06-04 13:39:05 UTC)
    of the Seneca strip, 58 m above ground, 8 m/s, course 60 deg.
    Sampled at ``rate_hz`` for ``duration_s`` (both ends included).
    """
    for name, val in (
        ("duration_s", duration_s),
        ("rate_hz", rate_hz),
        ("height_agl_m", height_agl_m),
    ):
        if not (math.isfinite(val) and val > 0):
            raise ValueError(f"{name} must be > 0, got {val}")
    if not (math.isfinite(speed_mps) and speed_mps >= 0):
        raise ValueError(f"speed_mps must be >= 0, got {speed_mps}")
    count = int(math.floor(duration_s * rate_hz + 1e-9)) + 1
    dt = np.arange(count) / rate_hz
    c = float(course_rad) % _TWO_PI
    east = speed_mps * dt * math.sin(c)
    north = speed_mps * dt * math.cos(c)
    lat, lon = enu_to_latlon(lat0_deg, lon0_deg, east, north)
    vel = np.tile([speed_mps * math.cos(c), speed_mps * math.sin(c), 0.0], (count, 1))
    alt = np.full(count, ground_alt_m + height_agl_m)
    samples = _samples_from_arrays(t0 + dt, lat, lon, alt, ground_alt_m, vel)
    if speed_mps == 0:  # hover: keep the requested heading instead of atan2(0, 0)
        samples = [replace(s, course_rad=c, yaw_rad=_wrap_pi(c)) for s in samples]
    return samples
