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

from subpix_ros.core.registration.geometry import centre_shift
from subpix_ros.core.telemetry import TelemetryBuffer, TelemetrySample
from subpix_ros.core.timing import expected_shift_px, frame_interval
from subpix_ros.core.timing_check import TelemetryAgreement, telemetry_agreement
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
    "u_registration_px",
    "v_registration_px",
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
    """Describe ``(dims, dtype)`` as ``"WxH[xC] dtype"``."""
    dims, dtype = shape
    width_height = f"{dims[1]}x{dims[0]}"
    channels = "" if len(dims) == 2 else f"x{dims[2]}"
    return f"{width_height}{channels} {dtype}"


def _image_rate(buf: TelemetryBuffer, t: float, reg_params: dict) -> tuple[float, float] | None:
    """Return the image velocity (rows, cols px/s) telemetry gives at time ``t`` (s).

    Parameters
    ----------
    buf : TelemetryBuffer
        The flight's telemetry.
    t : float
        Frame time, s (the stage's ``telemetry_time_offset_s`` is added).
    reg_params : dict
        The registration stage's parameters of :data:`EXPECTED_SHIFT_PARAMS`.

    Returns
    -------
    tuple of float or None
        ``expected_shift_px`` over 1 s; None without a sample, below ``min_speed_mps`` or
        with no height above ground.

    Notes
    -----
    METHODS eq. 1: ``u = s cos(course - heading)``, ``v = -s sin(course - heading)``,
    ``s = f V / (H a)``; heading = vehicle yaw (else the course) + the camera's yaw offset.
    """
    sample, _ = buf.at(t + float(reg_params["telemetry_time_offset_s"]))
    if (
        sample is None
        or sample.ground_speed_mps < float(reg_params["min_speed_mps"])
        or sample.height_agl_m <= 0
    ):
        return None
    yaw = sample.yaw_rad if sample.yaw_rad is not None else sample.course_rad
    heading = yaw + math.radians(float(reg_params["camera_yaw_offset_deg"]))
    try:
        return expected_shift_px(
            sample.ground_speed_mps,
            sample.course_rad,
            sample.height_agl_m,
            float(reg_params["focal_length_mm"]) * 1e-3,
            float(reg_params["pixel_pitch_um"]) * 1e-6,
            1.0,
            heading,
        )
    except ValueError:
        return None


def _interval_at(buf: TelemetryBuffer, t: float, reg_params: dict) -> float | None:
    """Return the frame interval (s, METHODS eq. 1 for shift ``p``) at time ``t``, or None."""
    sample, _ = buf.at(t + float(reg_params["telemetry_time_offset_s"]))
    if sample is None:
        return None
    interval = frame_interval(
        float(reg_params["pixel_pitch_um"]) * 1e-6,
        sample.height_agl_m,
        float(reg_params["focal_length_mm"]) * 1e-3,
        sample.ground_speed_mps,
        float(reg_params["p"]),
    )
    return interval.interval_s if interval.ok else None


def _shift_rows(collector: _Collector, buf: TelemetryBuffer, reg_params: dict) -> list[dict]:
    """Build the rows of ``shifts.csv``: measured, total, registration, expected shift, residual.

    Notes
    -----
    The registration's displacement of the reference's centre (:func:`_registration_shift`)
    is given for every frame with a homography, its sub-pixel shift converged or not; the
    total shift only where it converged. The expected shift over ``dt = t_frame - t_reference``
    is the mean of the image velocities at both times (trapezoid) times ``dt``; residual =
    total - expected, from the rounded values so that every process writes the same digits.
    """
    rows = []
    for stamp in sorted(collector.shifts):
        row = dict(collector.shifts[stamp])
        ref = row.get("reference_stamp_ns")
        moved = _registration_shift(collector, stamp)
        if moved is not None:
            row["u_registration_px"] = rounded(moved[0])
            row["v_registration_px"] = rounded(moved[1])
            if row.get("converged"):
                total = _total_shift(moved, collector.priors.get(stamp), row["u_px"], row["v_px"])
                row["u_total_px"], row["v_total_px"] = rounded(total[0]), rounded(total[1])
        if ref is not None and len(buf):
            t_ref, t = ref * 1e-9, stamp * 1e-9
            rate_ref, rate = _image_rate(buf, t_ref, reg_params), _image_rate(buf, t, reg_params)
            if rate_ref is not None and rate is not None:
                dt = t - t_ref
                row["u_expected_px"] = rounded(0.5 * (rate_ref[0] + rate[0]) * dt)
                row["v_expected_px"] = rounded(0.5 * (rate_ref[1] + rate[1]) * dt)
                if "u_total_px" in row:
                    row["u_residual_px"] = rounded(row["u_total_px"] - row["u_expected_px"])
                    row["v_residual_px"] = rounded(row["v_total_px"] - row["v_expected_px"])
        rows.append(row)
    return rows


def _registration_shift(collector: _Collector, stamp: int) -> tuple[float, float] | None:
    """Return the registration's displacement of the reference's centre in frame ``stamp``.

    Parameters
    ----------
    collector : _Collector
        The flight's homographies and frame shape.
    stamp : int
        The aligned frame's stamp, ns.

    Returns
    -------
    tuple of float or None
        :func:`~subpix_ros.core.registration.geometry.centre_shift` of the frame's homography
        (rows, cols px; the sign of the total shift); None without a homography or for a
        singular one.
    """
    homography = collector.homographies.get(stamp)
    return None if homography is None else centre_shift(homography, collector.shape)


def _total_shift(
    moved: tuple[float, float], prior: tuple[float, float] | None, u: float, v: float
) -> tuple[float, float]:
    """Return the homography's whole-pixel shift plus the estimated sub-pixel part (rows, cols).

    Parameters
    ----------
    moved : tuple of float
        The registration's displacement of the reference's centre (:func:`_registration_shift`).
    prior : tuple of float or None
        The part of ``moved`` the aligned frame keeps (None: all of it).
    u, v : float
        The sub-pixel shift measured on the aligned frame (rows, cols px).

    Returns
    -------
    tuple of float
        ``round(moved - prior) + (u, v)``.

    Notes
    -----
    The homography maps moving-frame px to reference px, so the reference's centre ``c``
    appears at ``H^-1 c`` in the moving frame; the aligned frame keeps ``prior`` of that
    displacement (the sub-pixel remainder), which the shift stage measures as (u, v).
    """
    dy, dx = moved
    prior_rows, prior_cols = prior if prior is not None else (0.0, 0.0)
    return round(dy - prior_rows) + u, round(dx - prior_cols) + v


def telemetry_check(collector: _Collector, rows: list[dict]) -> TelemetryAgreement:
    """Fit the frames' shifts to the telemetry's expected ones (METHODS eq. 1's parameters).

    Parameters
    ----------
    collector : _Collector
        The flight's homographies and frame shape.
    rows : list of dict
        ``shifts.csv``'s rows (:func:`_shift_rows`).

    Returns
    -------
    TelemetryAgreement
        :func:`~subpix_ros.core.timing_check.telemetry_agreement` over the rows with an expected
        shift; measured = the total shift where the sub-pixel shift converged, else the
        homography's displacement of the reference's centre (whole frames apart: registration
        accuracy is enough for a scale).
    """
    measured, expected = [], []
    for row in rows:
        if row.get("u_expected_px") is None:
            continue
        if row.get("u_total_px") is not None:
            got = (row["u_total_px"], row["v_total_px"])
        else:
            got = _registration_shift(collector, row["stamp_ns"])
        if got is not None:
            measured.append(got)
            expected.append((row["u_expected_px"], row["v_expected_px"]))
    return telemetry_agreement(
        np.array(measured, dtype=float).reshape(-1, 2),
        np.array(expected, dtype=float).reshape(-1, 2),
    )


def _telemetry_row(sample: TelemetrySample) -> dict:
    """Build one row of ``telemetry.csv`` (angles in degrees)."""
    return {
        "t_s": f"{sample.t:.3f}",
        "lat_deg": f"{sample.lat_deg:.7f}",
        "lon_deg": f"{sample.lon_deg:.7f}",
        "alt_msl_m": sample.alt_msl_m,
        "height_agl_m": sample.height_agl_m,
        "ground_speed_mps": sample.ground_speed_mps,
        "course_deg": math.degrees(sample.course_rad),
        "heading_deg": None if sample.yaw_rad is None else math.degrees(sample.yaw_rad) % 360.0,
    }
