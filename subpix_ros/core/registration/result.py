"""The result record of :func:`~subpix_ros.core.registration.register`."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .fit import Normaliser, distort_points, undistort_points
from .geometry import apply_h


@dataclass
class RegistrationResult:
    """Outcome of :func:`~subpix_ros.core.registration.register`.

    On failure ``ok`` is False, ``reason`` says why and ``homography`` is None (never a guessed
    matrix).

    Attributes
    ----------
    homography : ndarray or None
        3x3 float64, MOVING (x, y) -> REFERENCE (x, y), pixels; the best pure projective fit.
    inliers : int
        Tie points within the inlier threshold.
    rms_px : float or None
        RMS transfer residual of the full model over the inliers (reference px).
    overlap : float
        Fraction of the reference area covered by the moving frame.
    points : ndarray, shape (N, 4)
        The inliers: ``x_ref, y_ref, x_mov, y_mov``.
    model : str
        ``"projective"`` or ``"affine"``.
    distortion : float
        Division-model lambda (dimensionless, radius in half-diagonals); 0 for none.
    homography_undistorted : ndarray or None
        ``H_u`` between undistorted pixel coordinates.
    rms_px_projective : float or None
        RMS residual of ``homography`` alone over the inliers.
    median_px : float or None
        Median transfer residual of the full model.
    spread : float
        Fraction of 6x6 overlap cells holding an inlier.
    ref_shape, mov_shape : tuple of int
        Frame shapes (rows, cols).
    time_s : float
        Wall time of the registration (s).
    tracked : bool
        True if the tracking path (``prior``) gave this result.
    track_failure : str
        Why tracking failed when a prior was given and the full pipeline ran.
    """

    ok: bool
    reason: str = ""
    homography: np.ndarray | None = None
    inliers: int = 0
    rms_px: float | None = None
    overlap: float = 0.0
    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    model: str = "projective"
    distortion: float = 0.0
    homography_undistorted: np.ndarray | None = None
    rms_px_projective: float | None = None
    median_px: float | None = None
    spread: float = 0.0
    ref_shape: tuple[int, int] = (0, 0)
    mov_shape: tuple[int, int] = (0, 0)
    time_s: float = 0.0
    tracked: bool = False
    track_failure: str = ""

    def _norm(self) -> Normaliser:
        return Normaliser.for_shape(self.ref_shape)

    def transfer(self, pts_mov: np.ndarray) -> np.ndarray:
        """Map (N, 2) moving pixel coordinates (x, y) to the reference (full model)."""
        self._require_ok()
        pts = np.asarray(pts_mov, dtype=np.float64).reshape(-1, 2)
        if self.distortion == 0.0 or self.homography_undistorted is None:
            return apply_h(self.homography, pts)
        n = self._norm()
        return distort_points(
            apply_h(self.homography_undistorted, undistort_points(pts, self.distortion, n)),
            self.distortion,
            n,
        )

    def inverse_transfer(self, pts_ref: np.ndarray) -> np.ndarray:
        """Map (N, 2) reference pixel coordinates (x, y) to the moving frame (full model)."""
        self._require_ok()
        pts = np.asarray(pts_ref, dtype=np.float64).reshape(-1, 2)
        if self.distortion == 0.0 or self.homography_undistorted is None:
            return apply_h(np.linalg.inv(self.homography), pts)
        n = self._norm()
        hi = np.linalg.inv(self.homography_undistorted)
        return distort_points(
            apply_h(hi, undistort_points(pts, self.distortion, n)), self.distortion, n
        )

    def baseline_px(self) -> np.ndarray | None:
        """Return the motion ``t = transfer(c) - c`` of the moving frame's centre ``c``.

        Reference px (x, y); None on failure.
        """
        if not self.ok:
            return None
        hm, wm = self.mov_shape
        c = np.array([[wm / 2.0, hm / 2.0]])
        return (self.transfer(c) - c)[0]

    def residual_components(self) -> tuple[np.ndarray, np.ndarray] | None:
        """Split each inlier's transfer residual (px) along and across :meth:`baseline_px`.

        Parallax of relief (a 3-D scene seen from two positions of a
        translating camera) lies along the baseline (the epipolar lines of a
        nadir camera in straight flight), while matching noise is isotropic.
        Returns ``(along, cross)`` arrays, None when the registration failed,
        has no inliers or ``|t| < 1`` px (no direction).
        """
        t = self.baseline_px()
        if t is None or len(self.points) == 0:
            return None
        nt = float(np.hypot(*t))
        if not nt >= 1.0:
            return None
        e = t / nt
        d = self.transfer(self.points[:, 2:]) - self.points[:, :2]
        return d @ e, d @ np.array([-e[1], e[0]])

    def residual_along_cross(self) -> tuple[float, float] | None:
        """Return the RMS of :meth:`residual_components`, ``(along, cross)`` px.

        ``along`` well above ``cross`` says the residual is the scene (relief parallax), not
        the registration. None as there.
        """
        comp = self.residual_components()
        if comp is None:
            return None
        along, cross = comp
        return float(np.sqrt(np.mean(along**2))), float(np.sqrt(np.mean(cross**2)))

    def _require_ok(self) -> None:
        if not self.ok:
            raise ValueError(f"registration failed: {self.reason}")

    def as_dict(self) -> dict[str, Any]:
        """Return a JSON-friendly summary (homography as a nested 3x3 list, moving -> ref px)."""
        return {
            "ok": self.ok,
            "reason": self.reason,
            "homography": None if self.homography is None else self.homography.tolist(),
            "homography_convention": (
                "maps MOVING pixel (x=col, y=row, 1) to REFERENCE pixel coordinates"
            ),
            "inliers": int(self.inliers),
            "rms_px": self.rms_px,
            "rms_px_projective": self.rms_px_projective,
            "median_px": self.median_px,
            "rms_along_cross_px": self.residual_along_cross(),
            "overlap": self.overlap,
            "spread": self.spread,
            "model": self.model,
            "distortion_lambda": self.distortion,
            "homography_undistorted": None
            if self.homography_undistorted is None
            else self.homography_undistorted.tolist(),
            "ref_shape": list(self.ref_shape),
            "mov_shape": list(self.mov_shape),
            "time_s": self.time_s,
            "tracked": self.tracked,
            "track_failure": self.track_failure,
        }


def _fail(reason: str, t0: float, shapes, model: str) -> RegistrationResult:
    return RegistrationResult(
        False,
        reason,
        model=model,
        ref_shape=shapes[0],
        mov_shape=shapes[1],
        time_s=time.perf_counter() - t0,
    )
