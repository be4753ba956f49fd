"""MAVLink telemetry in and out (pymavlink, MAVLink 2, 'ardupilotmega' dialect).

* :func:`encode_samples` / :func:`write_tlog` turn :class:`TelemetrySample`
  sequences into real MAVLink packets (HEARTBEAT, ATTITUDE, VFR_HUD,
  GLOBAL_POSITION_INT) and ``.tlog`` files that MAVProxy, QGroundControl and
  ``mavutil.mavlink_connection`` read.
* :class:`MavlinkReader` reads a live link (UDP, TCP, serial) or replays a
  ``.tlog`` on its own thread and turns the message stream back into
  :class:`TelemetrySample` objects, with heartbeat/link-loss detection and
  statistics about everything it had to ignore.
* :class:`MavlinkSender` sends encoded packets over UDP (tests, demos).

Units on the wire (MAVLink common.xml): GLOBAL_POSITION_INT lat/lon in
1e-7 deg, alt (MSL) and relative_alt in mm, vx/vy/vz in cm/s NED, hdg in
centidegrees (UINT16_MAX = unknown); VFR_HUD groundspeed m/s, heading deg,
alt m MSL, climb m/s up; ATTITUDE roll/pitch/yaw rad (NED/FRD).

``relative_alt`` (height above home) is used as height above ground: the
flat-terrain assumption of METHODS.md B. Both the reader's and the
encoder's network endpoints default to 127.0.0.1 when the URL omits the
host (``udpin:14550`` binds 127.0.0.1:14550); give an explicit host such as
``udpin:0.0.0.0:14550`` to listen on all interfaces.
"""
from __future__ import annotations

import os

os.environ.setdefault("MAVLINK20", "1")

import math  # noqa: E402
import re  # noqa: E402
import struct  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402
from collections import Counter  # noqa: E402
from dataclasses import dataclass, field  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Callable, Iterable, Sequence  # noqa: E402

from pymavlink import mavutil  # noqa: E402
from pymavlink.dialects.v20 import ardupilotmega as mavlink2  # noqa: E402

from subpix_ros.core.telemetry import (  # noqa: E402
    TelemetrySample,
    course_from_velocity,
    validate_sample,
)

__all__ = [
    "DIALECT",
    "encode_samples",
    "write_tlog",
    "read_tlog_packets",
    "parse_url",
    "ConnectionSpec",
    "LinkEvent",
    "ReaderStats",
    "MavlinkReader",
    "MavlinkSender",
]

#: Dialect used to parse and build packets (superset of 'common').
DIALECT = "ardupilotmega"

UINT16_MAX = 65535
_TLOG_SUFFIXES = (".tlog", ".mavlink", ".raw")
_HOST_RE = re.compile(r"^[A-Za-z0-9.\-]+$")


# --------------------------------------------------------------------------- #
# Encoding
# --------------------------------------------------------------------------- #
def _i32(name: str, value: float) -> int:
    if not math.isfinite(value):
        raise ValueError(f"cannot encode non-finite {name} ({value}) as an integer MAVLink field")
    v = int(round(value))
    if not -(2**31) <= v < 2**31:
        raise ValueError(f"{name}={value} does not fit the int32 MAVLink field")
    return v


def _i16(name: str, value: float) -> int:
    if not math.isfinite(value):
        raise ValueError(f"cannot encode non-finite {name} ({value}) as an integer MAVLink field")
    v = int(round(value))
    if not -(2**15) <= v < 2**15:
        raise ValueError(f"{name}={value} does not fit the int16 MAVLink field")
    return v


def _cdeg(angle_rad: float | None) -> int:
    """Angle (rad, clockwise from north) as MAVLink centidegrees 0..35999, or UINT16_MAX."""
    if angle_rad is None or not math.isfinite(angle_rad):
        return UINT16_MAX
    return int(round(math.degrees(angle_rad) % 360.0 * 100.0)) % 36000


def _messages_for(s: TelemetrySample, boot_ms: int) -> list:
    """ATTITUDE, VFR_HUD and GLOBAL_POSITION_INT for one sample (in send order).

    GLOBAL_POSITION_INT goes last: the reader emits a sample on it, combining
    the ATTITUDE and VFR_HUD just received. Fields MAVLink needs but the
    sample does not define: airspeed = ground speed (no wind model), throttle
    0, body rates 0.
    """
    heading = s.yaw_rad if s.yaw_rad is not None else s.course_rad
    msgs = []
    if s.has_attitude:
        msgs.append(
            mavlink2.MAVLink_attitude_message(
                boot_ms, float(s.roll_rad), float(s.pitch_rad), float(s.yaw_rad), 0.0, 0.0, 0.0  # type: ignore[arg-type]
            )
        )
    vn, ve, vd = (float(x) for x in s.vel_ned_mps)
    msgs.append(
        mavlink2.MAVLink_vfr_hud_message(
            float(s.ground_speed_mps),
            float(s.ground_speed_mps),
            _cdeg(heading) // 100 if _cdeg(heading) != UINT16_MAX else 0,
            0,
            float(s.alt_msl_m),
            -vd,
        )
    )
    msgs.append(
        mavlink2.MAVLink_global_position_int_message(
            boot_ms,
            _i32("lat", s.lat_deg * 1e7),
            _i32("lon", s.lon_deg * 1e7),
            _i32("alt", s.alt_msl_m * 1000.0),
            _i32("relative_alt", s.height_agl_m * 1000.0),
            _i16("vx", vn * 100.0),
            _i16("vy", ve * 100.0),
            _i16("vz", vd * 100.0),
            _cdeg(s.yaw_rad),
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
            raise ValueError(f"system_id must be 1..255 and component_id 0..255, got {system_id}, {component_id}")
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
    """MAVLink packets for ``samples``: a list of (send time, packet bytes).

    Per sample, in order: HEARTBEAT (quadrotor, generic autopilot; the first
    sample and then every ``1/heartbeat_hz`` s, none if ``heartbeat_hz`` is
    0), ATTITUDE (when the sample has attitude), VFR_HUD,
    GLOBAL_POSITION_INT, each stamped with the sample time ``t``.
    ``time_boot_ms = round((t - boot_time) * 1000)``, ``boot_time`` defaulting
    to the first sample's time. MAVLink 2 framing unless ``mavlink1``.
    Raises ValueError for values a MAVLink field cannot hold (NaN in an
    integer field, int16 velocity overflow beyond +-327 m/s, ...).
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
    for s in samples:
        boot_ms = int(round((s.t - boot) * 1000.0))
        if not 0 <= boot_ms < 2**32:
            raise ValueError(f"sample t={s.t} is before boot_time={boot} or too late for time_boot_ms")
        if heartbeat_hz > 0 and s.t >= next_hb:
            out.append((s.t, packer.pack(_heartbeat())))
            next_hb = s.t + 1.0 / heartbeat_hz if next_hb == -math.inf else next_hb + 1.0 / heartbeat_hz
            if next_hb <= s.t:  # a gap in the samples: restart the heartbeat clock
                next_hb = s.t + 1.0 / heartbeat_hz
        for msg in _messages_for(s, boot_ms):
            out.append((s.t, packer.pack(msg)))
    return out


def _tlog_usec(t: float) -> int:
    """Tlog timestamp: POSIX microseconds, low 2 bits = link id 0 (as mavutil writes)."""
    if not (math.isfinite(t) and t >= 0):
        raise ValueError(f"tlog timestamps must be finite and >= 0, got {t}")
    return int(round(t * 1e6)) & ~3


def write_tlog(
    path: str | Path,
    samples: Iterable[TelemetrySample] | None = None,
    system_id: int = 1,
    component_id: int = 1,
    heartbeat_hz: float = 1.0,
    *,
    packets: Sequence[tuple[float, bytes]] | None = None,
    mavlink1: bool = False,
) -> int:
    """Write a telemetry log: each packet prefixed by its 8-byte big-endian
    POSIX timestamp in microseconds (the MAVProxy/pymavlink ``.tlog`` format).

    Give ``samples`` (encoded with :func:`encode_samples`) or ready
    ``packets`` [(t, bytes)]. Timestamps are written as mavutil does, with the
    two low bits cleared (link id 0): resolution 4 us. Returns the number of
    packets written.
    """
    if (samples is None) == (packets is None):
        raise ValueError("give exactly one of samples or packets")
    if packets is None:
        packets = encode_samples(samples, system_id, component_id, heartbeat_hz, mavlink1=mavlink1)  # type: ignore[arg-type]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("wb") as fh:
        for t, buf in packets:
            fh.write(struct.pack(">Q", _tlog_usec(t)) + bytes(buf))
    return len(packets)


def read_tlog_packets(path: str | Path) -> list[tuple[float, bytes]]:
    """Raw (t, packet) pairs of a tlog written by :func:`write_tlog` (for tests/tools).

    Parses each record as 8-byte timestamp + one MAVLink frame (v1 or v2,
    length from its header); raises ValueError on a malformed record.
    """
    data = Path(path).read_bytes()
    out, i = [], 0
    while i < len(data):
        if i + 8 + 3 > len(data):
            raise ValueError(f"truncated tlog record at byte {i}")
        (usec,) = struct.unpack(">Q", data[i : i + 8])
        magic, plen = data[i + 8], data[i + 9]
        if magic == 0xFD:
            n = 10 + plen + 2 + (13 if data[i + 10] & 1 else 0)
        elif magic == 0xFE:
            n = 6 + plen + 2
        else:
            raise ValueError(f"no MAVLink frame at byte {i + 8} (magic 0x{magic:02x})")
        out.append((usec * 1e-6, data[i + 8 : i + 8 + n]))
        i += 8 + n
    return out
