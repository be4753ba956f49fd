"""Per-frame metadata files: the ``frames.csv`` of GPS fixes and EXIF capture times.

The reading lives here (I/O); the trajectory through the fixes is computed by
:func:`subpix_ros.core.telemetry.trajectory_through_fixes` (pure numpy).
"""

from __future__ import annotations

import calendar
import csv
import math
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

import numpy as np

from subpix_ros.core.telemetry import TelemetrySample, trajectory_through_fixes

__all__ = ["FrameFixes", "exif_utc", "read_frames_csv", "trajectory_from_frames_csv"]

COLUMNS = ("datetime_original", "latitude_deg", "longitude_deg", "gps_altitude_m")


@dataclass(frozen=True)
class FrameFixes:
    """GPS fixes of the frames, one entry per row of the CSV, in file order."""

    t: np.ndarray  #: capture time, POSIX s (EXIF local time read as UTC)
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    alt_msl_m: np.ndarray
    names: tuple[str, ...]  #: the ``file`` column where present, else ""


def exif_utc(text: str) -> float:
    """POSIX time of an EXIF ``YYYY:MM:DD HH:MM:SS`` string, read as UTC."""
    try:
        dt = datetime.strptime(text.strip(), "%Y:%m:%d %H:%M:%S")
    except ValueError as exc:
        raise ValueError(f"bad EXIF datetime {text!r} (expected 'YYYY:MM:DD HH:MM:SS')") from exc
    return float(calendar.timegm(dt.timetuple()))


def read_frames_csv(csv_path: str | Path) -> FrameFixes:
    """Read the fixes of a ``frames.csv``.

    Parameters
    ----------
    csv_path : str or Path
        CSV with the columns ``datetime_original`` (EXIF), ``latitude_deg``,
        ``longitude_deg``, ``gps_altitude_m`` (and optionally ``file``).

    Returns
    -------
    FrameFixes
        The fixes in file order.
    """
    path = Path(csv_path)
    if not path.is_file():
        raise FileNotFoundError(f"frames CSV not found: {path}")
    with path.open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    if not rows or any(k not in rows[0] for k in COLUMNS):
        raise ValueError(f"{path}: expected columns {COLUMNS}")
    try:
        return FrameFixes(
            t=np.array([exif_utc(r["datetime_original"]) for r in rows]),
            lat_deg=np.array([float(r["latitude_deg"]) for r in rows]),
            lon_deg=np.array([float(r["longitude_deg"]) for r in rows]),
            alt_msl_m=np.array([float(r["gps_altitude_m"]) for r in rows]),
            names=tuple(r.get("file", "") or "" for r in rows),
        )
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from exc


def trajectory_from_frames_csv(
    csv_path: str | Path, ground_alt_m: float = 230.0, rate_hz: float = 10.0
) -> list[TelemetrySample]:
    """Build a smooth trajectory through the per-frame GPS fixes of a ``frames.csv``.

    Parameters
    ----------
    csv_path : str or Path
        The CSV (see :func:`read_frames_csv`).
    ground_alt_m : float
        Ground altitude, m (height above ground = GPS altitude - this).
    rate_hz : float
        Sample rate, Hz.

    Returns
    -------
    list of TelemetrySample
        See :func:`subpix_ros.core.telemetry.trajectory_through_fixes`.
    """
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise ValueError(f"rate_hz must be > 0, got {rate_hz}")
    fx = read_frames_csv(csv_path)
    try:
        return trajectory_through_fixes(
            fx.t, fx.lat_deg, fx.lon_deg, fx.alt_msl_m, ground_alt_m, rate_hz
        )
    except ValueError as exc:
        raise ValueError(f"{csv_path}: {exc}") from exc
