"""Plausibility of telemetry samples, and whether one can time frames (METHODS.md B eq. 1)."""

from __future__ import annotations

import math

import numpy as np

from subpix_ros.core.telemetry.sample import TelemetrySample

__all__ = [
    "MAX_GROUND_SPEED_MPS",
    "MIN_TIMING_SPEED_MPS",
    "MAX_HEIGHT_AGL_M",
    "validate_sample",
    "timing_usable",
]

#: Ground speeds above this (m/s, ~540 km/h) are treated as corrupt data.
MAX_GROUND_SPEED_MPS = 150.0
#: Below this ground speed (m/s) the vehicle hovers: the sample is valid but
#: eq. (1) gives no usable frame interval.
MIN_TIMING_SPEED_MPS = 0.5
#: Heights above ground beyond this (m) are treated as corrupt data.
MAX_HEIGHT_AGL_M = 20000.0

_TWO_PI = 2.0 * math.pi


def validate_sample(
    sample: TelemetrySample,
    *,
    max_ground_speed_mps: float = MAX_GROUND_SPEED_MPS,
    max_height_agl_m: float = MAX_HEIGHT_AGL_M,
) -> tuple[bool, str]:
    """Check that a sample is physically plausible data.

    Parameters
    ----------
    sample : TelemetrySample
        The sample to check.
    max_ground_speed_mps : float
        Ground speeds above this are corrupt, m/s.
    max_height_agl_m : float
        Heights above ground beyond this are corrupt, m.

    Returns
    -------
    ok : bool
        Whether the sample is plausible.
    reason : str
        Why not ('' when ok).

    Notes
    -----
    Rejected: non-finite fields (NaN/inf), latitude outside [-90, 90],
    longitude outside [-180, 180], negative or absurd height above ground,
    negative or absurd ground speed, course outside [0, 2 pi). A hovering
    vehicle (ground speed 0) is *valid*: see :func:`timing_usable` for whether
    the sample can time frames.
    """
    s = sample
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
    sample: TelemetrySample,
    *,
    min_ground_speed_mps: float = MIN_TIMING_SPEED_MPS,
    max_ground_speed_mps: float = MAX_GROUND_SPEED_MPS,
) -> tuple[bool, str]:
    """Check that a sample can time frames with METHODS.md B eq. (1).

    Parameters
    ----------
    sample : TelemetrySample
        The sample to check.
    min_ground_speed_mps : float
        Slowest ground speed that still gives a frame interval, m/s.
    max_ground_speed_mps : float
        Ground speeds above this are corrupt, m/s.

    Returns
    -------
    ok : bool
        Whether eq. (1) can use the sample.
    reason : str
        Why not ('' when ok).

    Notes
    -----
    Eq. (1), ``t = a H cos(phi) / (p f V)``, needs a valid sample with
    ``V >= min_ground_speed_mps`` (a hover, V ~ 0, is valid telemetry but
    gives an unbounded interval) and ``H > 0``.
    """
    ok, reason = validate_sample(sample, max_ground_speed_mps=max_ground_speed_mps)
    if not ok:
        return False, f"invalid sample: {reason}"
    if sample.ground_speed_mps < min_ground_speed_mps:
        return False, (
            f"hovering: ground speed {sample.ground_speed_mps:.2f} m/s "
            f"< {min_ground_speed_mps:g} m/s (valid telemetry, no frame interval)"
        )
    if sample.height_agl_m <= 0.0:
        return False, "height above ground is 0 m (no frame interval)"
    return True, ""
