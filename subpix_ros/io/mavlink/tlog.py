"""Telemetry logs (``.tlog``): MAVLink packets each behind an 8-byte POSIX timestamp."""

from __future__ import annotations

import math
import struct
from pathlib import Path
from typing import Iterable, Sequence

from subpix_ros.core.telemetry import TelemetrySample

from .encode import encode_samples

__all__ = ["write_tlog", "read_tlog_packets"]


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
    """Write a telemetry log (the MAVProxy/pymavlink ``.tlog`` format).

    Parameters
    ----------
    path : str or Path
        The file to write (its folder is created).
    samples : iterable of TelemetrySample, optional
        Samples to encode with :func:`encode_samples` (give these or ``packets``).
    system_id, component_id, heartbeat_hz, mavlink1
        As in :func:`encode_samples`.
    packets : sequence of (float, bytes), optional
        Ready packets with their POSIX times.

    Returns
    -------
    int
        The number of packets written.

    Notes
    -----
    Each packet is prefixed by its 8-byte big-endian POSIX timestamp in microseconds, written as
    mavutil does with the two low bits cleared (link id 0): resolution 4 us.
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
    """Read the raw (t, packet) pairs of a tlog written by :func:`write_tlog` (tests, tools).

    Parameters
    ----------
    path : str or Path
        The telemetry log.

    Returns
    -------
    list of (float, bytes)
        POSIX time (s) and one MAVLink frame (v1 or v2, its length from its header).

    Raises
    ------
    ValueError
        A malformed record.
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
