"""The MAVLink telemetry reader: a live link or a replayed ``.tlog`` as telemetry samples."""

from __future__ import annotations

import math
import threading
import time
from collections import Counter
from typing import Callable

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from subpix_ros.core.telemetry import (
    TelemetrySample,
    course_from_velocity,
    validate_sample,
)
from subpix_ros.core.telemetry.sample import FIX, GBAS_FIX, NO_FIX, SBAS_FIX

from .encode import UINT16_MAX
from .link import LinkEvent, ReaderStats, _open, parse_url

__all__ = ["MavlinkReader", "fix_status_from_fix_type"]


def fix_status_from_fix_type(fix_type: int) -> int:
    """Map MAVLink GPS_FIX_TYPE (GPS_RAW_INT.fix_type) to sensor_msgs/NavSatStatus ``status``.

    Parameters
    ----------
    fix_type : int
        0 no GPS, 1 no fix, 2 2D, 3 3D, 4 DGPS/SBAS, 5 RTK float, 6 RTK fixed, 7 static,
        8 PPP.

    Returns
    -------
    int
        STATUS_NO_FIX (-1) for 0-1, STATUS_FIX (0) for 2-3 and 7-8, STATUS_SBAS_FIX (1) for
        4, STATUS_GBAS_FIX (2) for RTK (5-6).

    Notes
    -----
    mavros (``global_position`` plugin, ``handle_gps_raw_int``) keeps only two levels:
    STATUS_FIX for fix_type > 2 and STATUS_NO_FIX otherwise, a 2D fix included; here a 2D
    fix is a fix (its latitude and longitude are measured; the height used is
    GLOBAL_POSITION_INT's relative_alt) and the augmented fixes say so.
    """
    if fix_type <= 1:
        return NO_FIX
    if fix_type == 4:
        return SBAS_FIX
    if fix_type in (5, 6):
        return GBAS_FIX
    return FIX


class MavlinkReader:
    """Read MAVLink telemetry on a background thread and emit TelemetrySamples.

    Parameters
    ----------
    url : str
        The link or log, see :func:`parse_url`.
    baud : int
        Serial baud rate when the URL gives none.
    system_id : int, optional
        The vehicle to track; None locks onto the first vehicle seen (any frame that is not
        from system 255 nor a GCS/gimbal/ADS-B/companion HEARTBEAT).
    link_timeout_s : float
        Silence after which the link is 'lost'.
    on_sample, on_status : callable, optional
        Called with each TelemetrySample / LinkEvent on the reader thread; exceptions they
        raise are counted, not propagated.
    on_packet : callable, optional
        Called with the message type of every MAVLink frame parsed with a good CRC (any
        system), on the reader thread: a link's liveness, whatever the frames hold.
    rate : float, optional
        Tlog replay speed (None: as fast as possible, 1.0: real time).
    attitude_max_age_s, vfr_max_age_s, gps_max_age_s : float
        How old the latest ATTITUDE (by time_boot_ms), VFR_HUD and GPS_RAW_INT (by receive
        time) may be to be combined with a GLOBAL_POSITION_INT.
    reboot_threshold_s : float
        A time_boot_ms this much earlier than the last is an autopilot reboot.
    poll_s : float
        Wait for data on a live link between checks.

    Notes
    -----
    A sample is emitted for every accepted GLOBAL_POSITION_INT of the tracked system, combined
    with the latest ATTITUDE (else the sample has no attitude) and VFR_HUD (its groundspeed,
    else the norm of vx, vy):

    * ``t``: the tlog timestamp when replaying a log, else the receive time;
    * lat/lon = 1e-7 * lat/lon, alt_msl = alt / 1000, height_agl = relative_alt / 1000 (flat
      terrain), vel_ned = (vx, vy, vz) / 100;
    * course = atan2(vy, vx) when the horizontal speed is >= 0.1 m/s, else the heading
      (ATTITUDE yaw, else GLOBAL_POSITION_INT hdg);
    * fix_status: STATUS_NO_FIX when lat and lon are both exactly 0 (the autopilot has no
      global position), else :func:`fix_status_from_fix_type` of the latest GPS_RAW_INT,
      else None (no GPS_RAW_INT: a fix);
    * time_boot_ms orders the stream: a repeated value is a duplicate, an earlier one is out
      of order (both rejected and counted), unless it is more than ``reboot_threshold_s``
      earlier (a reboot: accepted).

    Samples failing :func:`validate_sample` are rejected with a reason (counted in
    :attr:`stats`); bad bytes, bad CRCs, unknown messages and frames from other system ids are
    counted and skipped, never fatal.

    Link state: 'connected' at the first vehicle frame, 'lost' when no frame from it arrives
    for ``link_timeout_s``, 'restored' when frames return (live links: wall clock; tlog replay:
    gaps in the log's timestamps), and 'end_of_log' at the end of a tlog. On ``udpout:`` links
    a GCS HEARTBEAT is sent every second so the vehicle learns where to send.
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
        on_packet: Callable[[str], None] | None = None,
        rate: float | None = None,
        attitude_max_age_s: float = 0.5,
        vfr_max_age_s: float = 1.0,
        gps_max_age_s: float = 5.0,
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
        self.on_packet = on_packet
        self.rate = rate
        self.attitude_max_age_ms = attitude_max_age_s * 1000.0
        self.vfr_max_age_s = vfr_max_age_s
        self.gps_max_age_s = gps_max_age_s
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
        self._gps = None  # (t, fix_type, satellites_visible) of the latest GPS_RAW_INT
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
        # pymavlink counts the gaps in each sender's sequence numbers as it parses (mav_loss)
        s.packets_lost = int(getattr(self._conn, "mav_loss", 0) or 0)
        return s

    @property
    def link_state(self) -> str:
        """'waiting', 'connected', 'lost', 'restored' or 'end_of_log'."""
        return self._state

    @property
    def target_system(self) -> int | None:
        """System id of the vehicle being tracked (None until one is seen)."""
        return self._target

    @property
    def gps_raw(self) -> tuple[int, int] | None:
        """(fix_type, satellites_visible) of the latest GPS_RAW_INT, or None if none came."""
        gps = self._gps
        return None if gps is None else (gps[1], gps[2])

    @property
    def latest(self) -> TelemetrySample | None:
        """Latest accepted sample, or None."""
        return self._latest

    @property
    def events(self) -> list[LinkEvent]:
        """Link events so far (a copy)."""
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
        self._call("on_status", self.on_status, ev)

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
        self._call("on_packet", self.on_packet, mtype)
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
        elif mtype == "GPS_RAW_INT":
            self._gps = (t, int(msg.fix_type), int(msg.satellites_visible))
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
        gps = self._gps
        if msg.lat == 0 and msg.lon == 0:
            fix_status = NO_FIX
        elif gps is not None and 0.0 <= t - gps[0] <= self.gps_max_age_s:
            fix_status = fix_status_from_fix_type(gps[1])
        else:
            fix_status = None
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
            fix_status=fix_status,
        )
        ok, reason = validate_sample(sample)
        if not ok:
            self._reject(reason)
            return
        self._latest = sample
        with self._lock:
            self._stats.samples += 1
        self._call("on_sample", self.on_sample, sample)

    def _call(self, name: str, callback: Callable | None, arg) -> None:
        """Call a user callback on the reader thread; its exceptions are counted, not raised."""
        if callback is None:
            return
        try:
            callback(arg)
        except Exception as exc:  # noqa: BLE001 - a callback must not stop the reader
            with self._lock:
                self._stats.callback_errors += 1
                self._stats.last_error = f"{name}: {type(exc).__name__}: {exc}"
