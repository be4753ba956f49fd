"""``shifts.csv``: the registration's displacement of every aligned frame, shift or not.

A small synthetic flight fed to the collector as the stages report it (aligned frames, one
shift converged, one failed, one never reported), then :func:`_shift_rows`: no bag, fast.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from subpix_ros.core.registration.geometry import centre_shift
from subpix_ros.core.telemetry import TelemetryBuffer, sample_from_enu
from subpix_ros.process.collector import _Collector
from subpix_ros.process.products import rounded
from subpix_ros.process.tables import SHIFT_COLUMNS, _shift_rows

T0 = 1_717_000_000.0
REF_NS = int(T0 * 1e9)
SHAPE = (480, 640)
REG_PARAMS = {
    "focal_length_mm": 8.0,
    "pixel_pitch_um": 3.45,
    "camera_yaw_offset_deg": 0.0,
    "telemetry_time_offset_s": 0.0,
    "telemetry_timeout_s": 1.0,
    "p": 2.0,
    "min_speed_mps": 0.5,
}


class _NoWriter:
    """Stands for the products writer: the collector's writes go nowhere."""

    def __getattr__(self, name: str):
        return lambda *args, **kwargs: None


def _homography(rows_px: float, cols_px: float, angle_deg: float) -> np.ndarray:
    """Return MOVING -> REFERENCE (x, y): a small rotation and a shift of whole frames."""
    a = math.radians(angle_deg)
    return np.array(
        [
            [math.cos(a), -math.sin(a), -cols_px],
            [math.sin(a), math.cos(a), -rows_px],
            [0.0, 0.0, 1.0],
        ]
    )


def _flight() -> tuple[_Collector, dict[int, np.ndarray]]:
    """Three frames aligned to one reference: shift converged, failed, never reported."""
    collector = _Collector(_NoWriter(), REG_PARAMS)
    collector.shape = SHAPE
    reference = SimpleNamespace(stamp_ns=REF_NS)
    homographies = {}
    for k, (dy, dx, angle) in enumerate(((12.4, -3.2, 0.3), (25.1, -6.6, 0.5), (37.8, -9.7, 0.2))):
        stamp = REF_NS + (k + 1) * 100_000_000
        homographies[stamp] = _homography(dy, dx, angle)
        collector.on_aligned(
            SimpleNamespace(
                stamp_ns=stamp,
                reference=reference,
                homography=homographies[stamp],
                prior=None,
                frame_id="cam",
            )
        )
    first, failed, _ = sorted(homographies)
    collector.on_shift(
        SimpleNamespace(
            stamp_ns=first,
            reference_stamp_ns=REF_NS,
            u=0.31,
            v=-0.22,
            u_std=0.002,
            v_std=0.002,
            z=0.0,
        )
    )
    collector.on_skipped(
        ("shift_node", SimpleNamespace(stamp_ns=failed, reason="failed", detail="no converge"))
    )
    return collector, homographies


def _telemetry() -> TelemetryBuffer:
    buf = TelemetryBuffer(max_age_s=1e9, stale_after_s=1.0, max_samples=10**6)
    for k in range(10):
        buf.add(sample_from_enu(T0 - 0.2 + 0.1 * k, (0.0, 12.0, 0.0), 60.0))
    return buf


def test_a_frame_without_a_sub_pixel_shift_keeps_the_registrations_displacement():
    collector, homographies = _flight()
    rows = {r["stamp_ns"]: r for r in _shift_rows(collector, _telemetry(), REG_PARAMS)}
    assert len(rows) == 3
    for stamp, h in homographies.items():
        row = rows[stamp]
        du, dv = centre_shift(h, SHAPE)
        # every aligned frame: converged, failed or never measured
        assert row["u_registration_px"] == rounded(du), row
        assert row["v_registration_px"] == rounded(dv), row
        assert row["u_expected_px"] is not None
        if row["converged"]:
            # the total: the registration's whole pixels plus the sub-pixel shift
            assert row["u_total_px"] == pytest.approx(round(du) + 0.31)
            assert row["v_total_px"] == pytest.approx(round(dv) - 0.22)
            assert row["u_residual_px"] == rounded(row["u_total_px"] - row["u_expected_px"])
        else:
            # no sub-pixel shift: no total and no residual (residual = total - expected)
            assert "u_total_px" not in row and "u_residual_px" not in row, row
    failed = sorted(homographies)[1]
    assert rows[failed]["reason"] == "failed: no converge"
    # written after the total shift
    names = list(SHIFT_COLUMNS)
    assert names.index("u_registration_px") == names.index("v_total_px") + 1
    assert names.index("v_registration_px") == names.index("u_registration_px") + 1
