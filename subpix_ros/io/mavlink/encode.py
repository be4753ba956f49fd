"""MAVLink 2 packets for :class:`TelemetrySample` sequences (ArduPilot 'ardupilotmega' dialect).

Units on the wire (MAVLink common.xml): GLOBAL_POSITION_INT lat/lon in 1e-7 deg, alt (MSL) and
relative_alt in mm, vx/vy/vz in cm/s NED, hdg in centidegrees (UINT16_MAX = unknown); VFR_HUD
groundspeed m/s, heading deg, alt m MSL, climb m/s up; ATTITUDE roll/pitch/yaw rad (NED/FRD).
"""

from __future__ import annotations

import math
from typing import Iterable

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from subpix_ros.core.telemetry import TelemetrySample

__all__ = ["DIALECT", "UINT16_MAX", "encode_samples"]

#: Dialect used to parse and build packets (superset of 'common').
DIALECT = "ardupilotmega"

UINT16_MAX = 65535


def _int_field(name: str, value: float, bits: int) -> int:
    """Round ``value`` for a signed ``bits``-bit MAVLink field; ValueError if it cannot hold it."""
    if not math.isfinite(value):
        raise ValueError(f"cannot encode non-finite {name} ({value}) as an integer MAVLink field")
    rounded = int(round(value))
    if not -(2 ** (bits - 1)) <= rounded < 2 ** (bits - 1):
        raise ValueError(f"{name}={value} does not fit the int{bits} MAVLink field")
    return rounded


def _i32(name: str, value: float) -> int:
    """Round ``value`` for an int32 field."""
    return _int_field(name, value, 32)


def _i16(name: str, value: float) -> int:
    """Round ``value`` for an int16 field."""
    return _int_field(name, value, 16)


def _cdeg(angle_rad: float | None) -> int:
    """Angle (rad, clockwise from north) as MAVLink centidegrees 0..35999, or UINT16_MAX."""
    if angle_rad is None or not math.isfinite(angle_rad):
        return UINT16_MAX
    return int(round(math.degrees(angle_rad) % 360.0 * 100.0)) % 36000


def _messages_for(sample: TelemetrySample, boot_ms: int) -> list:
    """ATTITUDE, VFR_HUD and GLOBAL_POSITION_INT for one sample (in send order).

    GLOBAL_POSITION_INT goes last: the reader emits a sample on it, combining
    the ATTITUDE and VFR_HUD just received. Fields MAVLink needs but the
    sample does not define: airspeed = ground speed (no wind model), throttle
    0, body rates 0.
    """
    heading = sample.yaw_rad if sample.yaw_rad is not None else sample.course_rad
    msgs = []
    if sample.has_attitude:
        msgs.append(
            mavlink2.MAVLink_attitude_message(
                boot_ms,
                float(sample.roll_rad),
                float(sample.pitch_rad),
                float(sample.yaw_rad),
                0.0,
                0.0,
                0.0,  # type: ignore[arg-type]
            )
        )
    vn, ve, vd = (float(x) for x in sample.vel_ned_mps)
    msgs.append(
        mavlink2.MAVLink_vfr_hud_message(
            float(sample.ground_speed_mps),
            float(sample.ground_speed_mps),
            _cdeg(heading) // 100 if _cdeg(heading) != UINT16_MAX else 0,
            0,
            float(sample.alt_msl_m),
            -vd,
        )
    )
    msgs.append(
        mavlink2.MAVLink_global_position_int_message(
            boot_ms,
            _i32("lat", sample.lat_deg * 1e7),
            _i32("lon", sample.lon_deg * 1e7),
            _i32("alt", sample.alt_msl_m * 1000.0),
            _i32("relative_alt", sample.height_agl_m * 1000.0),
            _i16("vx", vn * 100.0),
            _i16("vy", ve * 100.0),
            _i16("vz", vd * 100.0),
            _cdeg(sample.yaw_rad),
        )
    )
    return msgs


def _heartbeat() -> "mavlink2.MAVLink_heartbeat_message":
    return mavlink2.MAVLink_heartbeat_message(
        mavlink2.MAV_TYPE_QUADROTOR,
        mavlink2.MAV_AUTOPILOT_GENERIC,
        mavlink2.MAV_MODE_FLAG_SAFETY_ARMED | mavlink2.MAV_MODE_FLAG_AUTO_ENABLED,
        0,
        mavlink2.MAV_STATE_ACTIVE,
        3,
    )


class _Packer:
    """Packs messages with one sequence counter (the wire ``seq`` field)."""

    def __init__(self, system_id: int, component_id: int, mavlink1: bool = False) -> None:
        if not (1 <= system_id <= 255 and 0 <= component_id <= 255):
            raise ValueError(
                f"system_id must be 1..255 and component_id 0..255, got {system_id}, {component_id}"
            )
        self.mav = mavlink2.MAVLink(None, srcSystem=system_id, srcComponent=component_id)
        self.mavlink1 = mavlink1

    def pack(self, msg) -> bytes:
        buf = msg.pack(self.mav, force_mavlink1=self.mavlink1)
        self.mav.seq = (self.mav.seq + 1) % 256
        return bytes(buf)


def encode_samples(
    samples: Iterable[TelemetrySample],
    system_id: int = 1,
    component_id: int = 1,
    heartbeat_hz: float = 1.0,
    *,
    boot_time: float | None = None,
    mavlink1: bool = False,
) -> list[tuple[float, bytes]]:
    """Encode ``samples`` as MAVLink packets.

    Parameters
    ----------
    samples : iterable of TelemetrySample
        The samples, in time order.
    system_id, component_id : int
        The sender's ids (1..255 and 0..255).
    heartbeat_hz : float
        HEARTBEAT rate (quadrotor, generic autopilot): at the first sample and then every
        ``1/heartbeat_hz`` s; none if 0.
    boot_time : float, optional
        POSIX time of the autopilot's boot (default: the first sample's time);
        ``time_boot_ms = round((t - boot_time) * 1000)``.
    mavlink1 : bool
        MAVLink 1 framing instead of MAVLink 2.

    Returns
    -------
    list of (float, bytes)
        (send time, packet bytes). Per sample, in order: HEARTBEAT when due, ATTITUDE (when the
        sample has attitude), VFR_HUD, GLOBAL_POSITION_INT, each stamped with the sample time.

    Raises
    ------
    ValueError
        A value a MAVLink field cannot hold (NaN in an integer field, int16 velocity beyond
        +-327 m/s, ...).
    """
    samples = list(samples)
    if not samples:
        return []
    if heartbeat_hz < 0 or not math.isfinite(heartbeat_hz):
        raise ValueError(f"heartbeat_hz must be >= 0, got {heartbeat_hz}")
    packer = _Packer(system_id, component_id, mavlink1)
    boot = samples[0].t if boot_time is None else float(boot_time)
    out: list[tuple[float, bytes]] = []
    next_hb = -math.inf
    for sample in samples:
        boot_ms = int(round((sample.t - boot) * 1000.0))
        if not 0 <= boot_ms < 2**32:
            raise ValueError(
                f"sample t={sample.t} is before boot_time={boot} or too late for time_boot_ms"
            )
        if heartbeat_hz > 0 and sample.t >= next_hb:
            out.append((sample.t, packer.pack(_heartbeat())))
            next_hb = (
                sample.t + 1.0 / heartbeat_hz
                if next_hb == -math.inf
                else next_hb + 1.0 / heartbeat_hz
            )
            if next_hb <= sample.t:  # a gap in the samples: restart the heartbeat clock
                next_hb = sample.t + 1.0 / heartbeat_hz
        for msg in _messages_for(sample, boot_ms):
            out.append((sample.t, packer.pack(msg)))
    return out
