"""MAVLink endpoints: URL validation, opening a connection, link events, the UDP sender."""

from __future__ import annotations

import os
import re
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

__all__ = [
    "ConnectionSpec",
    "parse_url",
    "LinkEvent",
    "ReaderStats",
    "MavlinkSender",
    "LinkLoss",
]

_TLOG_SUFFIXES = (".tlog", ".mavlink", ".raw")
_HOST_RE = re.compile(r"^[A-Za-z0-9.\-]+$")


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
        """Return the URL as pymavlink takes it."""
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

    Parameters
    ----------
    url : str
        ``udpin:[HOST:]PORT`` (listen; ``udp:`` is the same), ``udpout:[HOST:]PORT``,
        ``tcp:[HOST:]PORT`` (connect), ``tcpin:[HOST:]PORT`` (listen), a serial device
        (``/dev/ttyUSB0``, ``/dev/ttyACM0,115200``, ``COM3``; the device must exist) or an
        existing telemetry log (``.tlog``, ``.mavlink``, ``.raw``). HOST defaults to 127.0.0.1,
        so nothing listens on other interfaces unless the URL says so; listeners accept port 0
        (ephemeral, see :attr:`MavlinkReader.local_address`).
    baud : int
        Serial baud rate when the URL gives none.

    Returns
    -------
    ConnectionSpec
        The validated endpoint.

    Raises
    ------
    ValueError
        An unsupported or malformed URL.
    FileNotFoundError
        A missing telemetry log or serial device.
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
    packets_lost: int = 0  # frames missing from the senders' sequence numbers (pymavlink's count)
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


class LinkLoss:
    """The share of MAVLink frames a link lost over the last ``window_s`` seconds.

    Parameters
    ----------
    window_s : float
        The window, s.
    min_frames : int
        Fewer frames than this (received and lost) in the window give no figure: a handful of
        frames says nothing about the link.

    Notes
    -----
    ``loss = lost / (received + lost)`` over the window, from the reader's cumulative counters
    (:class:`ReaderStats` ``packets`` and ``packets_lost``, the gaps in the senders' sequence
    numbers). A frame that arrives out of order counts as a gap of up to 255 frames (the
    sequence number wraps at 256); such a link is in trouble anyway.
    """

    #: A link that lost more than this share of its frames is a problem (``telemetry_node``'s
    #: warning, ``subpix process``'s note on a ``.tlog``): a judgement, telemetry radios in use
    #: commonly lose a few per cent.
    WARN_ABOVE = 0.2

    def __init__(self, window_s: float = 10.0, min_frames: int = 50) -> None:
        self.window_s = float(window_s)
        self.min_frames = int(min_frames)
        self._history: list[tuple[float, int, int]] = []

    def add(self, now: float, received: int, lost: int) -> float | None:
        """Record the counters at ``now`` (s); return the loss over the window, or None."""
        self._history.append((now, int(received), int(lost)))
        while len(self._history) > 1 and now - self._history[1][0] >= self.window_s:
            self._history.pop(0)
        t0, r0, l0 = self._history[0]
        d_received, d_lost = int(received) - r0, int(lost) - l0
        if d_received < 0 or d_lost < 0:  # counters restarted (a new connection)
            self._history = [(now, int(received), int(lost))]
            return None
        if d_received + d_lost < self.min_frames:
            return None
        return self.share(d_received, d_lost)

    @staticmethod
    def share(received: int, lost: int) -> float:
        """Return ``lost / (received + lost)``, 0 when nothing was sent."""
        sent = received + lost
        return lost / sent if sent else 0.0


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
        """Close the UDP socket."""
        self._conn.close()

    def __enter__(self) -> "MavlinkSender":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
