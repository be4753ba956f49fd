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

import math
import os
import re
import struct
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable, Sequence

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from subpix_ros.core.telemetry import (
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
                boot_ms,
                float(s.roll_rad),
                float(s.pitch_rad),
                float(s.yaw_rad),
                0.0,
                0.0,
                0.0,  # type: ignore[arg-type]
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
            raise ValueError(
                f"sample t={s.t} is before boot_time={boot} or too late for time_boot_ms"
            )
        if heartbeat_hz > 0 and s.t >= next_hb:
            out.append((s.t, packer.pack(_heartbeat())))
            next_hb = (
                s.t + 1.0 / heartbeat_hz if next_hb == -math.inf else next_hb + 1.0 / heartbeat_hz
            )
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


# --------------------------------------------------------------------------- #
# Connection URLs
# --------------------------------------------------------------------------- #
@dataclass(frozen=True)
class ConnectionSpec:
    """A validated MAVLink endpoint.

    ``kind`` is one of 'udpin', 'udpout', 'tcp', 'tcpin', 'serial', 'tlog';
    ``address`` is 'host:port', a device path or a file path.
    """

    kind: str
    address: str
    baud: int | None = None

    @property
    def url(self) -> str:
        if self.kind in ("serial", "tlog"):
            return self.address
        return f"{self.kind}:{self.address}"


def _host_port(kind: str, rest: str, url: str) -> str:
    parts = rest.rsplit(":", 1)
    host, port_s = parts if len(parts) == 2 else ("", parts[0])
    host = host or "127.0.0.1"
    if not _HOST_RE.match(host):
        raise ValueError(f"bad host {host!r} in MAVLink URL {url!r}")
    try:
        port = int(port_s)
    except ValueError:
        raise ValueError(
            f"bad port {port_s!r} in MAVLink URL {url!r} (expected {kind}:HOST:PORT)"
        ) from None
    low = 0 if kind in ("udpin", "tcpin") else 1  # listeners may ask for an ephemeral port
    if not low <= port <= 65535:
        raise ValueError(f"port {port} out of range in MAVLink URL {url!r}")
    return f"{host}:{port}"


def parse_url(url: str, baud: int = 57600) -> ConnectionSpec:
    """Validate a pymavlink-style connection string (no shell, nothing executed).

    Accepted: ``udpin:[HOST:]PORT`` (listen; ``udp:`` is the same),
    ``udpout:[HOST:]PORT``, ``tcp:[HOST:]PORT`` (connect), ``tcpin:[HOST:]PORT``
    (listen), a serial device (``/dev/ttyUSB0``, ``/dev/ttyACM0,115200``,
    ``COM3``; the device must exist) and an existing telemetry log file
    (``.tlog``, ``.mavlink``, ``.raw``). HOST defaults to 127.0.0.1, so
    nothing listens on other interfaces unless the URL says so; listeners
    accept port 0 (ephemeral, see :attr:`MavlinkReader.local_address`).
    Raises ValueError (FileNotFoundError for a missing file/device).
    """
    if not isinstance(url, str) or not url.strip():
        raise ValueError("empty MAVLink URL")
    url = url.strip()
    m = re.match(r"^(udpin|udpout|udp|tcpin|tcp):(.*)$", url)
    if m:
        kind = "udpin" if m.group(1) == "udp" else m.group(1)
        return ConnectionSpec(kind, _host_port(kind, m.group(2), url))
    if re.match(r"^[A-Za-z][A-Za-z0-9+.\-]*://", url) or re.match(
        r"^(udpbcast|mcast|ws|wss|wsserver|uds|unix|csv):", url
    ):
        raise ValueError(
            f"unsupported MAVLink URL {url!r} (use udpin:, udpout:, tcp:, tcpin:, a serial device or a .tlog)"
        )
    dev, _, baud_s = url.partition(",")
    if dev.startswith("/dev/") or re.match(r"^COM\d+$", dev, re.IGNORECASE):
        if baud_s:
            try:
                baud = int(baud_s)
            except ValueError:
                raise ValueError(f"bad baud rate {baud_s!r} in {url!r}") from None
        if baud <= 0:
            raise ValueError(f"baud rate must be positive, got {baud}")
        if dev.startswith("/dev/") and not os.path.exists(dev):
            raise FileNotFoundError(f"serial device not found: {dev}")
        return ConnectionSpec("serial", dev, baud)
    path = Path(url)
    if path.suffix.lower() not in _TLOG_SUFFIXES:
        raise ValueError(
            f"unsupported MAVLink URL {url!r}: not udpin:/udpout:/tcp:/tcpin:, a serial device, "
            f"or a telemetry log ({', '.join(_TLOG_SUFFIXES)})"
        )
    if not path.is_file():
        raise FileNotFoundError(f"telemetry log not found: {path}")
    return ConnectionSpec("tlog", str(path))


def _open(spec: ConnectionSpec):
    """Open a pymavlink connection for ``spec`` with our own MAVLink 2 parser."""
    if spec.kind == "udpin":
        conn = mavutil.mavudp(spec.address, input=True)
    elif spec.kind == "udpout":
        conn = mavutil.mavudp(spec.address, input=False)
    elif spec.kind == "tcp":
        conn = mavutil.mavtcp(spec.address, autoreconnect=True)
    elif spec.kind == "tcpin":
        conn = mavutil.mavtcpin(spec.address)
    elif spec.kind == "serial":
        try:
            import serial  # noqa: F401  (pyserial, used by mavutil.mavserial)
        except ImportError:
            raise RuntimeError("serial MAVLink links need pyserial: pip install pyserial") from None
        conn = mavutil.mavserial(spec.address, baud=spec.baud or 57600, autoreconnect=True)
    elif spec.kind == "tlog":
        # mavlogfile directly: mavlink_connection() would *execute* some paths.
        conn = mavutil.mavlogfile(spec.address, robust_parsing=True)
    else:  # pragma: no cover - parse_url only returns the kinds above
        raise ValueError(f"unknown connection kind {spec.kind}")
    # Parse with the v2 'ardupilotmega' dialect whatever mavutil's global
    # dialect is (it accepts MAVLink 1 and 2 frames alike), robustly: bad
    # bytes become BAD_DATA messages instead of exceptions.
    conn.mav = mavlink2.MAVLink(
        conn, srcSystem=255, srcComponent=mavlink2.MAV_COMP_ID_MISSIONPLANNER
    )
    conn.mav.robust_parsing = True
    conn.first_byte = False  # no auto protocol switch replacing our parser
    conn.WIRE_PROTOCOL_VERSION = "2.0"
    return conn


# --------------------------------------------------------------------------- #
# Reader
# --------------------------------------------------------------------------- #
@dataclass(frozen=True)
class LinkEvent:
    """A link state change: state is 'connected', 'lost', 'restored' or 'end_of_log'.

    ``t`` is POSIX seconds: the log time for tlog replay, else wall time.
    """

    state: str
    t: float
    reason: str


@dataclass
class ReaderStats:
    """Counters of a :class:`MavlinkReader` (a snapshot from :attr:`MavlinkReader.stats`)."""

    packets: int = 0  # MAVLink frames parsed with a good CRC
    mavlink1: int = 0
    mavlink2: int = 0
    bad_crc: int = 0
    bad_data: int = 0  # other parse failures (garbage prefix, bad length, ...)
    garbage_bytes: int = 0
    unknown_messages: int = 0
    other_system: int = 0  # frames from other system ids, ignored
    heartbeats: int = 0
    samples: int = 0  # TelemetrySamples delivered
    rejected: int = 0  # GLOBAL_POSITION_INT not turned into a sample
    reject_reasons: dict = field(default_factory=dict)
    out_of_order: int = 0
    duplicates: int = 0
    reboots: int = 0
    link_losses: int = 0
    exceptions: int = 0
    callback_errors: int = 0
    last_error: str = ""
    last_reject: str = ""


class MavlinkReader:
    """Read MAVLink telemetry on a background thread and emit TelemetrySamples.

    ``url``: see :func:`parse_url`. A sample is emitted for every accepted
    GLOBAL_POSITION_INT of the tracked system, combined with the latest
    ATTITUDE (used if its time_boot_ms is within ``attitude_max_age_s``,
    else the sample has no attitude) and VFR_HUD (its groundspeed is used if
    received within ``vfr_max_age_s``, else the norm of vx, vy):

    * ``t``: the tlog timestamp when replaying a log, else the receive time;
    * lat/lon = 1e-7 * lat/lon, alt_msl = alt / 1000, height_agl =
      relative_alt / 1000 (flat terrain), vel_ned = (vx, vy, vz) / 100;
    * course = atan2(vy, vx) when the horizontal speed is >= 0.1 m/s, else
      the heading (ATTITUDE yaw, else GLOBAL_POSITION_INT hdg);
    * time_boot_ms orders the stream: a repeated value is a duplicate, an
      earlier one is out of order (both rejected and counted), unless it is
      more than ``reboot_threshold_s`` earlier (an autopilot reboot: accepted).

    Samples failing :func:`validate_sample` are rejected with a reason
    (counted in :attr:`stats`); bad bytes, bad CRCs, unknown messages and
    frames from other system ids are counted and skipped, never fatal.
    ``system_id=None`` locks onto the first vehicle seen (any frame that is
    not from system 255 nor a GCS/gimbal/ADS-B/companion HEARTBEAT).

    Link state: 'connected' at the first vehicle frame, 'lost' when no frame
    from it arrives for ``link_timeout_s``, 'restored' when frames return
    (live links: wall clock; tlog replay: gaps in the log's timestamps), and
    'end_of_log' at the end of a tlog. ``on_status(LinkEvent)`` and
    ``on_sample(TelemetrySample)`` are called on the reader thread;
    exceptions they raise are counted, not propagated.

    ``rate``: tlog replay speed (None = as fast as possible, 1.0 = real
    time). On ``udpout:`` links a GCS HEARTBEAT is sent every second so the
    vehicle learns where to send.
    """

    def __init__(
        self,
        url: str,
        *,
        baud: int = 57600,
        system_id: int | None = None,
        link_timeout_s: float = 2.0,
        on_sample: Callable[[TelemetrySample], None] | None = None,
        on_status: Callable[[LinkEvent], None] | None = None,
        rate: float | None = None,
        attitude_max_age_s: float = 0.5,
        vfr_max_age_s: float = 1.0,
        reboot_threshold_s: float = 10.0,
        poll_s: float = 0.05,
    ) -> None:
        self.spec = parse_url(url, baud)
        if system_id is not None and not 1 <= system_id <= 255:
            raise ValueError(f"system_id must be 1..255 or None, got {system_id}")
        if not (math.isfinite(link_timeout_s) and link_timeout_s > 0):
            raise ValueError(f"link_timeout_s must be > 0, got {link_timeout_s}")
        if rate is not None and not (math.isfinite(rate) and rate > 0):
            raise ValueError(f"rate must be None or > 0, got {rate}")
        if rate is not None and self.spec.kind != "tlog":
            raise ValueError("rate only applies to tlog replay")
        self.system_id = system_id
        self.link_timeout_s = float(link_timeout_s)
        self.on_sample = on_sample
        self.on_status = on_status
        self.rate = rate
        self.attitude_max_age_ms = attitude_max_age_s * 1000.0
        self.vfr_max_age_s = vfr_max_age_s
        self.reboot_threshold_ms = reboot_threshold_s * 1000.0
        self.poll_s = poll_s
        self._is_log = self.spec.kind == "tlog"
        self._conn = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._stats = ReaderStats()
        self._reasons: Counter = Counter()
        self._target: int | None = system_id
        self._state = "waiting"
        self._last_activity: float | None = None
        self._last_heartbeat: float | None = None
        self._attitude = None  # (time_boot_ms, roll, pitch, yaw)
        self._vfr = None  # (t, groundspeed)
        self._last_boot_ms: int | None = None
        self._latest: TelemetrySample | None = None
        self._events: list[LinkEvent] = []
        self._replay_origin: tuple[float, float] | None = None
        self._next_gcs_hb = 0.0

    # -- lifecycle ---------------------------------------------------------
    def start(self) -> "MavlinkReader":
        """Open the connection (errors raise here) and start the reader thread."""
        if self._thread is not None:
            raise RuntimeError("reader already started")
        self._conn = _open(self.spec)
        self._thread = threading.Thread(
            target=self._run, name=f"mavlink-reader[{self.spec.url}]", daemon=True
        )
        self._thread.start()
        return self

    def stop(self, timeout: float = 2.0) -> None:
        """Stop the thread (waits up to ``timeout`` s) and close the connection."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
        if self._conn is not None:
            try:
                self._conn.close()
            except Exception:  # noqa: BLE001 - closing a dead link must not raise
                pass

    def join(self, timeout: float | None = None) -> bool:
        """Wait for the thread to finish (tlog end); True if it has."""
        if self._thread is None:
            return True
        self._thread.join(timeout)
        return not self._thread.is_alive()

    def __enter__(self) -> "MavlinkReader":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    # -- state -------------------------------------------------------------
    @property
    def stats(self) -> ReaderStats:
        """A consistent snapshot of the counters."""
        with self._lock:
            s = ReaderStats(
                **{k: v for k, v in self._stats.__dict__.items() if k != "reject_reasons"}
            )
            s.reject_reasons = dict(self._reasons)
            return s

    @property
    def link_state(self) -> str:
        """'waiting', 'connected', 'lost', 'restored' or 'end_of_log'."""
        return self._state

    @property
    def target_system(self) -> int | None:
        return self._target

    @property
    def latest(self) -> TelemetrySample | None:
        return self._latest

    @property
    def events(self) -> list[LinkEvent]:
        with self._lock:
            return list(self._events)

    @property
    def local_address(self) -> tuple[str, int] | None:
        """Bound (host, port) of a udpin/tcpin listener (useful with port 0)."""
        if self._conn is None:
            return None
        port = self._conn.listen if self.spec.kind == "tcpin" else getattr(self._conn, "port", None)
        try:
            return port.getsockname()[:2] if port is not None else None
        except OSError:
            return None

    def last_heartbeat_age(self, now: float | None = None) -> float | None:
        """Seconds since the tracked vehicle's last HEARTBEAT (log time for tlogs)."""
        if self._last_heartbeat is None:
            return None
        ref = now if now is not None else (self._last_activity if self._is_log else time.time())
        return ref - self._last_heartbeat  # type: ignore[operator]

    # -- thread --------------------------------------------------------------
    def _run(self) -> None:
        idle = False
        while not self._stop.is_set():
            try:
                if self.spec.kind == "udpout":
                    self._gcs_heartbeat()
                msg = self._conn.recv_msg()  # type: ignore[union-attr]
            except Exception as exc:  # noqa: BLE001 - a reader thread must survive
                self._error(exc)
                if self._is_log:
                    break
                self._stop.wait(0.1)
                continue
            now = time.time()
            if msg is None:
                if self._is_log:
                    self._emit(
                        LinkEvent("end_of_log", self._last_activity or now, "end of telemetry log")
                    )
                    break
                self._check_link(now)
                try:
                    waited = time.monotonic()
                    ready = self._conn.select(self.poll_s)  # type: ignore[union-attr]
                    if ready and time.monotonic() - waited < 1e-3 and idle:
                        # Readable yet nothing parsed twice in a row: a closed
                        # TCP peer or a dead device. Do not spin.
                        self._stop.wait(self.poll_s)
                except Exception as exc:  # noqa: BLE001
                    self._error(exc)
                    self._stop.wait(self.poll_s)
                idle = True
                continue
            idle = False
            try:
                self._handle(msg, now)
            except Exception as exc:  # noqa: BLE001
                self._error(exc)
            if not self._is_log:
                self._check_link(now)

    def _error(self, exc: BaseException) -> None:
        with self._lock:
            self._stats.exceptions += 1
            self._stats.last_error = f"{type(exc).__name__}: {exc}"

    def _gcs_heartbeat(self) -> None:
        now = time.time()
        if now >= self._next_gcs_hb:
            self._next_gcs_hb = now + 1.0
            self._conn.mav.heartbeat_send(
                mavlink2.MAV_TYPE_GCS, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, 0
            )  # type: ignore[union-attr]

    def _emit(self, ev: LinkEvent) -> None:
        with self._lock:
            self._events.append(ev)
            if ev.state == "lost":
                self._stats.link_losses += 1
        self._state = ev.state
        if self.on_status is not None:
            try:
                self.on_status(ev)
            except Exception as exc:  # noqa: BLE001
                with self._lock:
                    self._stats.callback_errors += 1
                    self._stats.last_error = f"on_status: {type(exc).__name__}: {exc}"

    def _check_link(self, now: float) -> None:
        if self._state in ("connected", "restored") and self._last_activity is not None:
            if now - self._last_activity > self.link_timeout_s:
                self._emit(
                    LinkEvent(
                        "lost",
                        now,
                        f"no MAVLink from system {self._target} for {now - self._last_activity:.2f} s",
                    )
                )

    def _activity(self, t: float) -> None:
        last = self._last_activity
        if (
            self._is_log
            and last is not None
            and t - last > self.link_timeout_s
            and self._state != "lost"
        ):
            self._emit(
                LinkEvent(
                    "lost",
                    last + self.link_timeout_s,
                    f"no MAVLink from system {self._target} for {t - last:.2f} s in the log",
                )
            )
        self._last_activity = t
        if self._state == "waiting":
            self._emit(LinkEvent("connected", t, f"receiving system {self._target}"))
        elif self._state == "lost":
            self._emit(
                LinkEvent(
                    "restored",
                    t,
                    f"system {self._target} back after {t - last:.2f} s" if last else "restored",
                )
            )

    def _pace(self, t: float) -> None:
        if self.rate is None:
            return
        if self._replay_origin is None:
            self._replay_origin = (time.monotonic(), t)
        wall0, log0 = self._replay_origin
        while not self._stop.is_set():
            delay = wall0 + (t - log0) / self.rate - time.monotonic()
            if delay <= 0:
                return
            self._stop.wait(min(delay, 0.1))

    @staticmethod
    def _is_vehicle(msg) -> bool:
        if msg.get_srcSystem() in (0, 255):
            return False
        if msg.get_type() == "HEARTBEAT":
            return msg.type not in (
                mavlink2.MAV_TYPE_GCS,
                mavlink2.MAV_TYPE_GIMBAL,
                mavlink2.MAV_TYPE_ADSB,
                mavlink2.MAV_TYPE_ONBOARD_CONTROLLER,
            )
        return True

    def _handle(self, msg, recv_time: float) -> None:
        mtype = msg.get_type()
        if mtype == "BAD_DATA":
            reason = str(getattr(msg, "reason", ""))
            with self._lock:
                if "CRC" in reason:
                    self._stats.bad_crc += 1
                else:
                    self._stats.bad_data += 1
                    self._stats.garbage_bytes += len(getattr(msg, "data", b""))
            return
        t = float(msg._timestamp) if self._is_log else recv_time
        if self._is_log:
            self._pace(t)
        buf = msg.get_msgbuf()
        with self._lock:
            self._stats.packets += 1
            if buf and buf[0] == mavlink2.PROTOCOL_MARKER_V1:
                self._stats.mavlink1 += 1
            else:
                self._stats.mavlink2 += 1
            if msg.get_msgId() < 0 or mtype.startswith("UNKNOWN"):
                self._stats.unknown_messages += 1
        sysid = msg.get_srcSystem()
        if self._target is None and self._is_vehicle(msg):
            self._target = sysid
        if sysid != self._target:
            with self._lock:
                self._stats.other_system += 1
            return
        self._activity(t)
        if mtype == "HEARTBEAT":
            self._last_heartbeat = t
            with self._lock:
                self._stats.heartbeats += 1
        elif mtype == "ATTITUDE":
            self._attitude = (msg.time_boot_ms, msg.roll, msg.pitch, msg.yaw)
        elif mtype == "VFR_HUD":
            self._vfr = (t, msg.groundspeed)
        elif mtype == "GLOBAL_POSITION_INT":
            self._position(msg, t, sysid)

    def _reject(self, reason: str) -> None:
        with self._lock:
            self._stats.rejected += 1
            self._stats.last_reject = reason
            self._reasons[reason.split(" (")[0]] += 1

    def _position(self, msg, t: float, sysid: int) -> None:
        tb = int(msg.time_boot_ms)
        last = self._last_boot_ms
        if last is not None:
            if tb == last:
                with self._lock:
                    self._stats.duplicates += 1
                self._reject(f"duplicate time_boot_ms ({tb})")
                return
            if tb < last:
                if last - tb <= self.reboot_threshold_ms:
                    with self._lock:
                        self._stats.out_of_order += 1
                    self._reject(f"out-of-order time_boot_ms ({tb} < {last})")
                    return
                with self._lock:
                    self._stats.reboots += 1
                self._attitude = None
        self._last_boot_ms = tb
        vn, ve, vd = msg.vx / 100.0, msg.vy / 100.0, msg.vz / 100.0
        att = self._attitude
        if att is not None and abs(att[0] - tb) > self.attitude_max_age_ms:
            att = None
        roll, pitch, yaw = (att[1], att[2], att[3]) if att is not None else (None, None, None)
        vfr = self._vfr
        if vfr is not None and 0.0 <= t - vfr[0] <= self.vfr_max_age_s:
            ground_speed = float(vfr[1])
        else:
            ground_speed = math.hypot(vn, ve)
        if math.hypot(vn, ve) >= 0.1:
            course = course_from_velocity(vn, ve)
        elif yaw is not None and math.isfinite(yaw):
            course = float(yaw) % (2 * math.pi)
        elif msg.hdg != UINT16_MAX:
            course = math.radians(msg.hdg / 100.0) % (2 * math.pi)
        else:
            course = course_from_velocity(vn, ve)
        sample = TelemetrySample(
            t=t,
            lat_deg=msg.lat / 1e7,
            lon_deg=msg.lon / 1e7,
            alt_msl_m=msg.alt / 1000.0,
            height_agl_m=msg.relative_alt / 1000.0,
            vel_ned_mps=(vn, ve, vd),
            ground_speed_mps=ground_speed,
            course_rad=course,
            roll_rad=roll,
            pitch_rad=pitch,
            yaw_rad=yaw,
            time_boot_ms=tb,
            system_id=sysid,
        )
        ok, reason = validate_sample(sample)
        if not ok:
            self._reject(reason)
            return
        self._latest = sample
        with self._lock:
            self._stats.samples += 1
        if self.on_sample is not None:
            try:
                self.on_sample(sample)
            except Exception as exc:  # noqa: BLE001
                with self._lock:
                    self._stats.callback_errors += 1
                    self._stats.last_error = f"on_sample: {type(exc).__name__}: {exc}"


# --------------------------------------------------------------------------- #
# Sender
# --------------------------------------------------------------------------- #
class MavlinkSender:
    """Send raw MAVLink packets over UDP (``udpout:[HOST:]PORT``, host default 127.0.0.1)."""

    def __init__(self, url: str) -> None:
        spec = parse_url(url)
        if spec.kind != "udpout":
            raise ValueError(f"MavlinkSender sends over udpout: only, got {url!r}")
        self.spec = spec
        self._conn = mavutil.mavudp(spec.address, input=False)
        self.sent = 0

    def send(self, packet: bytes) -> None:
        """Send one datagram (a packet, several packets or any bytes)."""
        self._conn.write(bytes(packet))
        self.sent += 1

    def send_packets(
        self,
        packets: Sequence[tuple[float, bytes]],
        rate: float | None = None,
        stop: threading.Event | None = None,
    ) -> int:
        """Send (t, bytes) packets in order, paced by ``t`` at ``rate`` x real time (None: no pacing)."""
        if not packets:
            return 0
        wall0, t0 = time.monotonic(), packets[0][0]
        n = 0
        for t, buf in packets:
            if stop is not None and stop.is_set():
                break
            if rate is not None:
                delay = wall0 + (t - t0) / rate - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
            self.send(buf)
            n += 1
        return n

    def close(self) -> None:
        self._conn.close()

    def __enter__(self) -> "MavlinkSender":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
