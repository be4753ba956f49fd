"""Sample trajectories: a smooth path through GPS fixes, a straight level pass."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from subpix_ros.core.telemetry.geodesy import enu_offset_m, enu_to_latlon
from subpix_ros.core.telemetry.sample import TelemetrySample

__all__ = ["trajectory_through_fixes", "trajectory_straight"]

_TWO_PI = 2.0 * math.pi


def _natural_cubic_spline(
    x: np.ndarray, y: np.ndarray, xq: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Return the value and first derivative at ``xq`` of the natural cubic spline through (x, y).

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
    """Build level samples (yaw = course, roll = pitch = 0) from per-sample arrays."""
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
    """Build a smooth trajectory through GPS fixes taken at known times.

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

    Raises
    ------
    ValueError
        On a non-positive rate, fewer than 2 fixes or times not strictly increasing.

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
    """Build a straight, level pass at constant ground speed, height and course.

    Parameters
    ----------
    t0 : float
        Start time, POSIX s (default: the capture time of the Seneca strip,
        2013-06-04 13:39:05 UTC).
    duration_s : float
        Length of the pass, s.
    rate_hz : float
        Sample rate, Hz.
    lat0_deg, lon0_deg : float
        Start fix, degrees (default: the Seneca strip's).
    ground_alt_m : float
        Ground altitude above mean sea level, m.
    height_agl_m : float
        Height above ground, m.
    speed_mps : float
        Ground speed, m/s (0: a hover).
    course_rad : float
        Ground-track course, rad clockwise from north.

    Returns
    -------
    list of TelemetrySample
        Samples every ``1 / rate_hz`` over ``duration_s`` (both ends included).

    Raises
    ------
    ValueError
        On a non-positive duration, rate or height, or a negative speed.

    Notes
    -----
    Position ``(east, north) = speed * (t - t0) * (sin course, cos course)``
    from (lat0, lon0) in the local tangent plane; velocity NED
    ``(speed cos course, speed sin course, 0)``; yaw = course, roll = pitch = 0.
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
        samples = [
            replace(s, course_rad=c, yaw_rad=(c + math.pi) % _TWO_PI - math.pi) for s in samples
        ]
    return samples
