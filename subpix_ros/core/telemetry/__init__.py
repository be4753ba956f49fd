"""Vehicle telemetry: samples, ROS conversions, validation, geodesy, buffer, trajectories.

Telemetry feeds the frame timing of METHODS.md B, eqs. (1)-(2): the ground
speed V, the height above ground H and the ground-track course (which fixes
the angle phi between the detector axis and the velocity). This package holds
the vehicle state those equations need (pure numpy, no ROS, no file I/O); the
equations themselves live in :mod:`subpix_ros.core.timing` and the CSV/EXIF
readers in :mod:`subpix_ros.io.frame_metadata`.

Modules: :mod:`.sample` (the sample type and the REP-103 conversions),
:mod:`.validation` (plausibility limits), :mod:`.geodesy` (local tangent
plane), :mod:`.buffer` (time-indexed buffer, interpolation at image stamps),
:mod:`.trajectory` (smooth trajectories through fixes, straight passes).

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

from subpix_ros.core.telemetry.buffer import BufferStats, TelemetryBuffer
from subpix_ros.core.telemetry.geodesy import WGS84_A, WGS84_E2, enu_offset_m, enu_to_latlon
from subpix_ros.core.telemetry.sample import (
    TelemetrySample,
    attitude_quaternion_enu,
    course_from_velocity,
    heading_from_quaternion_enu,
    ned_to_enu,
    sample_from_enu,
)
from subpix_ros.core.telemetry.trajectory import trajectory_straight, trajectory_through_fixes
from subpix_ros.core.telemetry.validation import (
    MAX_GROUND_SPEED_MPS,
    MAX_HEIGHT_AGL_M,
    MIN_TIMING_SPEED_MPS,
    timing_usable,
    validate_sample,
)

__all__ = [
    "TelemetrySample",
    "TelemetryBuffer",
    "BufferStats",
    "ned_to_enu",
    "attitude_quaternion_enu",
    "course_from_velocity",
    "heading_from_quaternion_enu",
    "sample_from_enu",
    "validate_sample",
    "timing_usable",
    "enu_offset_m",
    "enu_to_latlon",
    "trajectory_through_fixes",
    "trajectory_straight",
    "WGS84_A",
    "WGS84_E2",
    "MAX_GROUND_SPEED_MPS",
    "MAX_HEIGHT_AGL_M",
    "MIN_TIMING_SPEED_MPS",
]
