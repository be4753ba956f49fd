"""Rows of ``shifts.csv``, ``frames.csv`` and ``telemetry.csv``, with the telemetry's expectations.

The expected shift over a frame pair is METHODS eq. 1 integrated over the interval:

    u_exp = s dt cos(course - heading),  v_exp = -s dt sin(course - heading),
    s = f V / (H a),  dt = t_frame - t_reference

(rows, columns; compass angles; ``heading`` = vehicle yaw + the camera's yaw offset:
:func:`subpix_ros.core.timing.expected_shift_px`).
"""

from __future__ import annotations

import math

import numpy as np

from subpix_ros.core.telemetry import TelemetryBuffer, TelemetrySample
from subpix_ros.core.timing import expected_shift_px, frame_interval
from subpix_ros.process.collector import _Collector
from subpix_ros.process.products import rounded

DIAGNOSTICS_PERIOD_NS = 1_000_000_000
SHIFT_COLUMNS = (
    "stamp_ns",
    "reference_stamp_ns",
    "u_px",
    "v_px",
    "u_std_px",
    "v_std_px",
    "converged",
    "reason",
    "u_total_px",
    "v_total_px",
    "u_expected_px",
    "v_expected_px",
    "u_residual_px",
    "v_residual_px",
)
FRAME_COLUMNS = (
    "index",
    "stamp_ns",
    "status",
    "reason",
    "reference_stamp_ns",
    "inliers",
    "rms_px",
    "rms_along_px",
    "rms_cross_px",
    "tracked",
    "mosaic",
)
TELEMETRY_COLUMNS = (
    "t_s",
    "lat_deg",
    "lon_deg",
    "alt_msl_m",
    "height_agl_m",
    "ground_speed_mps",
    "course_deg",
    "heading_deg",
)


def _shape_text(shape) -> str:
    dims, dtype = shape
    hw = f"{dims[1]}x{dims[0]}"
    ch = "" if len(dims) == 2 else f"x{dims[2]}"
    return f"{hw}{ch} {dtype}"


def _image_rate(buf: TelemetryBuffer, t: float, rp: dict) -> tuple[float, float] | None:
    s, _ = buf.at(t + float(rp["telemetry_time_offset_s"]))
    if s is None or s.ground_speed_mps < float(rp["min_speed_mps"]) or s.height_agl_m <= 0:
        return None
    heading = (s.yaw_rad if s.yaw_rad is not None else s.course_rad) + math.radians(
        float(rp["camera_yaw_offset_deg"])
    )
    try:
        return expected_shift_px(
            s.ground_speed_mps,
            s.course_rad,
            s.height_agl_m,
            float(rp["focal_length_mm"]) * 1e-3,
            float(rp["pixel_pitch_um"]) * 1e-6,
            1.0,
            heading,
        )
    except ValueError:
        return None


def _interval_at(buf: TelemetryBuffer, t: float, rp: dict) -> float | None:
    s, _ = buf.at(t + float(rp["telemetry_time_offset_s"]))
    if s is None:
        return None
    iv = frame_interval(
        float(rp["pixel_pitch_um"]) * 1e-6,
        s.height_agl_m,
        float(rp["focal_length_mm"]) * 1e-3,
        s.ground_speed_mps,
        float(rp["p"]),
    )
    return iv.interval_s if iv.ok else None


def _shift_rows(col: _Collector, buf: TelemetryBuffer, rp: dict) -> list[dict]:
    rows = []
    for stamp in sorted(col.shifts):
        row = dict(col.shifts[stamp])
        ref = row.get("reference_stamp_ns")
        h = col.homographies.get(stamp)
        prior = col.priors.get(stamp)
        if h is not None and row.get("converged"):
            total = _total_shift(h, prior, row["u_px"], row["v_px"], col.shape)
            if total is not None:
                row["u_total_px"], row["v_total_px"] = rounded(total[0]), rounded(total[1])
        if ref is not None and len(buf):
            t_ref, t = ref * 1e-9, stamp * 1e-9
            r0, r1 = _image_rate(buf, t_ref, rp), _image_rate(buf, t, rp)
            if (
                r0 is not None and r1 is not None
            ):  # mean image velocity over the interval (trapezoid)
                dt = t - t_ref
                row["u_expected_px"] = rounded(0.5 * (r0[0] + r1[0]) * dt)
                row["v_expected_px"] = rounded(0.5 * (r0[1] + r1[1]) * dt)
                if "u_total_px" in row:  # from the rounded values: the same digits in every process
                    row["u_residual_px"] = rounded(row["u_total_px"] - row["u_expected_px"])
                    row["v_residual_px"] = rounded(row["v_total_px"] - row["v_expected_px"])
        rows.append(row)
    return rows


def _total_shift(h: np.ndarray, prior, u: float, v: float, shape) -> tuple[float, float] | None:
    """Whole-pixel part of the homography's shift plus the estimated sub-pixel part (rows, cols).

    The homography maps moving-frame px to reference px, so the reference's
    centre ``c`` appears at ``H^-1 c`` in the moving frame; the aligned frame
    keeps ``prior`` of that displacement (the sub-pixel remainder), which the
    shift stage measures as (u, v).
    """
    try:
        hi = np.linalg.inv(h)
    except np.linalg.LinAlgError:
        return None
    cy, cx = (shape[0] - 1) / 2.0, (shape[1] - 1) / 2.0
    q = hi @ np.array([cx, cy, 1.0])
    if abs(q[2]) < 1e-12:
        return None
    dx, dy = q[0] / q[2] - cx, q[1] / q[2] - cy
    py, px = prior if prior is not None else (0.0, 0.0)
    return round(dy - py) + u, round(dx - px) + v


def _telemetry_row(s: TelemetrySample) -> dict:
    return {
        "t_s": f"{s.t:.3f}",
        "lat_deg": f"{s.lat_deg:.7f}",
        "lon_deg": f"{s.lon_deg:.7f}",
        "alt_msl_m": s.alt_msl_m,
        "height_agl_m": s.height_agl_m,
        "ground_speed_mps": s.ground_speed_mps,
        "course_deg": math.degrees(s.course_rad),
        "heading_deg": None if s.yaw_rad is None else math.degrees(s.yaw_rad) % 360.0,
    }
