"""Check the telemetry's image motion (METHODS.md B, eq. 1) against the frames' own.

The frame timing of :mod:`subpix_ros.core.timing` rests on ``s = f V / (H a)``: a focal length
``f`` or a pixel pitch ``a`` that does not fit the stream (a topic downscaled 2x doubles ``a``),
a height above mean sea level given as height above ground, or a camera mounted at another yaw
than configured, all leave the frame selection aiming at the wrong fraction of a pixel and the
expected shifts off by a factor or an angle, with nothing else failing. The frames measure the
same motion (registration and sub-pixel shift), so one fit tells both errors apart from the
telemetry's noise.

Conventions as :mod:`subpix_ros.core.timing`: shifts ``(u, v)`` = (rows, columns), pixels, how
far the scene content moved from the reference to the frame; angles clockwise from north.

References
----------
.. [1] S. A. Stankevich, S. V. Shklyar, M. S. Lubskyi, "Increasing the spatial
   resolution of aerial imaging by sub-pixel image registration", 2013
   (docs/METHODS.md B, eq. 1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["TelemetryAgreement", "telemetry_agreement", "what_would_fit"]

#: A scale further than this from 1 (and beyond 3 standard errors) is a disagreement.
SCALE_TOLERANCE = 0.10
#: A rotation further than this (deg; and beyond 3 standard errors) is a disagreement.
ROTATION_TOLERANCE_DEG = 10.0
#: Fewest frame pairs the fit is made from.
MIN_PAIRS = 3
#: Least RMS expected shift (px) over the pairs: below it the fit cannot see a scale.
MIN_MOTION_PX = 0.5
#: Frames whose RMS shift is below this fraction of the expected RMS did not move: a frozen
#: camera or repeated frames, not a camera parameter off (no scale or rotation fits them).
STILL_FRACTION = 0.1


@dataclass(frozen=True)
class TelemetryAgreement:
    """The fit ``measured = k exp(i theta) expected`` over a flight's frame pairs.

    Attributes
    ----------
    pairs : int
        Frame pairs the fit used (after leaving out ``outliers``).
    outliers : int
        Pairs left out: residual above 5 times the median residual (and 0.5 px).
    scale, scale_se : float or None
        ``k`` and its standard error: how many times the telemetry's expected shift the frames
        moved (1: agree). ``k f / a`` is the focal length in pixels the frames imply.
    rotation_deg, rotation_se_deg : float or None
        ``theta`` (deg) and its standard error: the image's heading is ``theta`` clockwise of
        the one assumed (add it to ``camera_yaw_offset_deg``).
    rms_px : float or None
        RMS residual of the fit (px, per pair, both axes).
    agrees : bool or None
        False: the scale or the rotation is off by more than its tolerance and 3 standard
        errors; True: neither is, and 3 standard errors are within both tolerances; None:
        too little or too noisy to tell (``reason`` says why).
    scale_off, rotation_off : bool
        Which of the two is off (both False unless ``agrees`` is False).
    still : bool
        The frames did not move while the telemetry expects motion (their RMS shift below
        ``STILL_FRACTION`` of the expected): ``agrees`` False, neither ``scale_off`` nor
        ``rotation_off`` (no parameter would fit; a frozen camera or repeated frames).
    reason : str
        One sentence: what the fit found, or why it could not be made.
    """

    pairs: int
    outliers: int = 0
    scale: float | None = None
    scale_se: float | None = None
    rotation_deg: float | None = None
    rotation_se_deg: float | None = None
    rms_px: float | None = None
    agrees: bool | None = None
    reason: str = ""
    scale_off: bool = False
    rotation_off: bool = False
    still: bool = False


def telemetry_agreement(measured: np.ndarray, expected: np.ndarray) -> TelemetryAgreement:
    """Fit the frames' measured shifts to the telemetry's expected ones by a scale and a rotation.

    Parameters
    ----------
    measured : numpy.ndarray
        (N, 2) shifts ``(u, v)`` the frames show between each frame and its reference, px
        (registration plus sub-pixel shift). Rows with a NaN are left out.
    expected : numpy.ndarray
        (N, 2) shifts METHODS eq. 1 gives over the same intervals, px
        (:func:`subpix_ros.core.timing.expected_shift_px`).

    Returns
    -------
    TelemetryAgreement
        ``agrees=None`` with the reason when fewer than ``MIN_PAIRS`` pairs remain, the
        expected motion is below ``MIN_MOTION_PX`` RMS, or the fit's 3 standard errors exceed
        a tolerance without the estimate doing so; ``agrees=False`` and ``still`` when the
        frames moved less than ``STILL_FRACTION`` of the expected RMS shift (no fit is made:
        its scale and rotation would be noise).

    Raises
    ------
    ValueError
        If the arrays are not both (N, 2).

    Notes
    -----
    With ``z = u + i v`` eq. 1 reads ``z = s dt exp(-i (course - heading))``, so a scale
    error of ``s`` (``f``, ``a``, ``H``) multiplies every ``z`` by a real ``k`` and an image
    heading ``theta`` clockwise of the assumed one by ``exp(i theta)``. The least-squares
    ``c = sum z_m conj(z_e) / sum |z_e|^2`` gives ``k = |c|``, ``theta = arg c``; the residual
    ``r = z_m - c z_e`` has per-axis variance ``sigma^2 = sum |r|^2 / (2 (N - 1))`` and
    ``se(k) = sigma / sqrt(sum |z_e|^2)``, ``se(theta) = se(k) / k`` (rad). The fit is made
    twice: pairs whose residual exceeds ``max(5 median |r|, 0.5 px)`` are left out of the
    second (a failed registration). The standard errors count the telemetry's noise but not
    its slow biases (GPS speed), so the tolerances, not the errors alone, decide.
    """
    zm_all = _as_complex(measured, "measured")
    ze_all = _as_complex(expected, "expected")
    if zm_all.shape != ze_all.shape:
        raise ValueError(f"measured and expected differ in length: {zm_all.size}, {ze_all.size}")
    ok = np.isfinite(zm_all) & np.isfinite(ze_all)
    zm, ze = zm_all[ok], ze_all[ok]
    if zm.size < MIN_PAIRS:
        return TelemetryAgreement(
            int(zm.size),
            reason=f"not checked: {zm.size} frame pairs with a measured and an expected shift "
            f"(at least {MIN_PAIRS} needed)",
        )
    motion = float(np.sqrt(np.mean(np.abs(ze) ** 2)))
    if motion < MIN_MOTION_PX:
        return TelemetryAgreement(
            int(zm.size),
            reason=f"not checked: the expected shifts are {motion:.2f} px RMS "
            f"(at least {MIN_MOTION_PX} px needed to see a scale)",
        )
    moved = float(np.sqrt(np.mean(np.abs(zm) ** 2)))
    if moved < STILL_FRACTION * motion:
        return _still(int(zm.size), moved, motion)
    c, resid = _fit(zm, ze)
    keep = np.abs(resid) <= max(5.0 * float(np.median(np.abs(resid))), 0.5)
    if keep.sum() >= MIN_PAIRS and not keep.all():
        c, _ = _fit(zm[keep], ze[keep])
    else:
        keep = np.ones_like(keep)
    zm, ze = zm[keep], ze[keep]
    resid = zm - c * ze
    n = int(zm.size)
    sigma = math.sqrt(float(np.sum(np.abs(resid) ** 2)) / (2.0 * (n - 1)))
    k = float(abs(c))
    k_se = sigma / math.sqrt(float(np.sum(np.abs(ze) ** 2)))
    theta = math.degrees(math.atan2(c.imag, c.real))
    theta_se = math.degrees(k_se / k) if k > 0 else math.inf
    off_scale = abs(k - 1.0) > max(SCALE_TOLERANCE, 3.0 * k_se)
    off_turn = abs(theta) > max(ROTATION_TOLERANCE_DEG, 3.0 * theta_se)
    sure = 3.0 * k_se <= SCALE_TOLERANCE and 3.0 * theta_se <= ROTATION_TOLERANCE_DEG
    agrees = False if (off_scale or off_turn) else (True if sure else None)
    found = (
        f"the frames moved {k:.3f}x (+- {k_se:.3f}) the telemetry's expected shift, rotated "
        f"{theta:+.1f} deg (+- {theta_se:.1f}), over {n} frame pairs"
        + (f" ({int((~keep).sum())} left out)" if not keep.all() else "")
    )
    verdict = {
        True: "agrees: ",
        False: "disagrees: ",
        None: "undecided (the fit is too uncertain to tell a "
        f"{SCALE_TOLERANCE:.0%} scale or a {ROTATION_TOLERANCE_DEG:g} deg rotation): ",
    }[agrees]
    return TelemetryAgreement(
        n,
        int((~keep).sum()),
        k,
        k_se,
        theta,
        theta_se,
        math.sqrt(float(np.mean(np.abs(resid) ** 2))),
        agrees,
        verdict + found,
        off_scale,
        off_turn,
    )


def _still(pairs: int, moved_px: float, expected_px: float) -> TelemetryAgreement:
    """Return the verdict on frames that did not move while the telemetry expects motion.

    Parameters
    ----------
    pairs : int
        Frame pairs compared.
    moved_px, expected_px : float
        RMS shift the frames show and the telemetry expects over them, px.

    Returns
    -------
    TelemetryAgreement
        ``agrees`` False, ``still`` True, the scale ``moved_px / expected_px`` (no rotation:
        there is no motion to measure one from).
    """
    return TelemetryAgreement(
        pairs,
        scale=moved_px / expected_px,
        agrees=False,
        still=True,
        reason=f"disagrees: the frames did not move ({moved_px:.2f} px RMS against their "
        f"references) while the telemetry expects {expected_px:.2f} px RMS, over {pairs} frame "
        "pairs",
    )


def what_would_fit(
    check: TelemetryAgreement,
    focal_length_mm: float,
    pixel_pitch_um: float,
    camera_yaw_offset_deg: float,
) -> str:
    """Say which of METHODS eq. 1's parameters would fit the frames ('' unless they disagree).

    Parameters
    ----------
    check : TelemetryAgreement
        :func:`telemetry_agreement` of the frames against the expectation made with the
        parameters below.
    focal_length_mm, pixel_pitch_um, camera_yaw_offset_deg : float
        The parameters the expected shifts were made with (mm, um, deg).

    Returns
    -------
    str
        For a scale off: the focal length in pixels ``f / a`` used and the one the frames
        imply, ``k f / a`` (e.g. ``pixel_pitch_um a / k``; or the height above ground is off by
        ``1 / k``); for a rotation off: the yaw offset that would fit, the given one plus
        ``theta``. Joined by "; ". For frames that did not move (``still``): that no parameter
        would fit, and what to look at instead.
    """
    if check.agrees is not False:
        return ""
    if check.still:
        return (
            "a frozen camera or repeated frames? (no camera parameter would fit: check that "
            "the camera sends new images)"
        )
    fixes = []
    if check.scale_off:
        f_px = focal_length_mm * 1e3 / pixel_pitch_um
        fixes.append(
            f"focal_length_mm {focal_length_mm:g} and pixel_pitch_um {pixel_pitch_um:g} (f/a "
            f"{f_px:.0f} px) or the height above ground do not fit these frames: they imply f/a "
            f"{check.scale * f_px:.0f} px (e.g. pixel_pitch_um {pixel_pitch_um / check.scale:.3g}, "
            "as for a stream downscaled by that factor)"
        )
    if check.rotation_off:
        fixes.append(
            f"the camera is yawed {check.rotation_deg:+.1f} deg from camera_yaw_offset_deg "
            f"{camera_yaw_offset_deg:g}: give yaw offset "
            f"{camera_yaw_offset_deg + check.rotation_deg:.1f} deg"
        )
    return "; ".join(fixes) + "; so the frame timing aims at another shift than p asks"


def _as_complex(a: np.ndarray, name: str) -> np.ndarray:
    """Return (N, 2) shifts ``(u, v)`` as ``u + i v``; ValueError for another shape."""
    arr = np.asarray(a, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValueError(f"{name} must be (N, 2) shifts (u, v), got shape {arr.shape}")
    return arr[:, 0] + 1j * arr[:, 1]


def _fit(zm: np.ndarray, ze: np.ndarray) -> tuple[complex, np.ndarray]:
    """Return the least-squares ``c`` of ``zm = c ze`` and the residuals ``zm - c ze``."""
    c = complex(np.sum(zm * np.conj(ze)) / np.sum(np.abs(ze) ** 2))
    return c, zm - c * ze
