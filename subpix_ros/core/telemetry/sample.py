"""The telemetry sample and its ROS (REP-103) conversions.

Units, frames and sign conventions: see :mod:`subpix_ros.core.telemetry`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

__all__ = [
    "TelemetrySample",
    "NO_FIX",
    "FIX",
    "SBAS_FIX",
    "GBAS_FIX",
    "ned_to_enu",
    "attitude_quaternion_enu",
    "course_from_velocity",
    "heading_from_quaternion_enu",
    "sample_from_enu",
]

_TWO_PI = 2.0 * math.pi

#: GNSS fix levels, the values of sensor_msgs/NavSatStatus ``status``.
NO_FIX, FIX, SBAS_FIX, GBAS_FIX = -1, 0, 1, 2


@dataclass(frozen=True, eq=False)
class TelemetrySample:
    """The vehicle state at one instant.

    Parameters
    ----------
    t : float
        Time, POSIX s (UTC).
    lat_deg, lon_deg : float
        WGS-84 latitude and longitude, degrees.
    alt_msl_m : float
        Altitude above mean sea level, m.
    height_agl_m : float
        Height above ground, m.
    vel_ned_mps : array_like, shape (3,)
        Velocity (north, east, down), m/s; stored as a read-only float64 array.
    ground_speed_mps : float
        Horizontal speed over ground, m/s.
    course_rad : float
        Ground-track course, radians clockwise from north, in [0, 2 pi).
    roll_rad, pitch_rad, yaw_rad : float or None
        MAVLink attitude (ZYX Euler angles of the FRD body w.r.t. NED), rad;
        None when the source gave no attitude.
    time_boot_ms : int or None
        Autopilot boot clock of the source MAVLink message (used only to
        order and deduplicate), else None.
    system_id : int or None
        MAVLink system id of the source, else None.
    fix_status : int or None
        The GNSS fix, as sensor_msgs/NavSatStatus ``status``: :data:`NO_FIX` (-1),
        :data:`FIX` (0), :data:`SBAS_FIX` (1, augmented: DGPS/SBAS), :data:`GBAS_FIX`
        (2, RTK); None when the source does not say (then a fix unless latitude and
        longitude are both exactly 0, what an autopilot without a position sends).

    Raises
    ------
    ValueError
        If ``vel_ned_mps`` does not have 3 components.
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
    fix_status: int | None = None

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
    def navsat_status(self) -> int:
        """The NavSatStatus ``status`` of the sample's position (``fix_status``, see above)."""
        if self.fix_status is not None:
            return int(self.fix_status)
        return NO_FIX if self.lat_deg == 0.0 and self.lon_deg == 0.0 else FIX

    @property
    def has_fix(self) -> bool:
        """Whether the position is a GNSS fix (:attr:`navsat_status` >= :data:`FIX`)."""
        return self.navsat_status >= FIX

    @property
    def has_attitude(self) -> bool:
        """Whether roll, pitch and yaw are all known."""
        return self.roll_rad is not None and self.pitch_rad is not None and self.yaw_rad is not None

    def orientation_enu(self) -> tuple[float, float, float, float] | None:
        """Return the body (FLU) orientation w.r.t. ENU.

        Returns
        -------
        tuple of float or None
            Quaternion (x, y, z, w) from :func:`attitude_quaternion_enu`, or
            None without attitude.
        """
        if not self.has_attitude:
            return None
        return attitude_quaternion_enu(self.roll_rad, self.pitch_rad, self.yaw_rad)  # type: ignore[arg-type]


def ned_to_enu(v: Sequence[float] | np.ndarray) -> np.ndarray:
    """Convert vectors from NED to ENU.

    Parameters
    ----------
    v : array_like, shape (3,) or (..., 3)
        Vector(s) in NED (north, east, down).

    Returns
    -------
    ndarray of float64, same shape
        ``(e, n, u) = (v[1], v[0], -v[2])``.

    Raises
    ------
    ValueError
        If the last axis does not have length 3.
    """
    a = np.asarray(v, dtype=np.float64)
    if a.shape[-1] != 3:
        raise ValueError(f"expected (..., 3) vectors, got shape {a.shape}")
    return np.stack([a[..., 1], a[..., 0], -a[..., 2]], axis=-1)


def _quat_from_euler_zyx(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Return the quaternion (x, y, z, w) of R = Rz(yaw) Ry(pitch) Rx(roll) (intrinsic ZYX)."""
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
    """Return the orientation of the FLU body w.r.t. ENU from MAVLink NED/FRD Euler angles.

    Parameters
    ----------
    roll, pitch, yaw : float
        MAVLink ATTITUDE angles (ZYX Euler, FRD body w.r.t. NED), rad.

    Returns
    -------
    tuple of float
        Quaternion (x, y, z, w) with ``w >= 0``.

    Raises
    ------
    ValueError
        If an angle is not finite.

    Notes
    -----
    ``q_ENU<-FLU = q_ENU<-NED * q_NED<-FRD(roll, pitch, yaw) * q_FRD<-FLU``
    (what mavros publishes on ``imu/data``). Both frame swaps are 180 deg
    rotations, so in Euler form (ZYX, radians) this is simply
    ``roll_enu = roll``, ``pitch_enu = -pitch``, ``yaw_enu = pi/2 - yaw``:
    yaw 0 in NED (nose north) is yaw +90 deg in ENU (x axis of ENU is east).
    """
    for name, val in (("roll", roll), ("pitch", pitch), ("yaw", yaw)):
        if not math.isfinite(val):
            raise ValueError(f"{name} must be finite, got {val}")
    q = _quat_from_euler_zyx(roll, -pitch, math.pi / 2 - yaw)
    if q[3] < 0:
        q = -q
    return (float(q[0]), float(q[1]), float(q[2]), float(q[3]))


def course_from_velocity(v_north: float, v_east: float) -> float:
    """Return the ground-track course, rad clockwise from north in [0, 2 pi).

    Parameters
    ----------
    v_north, v_east : float
        Horizontal velocity components, m/s.

    Returns
    -------
    float
        ``atan2(v_east, v_north) mod 2 pi``.
    """
    return float(math.atan2(v_east, v_north) % _TWO_PI)


def heading_from_quaternion_enu(x: float, y: float, z: float, w: float) -> float:
    """Return the compass heading of the body x axis from an ENU orientation.

    Parameters
    ----------
    x, y, z, w : float
        Orientation quaternion of the FLU body w.r.t. ENU.

    Returns
    -------
    float
        Heading, rad clockwise from north, in [0, 2 pi).

    Notes
    -----
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
    """Build a :class:`TelemetrySample` from ROS (REP-103) inputs.

    Parameters
    ----------
    t : float
        Time, POSIX s.
    vel_enu_mps : sequence of float
        Velocity (east, north, up), m/s.
    height_agl_m : float
        Height above ground, m.
    lat_deg, lon_deg, alt_msl_m : float
        Position, when known (0 otherwise).
    heading_rad : float or None
        Compass heading, rad clockwise from north; None uses the course.

    Returns
    -------
    TelemetrySample
        Course and ground speed from the velocity, yaw = heading (course if
        None), roll and pitch unknown (0).
    """
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
