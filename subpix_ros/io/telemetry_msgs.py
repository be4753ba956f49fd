"""Telemetry samples <-> ROS messages (CDR bytes through the shared typestore).

One code path for the telemetry node (which publishes these bytes raw) and the
sample-flight builder (which writes them into bags), so the bag's telemetry is
exactly what the node publishes.

Topics and types (relative names, under the node's namespace):

========================  ==============================  =========================================
``telemetry/fix``         sensor_msgs/NavSatFix           lat/lon (deg), altitude (m, MSL as MAVLink
                                                          GLOBAL_POSITION_INT gives it), status:
                                                          the GNSS fix (STATUS_NO_FIX without one)
``telemetry/velocity``    geometry_msgs/TwistStamped      ground velocity, ENU (x east, y north,
                                                          z up; REP-103), frame_id ``map``
``telemetry/height``      std_msgs/Float64                height above ground (m)
``telemetry/imu``         sensor_msgs/Imu                 orientation of base_link (FLU) in ENU;
                                                          rates/accelerations not provided (cov -1)
``telemetry/frame_interval``  std_msgs/Float64          recommended frame interval (s), eq. 1
========================  ==============================  =========================================
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from subpix_ros.core.telemetry import (
    TelemetrySample,
    attitude_quaternion_enu,
    heading_from_quaternion_enu,
    ned_to_enu,
    sample_from_enu,
)
from subpix_ros.io.cdr import TYPESTORE, header_to_ns, make_header, serialize

T = TYPESTORE.types

FIX = "sensor_msgs/msg/NavSatFix"
TWIST = "geometry_msgs/msg/TwistStamped"
FLOAT64 = "std_msgs/msg/Float64"
IMU = "sensor_msgs/msg/Imu"
VECTOR3 = "geometry_msgs/msg/Vector3Stamped"

TOPICS = {
    "fix": FIX,
    "velocity": TWIST,
    "height": FLOAT64,
    "imu": IMU,
    "frame_interval": FLOAT64,
}


def _unknown_cov() -> np.ndarray:
    return np.zeros(9, dtype=np.float64)


def fix_cdr(s: TelemetrySample, stamp_ns: int, frame_id: str = "gps") -> bytes:
    """Serialize ``s`` as a sensor_msgs/NavSatFix (CDR; position covariance unknown).

    The status is the sample's :attr:`~TelemetrySample.navsat_status` (STATUS_NO_FIX for a
    sample without a GNSS fix); the service is GPS.
    """
    status = T["sensor_msgs/msg/NavSatStatus"](status=s.navsat_status, service=1)
    msg = T[FIX](
        header=make_header(stamp_ns, frame_id),
        status=status,
        latitude=float(s.lat_deg),
        longitude=float(s.lon_deg),
        altitude=float(s.alt_msl_m),
        position_covariance=_unknown_cov(),
        position_covariance_type=0,
    )
    return serialize(msg, FIX)


def velocity_cdr(s: TelemetrySample, stamp_ns: int, frame_id: str = "map") -> bytes:
    """Serialize the velocity of ``s`` as a geometry_msgs/TwistStamped (CDR, ENU)."""
    e, n, u = (float(x) for x in ned_to_enu(np.asarray(s.vel_ned_mps, dtype=np.float64)))
    V3 = T["geometry_msgs/msg/Vector3"]
    twist = T["geometry_msgs/msg/Twist"](linear=V3(x=e, y=n, z=u), angular=V3(x=0.0, y=0.0, z=0.0))
    return serialize(T[TWIST](header=make_header(stamp_ns, frame_id), twist=twist), TWIST)


def float64_cdr(value: float) -> bytes:
    """Serialize ``value`` as a std_msgs/Float64 (CDR)."""
    return serialize(T[FLOAT64](data=float(value)), FLOAT64)


def imu_cdr(s: TelemetrySample, stamp_ns: int, frame_id: str = "base_link") -> bytes:
    """Serialize the attitude of ``s`` as a sensor_msgs/Imu orientation (CDR, ENU)."""
    x, y, z, w = attitude_quaternion_enu(s.roll_rad, s.pitch_rad, s.yaw_rad)
    V3 = T["geometry_msgs/msg/Vector3"]
    not_given = np.zeros(9, dtype=np.float64)
    not_given[0] = -1.0
    msg = T[IMU](
        header=make_header(stamp_ns, frame_id),
        orientation=T["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w),
        orientation_covariance=_unknown_cov(),
        angular_velocity=V3(x=0.0, y=0.0, z=0.0),
        angular_velocity_covariance=not_given.copy(),
        linear_acceleration=V3(x=0.0, y=0.0, z=0.0),
        linear_acceleration_covariance=not_given.copy(),
    )
    return serialize(msg, IMU)


@dataclass(frozen=True)
class FrameIds:
    """The ``header.frame_id`` of each telemetry message (telemetry_node's ``*_frame_id``).

    The defaults are one vehicle's names; with several vehicles on one ROS graph each node is
    given its own (``drone1/base_link``), as TF needs.
    """

    gps: str = "gps"  #: NavSatFix
    world: str = "map"  #: TwistStamped velocity (ENU)
    base: str = "base_link"  #: Imu orientation (body FLU)
    camera: str = "camera"  #: the expected shift (Vector3Stamped, px)


def sample_messages(
    s: TelemetrySample, frame_interval_s: float | None = None, frames: FrameIds = FrameIds()
) -> list[tuple[str, str, bytes]]:
    """(relative topic, type, CDR) of every telemetry message for one sample.

    A sample without attitude (no recent ATTITUDE message: ``roll_rad`` etc. None) has no
    ``telemetry/imu`` message; the others are built as usual. ``frames``: the messages'
    frame ids.
    """
    stamp = int(round(s.t * 1e9))
    out = [
        ("telemetry/fix", FIX, fix_cdr(s, stamp, frames.gps)),
        ("telemetry/height", FLOAT64, float64_cdr(s.height_agl_m)),
    ]
    if None not in (s.roll_rad, s.pitch_rad, s.yaw_rad):
        out.append(("telemetry/imu", IMU, imu_cdr(s, stamp, frames.base)))
    # the velocity last: a reader builds a sample on it with the height and heading before it
    out.append(("telemetry/velocity", TWIST, velocity_cdr(s, stamp, frames.world)))
    if frame_interval_s is not None:
        out.append(("telemetry/frame_interval", FLOAT64, float64_cdr(frame_interval_s)))
    return out


class TelemetryFromTopics:
    """Rebuild TelemetrySamples from the telemetry node's topics.

    The inverse of :func:`sample_messages`, for message objects of rclpy or rosbags alike.

    ``telemetry/height`` (Float64), ``telemetry/imu`` (Imu orientation, ENU) and
    ``telemetry/fix`` (NavSatFix) are remembered; each ``telemetry/velocity``
    (TwistStamped, ENU) gives a sample with them. A velocity that comes before any height (the
    order of separate topics is not guaranteed; bags recorded before the telemetry node sent
    the height first have it the other way round) is held and given as a sample by the first
    height, so the flight's first sample is not lost.
    """

    def __init__(self) -> None:
        self.height_m: float | None = None
        self.heading_rad: float | None = None
        self.fix: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self._waiting = None  # the newest velocity message before any height

    def height(self, msg) -> TelemetrySample | None:
        """Remember the height above ground of a ``telemetry/height`` message.

        A NaN or infinite height is kept too: the samples built with it are refused where they
        are used (:func:`~subpix_ros.core.telemetry.validate_sample`) and counted there, not
        lost without a word as if no height had come.

        Returns
        -------
        TelemetrySample or None
            The sample of a velocity that came before the first height, else None.
        """
        self.height_m = float(msg.data)
        waiting, self._waiting = self._waiting, None
        return None if waiting is None else self.velocity(waiting)

    def imu(self, msg) -> None:
        """Remember the heading of a ``telemetry/imu`` orientation."""
        q = msg.orientation
        self.heading_rad = heading_from_quaternion_enu(q.x, q.y, q.z, q.w)

    def navsat(self, msg) -> None:
        """Remember the position of a ``telemetry/fix`` message."""
        self.fix = (float(msg.latitude), float(msg.longitude), float(msg.altitude))

    def velocity(self, msg) -> TelemetrySample | None:
        """Build a sample from a ``telemetry/velocity`` message (None before any height: held)."""
        if self.height_m is None:
            self._waiting = msg
            return None
        v = msg.twist.linear
        lat, lon, alt = self.fix
        return sample_from_enu(
            header_to_ns(msg.header) * 1e-9,
            (v.x, v.y, v.z),
            self.height_m,
            lat_deg=lat,
            lon_deg=lon,
            alt_msl_m=alt,
            heading_rad=self.heading_rad,
        )
