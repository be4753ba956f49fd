"""Frame timing from the carrier's own motion (METHODS.md B, eqs. 1 and 2).

Units are SI throughout the signatures (metres, seconds, radians); shifts are
in detector pixels.

Conventions
-----------
* Image motion: with ground speed ``V`` (m/s), height above ground ``H`` (m),
  focal length ``f`` (m) and pixel pitch ``a`` (m), a nadir camera sees the
  ground move across the focal plane at ``f V / H`` m/s, i.e.
  ``s = f V / (H a)`` pixels per second.
* Shifts are ``(u, v)`` = (rows, columns), pixels: how far the scene content
  moves from one frame to the next (a feature at (r, c) appears at
  (r + u, c + v)). This is the project-wide convention of
  :mod:`subpix_ros.core.shift`.
* Angles for :func:`expected_shift_px`: ``course_rad`` is the ground-track
  direction and ``image_heading_rad`` the direction the image's "up" (row 0
  side, decreasing row index) points on the ground, both measured clockwise
  from north (compass convention). The camera is nadir-looking and the image
  is not mirrored, so image "right" (increasing column) points to
  ``image_heading + 90 deg``. With ``alpha = course - image_heading`` the
  camera moves ``(-cos alpha, +sin alpha)`` in (row, col) per unit of motion,
  so the scene content moves the opposite way:
  ``u = +s dt cos(alpha)``, ``v = -s dt sin(alpha)``. Flying towards the top
  of the image makes features slide down (``u > 0``); flying towards the
  image's right makes them slide left (``v < 0``).

Nothing here returns a negative, infinite or NaN interval silently: bad input
gives a result with ``ok=False`` and a reason (or ``ValueError`` where the
function returns a bare number).

References
----------
.. [1] S. A. Stankevich, S. V. Shklyar, M. S. Lubskyi, "Increasing the spatial
   resolution of aerial imaging by sub-pixel image registration", 2013
   (docs/METHODS.md B, eqs. 1 and 2).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Optional, Sequence, Tuple

__all__ = [
    "IntervalResult",
    "frame_interval",
    "detector_angle",
    "image_speed_px_s",
    "expected_shift_px",
    "FrameDecision",
    "FrameSelector",
]


def _finite_positive(x: float) -> bool:
    """Tell whether ``x`` is a finite number > 0 (False for anything that is not a number)."""
    try:
        return math.isfinite(float(x)) and float(x) > 0.0
    except (TypeError, ValueError):
        return False


@dataclass
class IntervalResult:
    """Outcome of :func:`frame_interval`.

    Parameters
    ----------
    ok, reason : bool, str
        Whether an interval could be computed, and why not ('' when ok).
    interval_s : float or None
        Time between frames, s; None when ``ok`` is False.
    phi_rad : float
        Angle between the detector's long axis and the ground track, rad.
    p : float
        Sub-pixel factor: the target step is ``1/p`` pixel.
    shift_px_per_s : float or None
        Image speed ``f V / (H a)``, pixels/s.
    step_px : float or None
        Along-track image step during ``interval_s``: ``cos(phi) / p`` px by eq. (1).
    frame_rate_hz : float or None
        ``1 / interval_s``, Hz.
    """

    ok: bool
    reason: str
    interval_s: Optional[float]
    phi_rad: float
    p: float
    shift_px_per_s: Optional[float] = None
    step_px: Optional[float] = None
    frame_rate_hz: Optional[float] = None

    @property
    def phi_deg(self) -> float:
        """Angle ``phi_rad`` in degrees."""
        return math.degrees(self.phi_rad)

    def as_dict(self) -> dict:
        """Return the fields as a plain dict, with ``phi_deg`` added."""
        d = asdict(self)
        d["phi_deg"] = self.phi_deg
        return d


def detector_angle(p: float) -> float:
    """Return the detector rotation for ``p`` sub-pixel steps, METHODS.md B eq. (2).

    Parameters
    ----------
    p : float
        Sub-pixel factor, finite and >= 2 (p = 1 would need 90 deg, i.e. no
        sub-pixel step at all).

    Returns
    -------
    float
        ``phi``, rad.

    Raises
    ------
    ValueError
        For ``p < 2`` or a non-finite ``p``.

    Notes
    -----
    ``phi = arctan(1 / (p - 1))``: the image then steps ``1/p`` pixel across
    and ``(p - 1)/p`` pixel along the detector's long axis [1]_.
    """
    if not (isinstance(p, (int, float)) and math.isfinite(p)) or p < 2:
        raise ValueError(f"p must be a finite number >= 2 (got {p!r})")
    return math.atan(1.0 / (p - 1.0))


def image_speed_px_s(
    speed_mps: float, height_m: float, focal_length_m: float, pixel_pitch_m: float
) -> float:
    """Return the image motion rate in pixels per second (METHODS.md B, text of eq. 1).

    Parameters
    ----------
    speed_mps : float
        Ground speed ``V``, m/s; may be 0 (hovering).
    height_m, focal_length_m, pixel_pitch_m : float
        Height above ground ``H``, focal length ``f`` and detector pixel pitch ``a``, m.

    Returns
    -------
    float
        ``s = f V / (H a)``, pixels/s.

    Raises
    ------
    ValueError
        On a negative or non-finite speed, or a non-positive height, focal
        length or pitch.
    """
    if not (math.isfinite(speed_mps) and speed_mps >= 0.0):
        raise ValueError(f"ground speed must be finite and >= 0 m/s (got {speed_mps!r})")
    for name, val in (
        ("height_m", height_m),
        ("focal_length_m", focal_length_m),
        ("pixel_pitch_m", pixel_pitch_m),
    ):
        if not _finite_positive(val):
            raise ValueError(f"{name} must be finite and > 0 (got {val!r})")
    return focal_length_m * speed_mps / (height_m * pixel_pitch_m)


def frame_interval(
    pixel_pitch_m: float,
    height_m: float,
    focal_length_m: float,
    speed_mps: float,
    p: float,
    phi_rad: float = 0.0,
) -> IntervalResult:
    """Return the time between frames for a ``1/p`` pixel step, METHODS.md B eq. (1).

    Parameters
    ----------
    pixel_pitch_m, height_m, focal_length_m : float
        Pixel pitch ``a``, height above ground ``H`` and focal length ``f``, m.
    speed_mps : float
        Ground speed ``V``, m/s.
    p : float
        Sub-pixel factor (>= 2).
    phi_rad : float
        Angle between the detector's long axis and the ground-track velocity,
        rad (use :func:`detector_angle` for eq. 2).

    Returns
    -------
    IntervalResult
        The interval, or ``ok=False`` with a reason (never a negative, zero or
        infinite time) when V <= 0 or non-finite, H, f or a <= 0 or
        non-finite, p < 2, or ``cos(phi) <= 0`` (|phi| >= 90 deg).

    Notes
    -----
    ``t = a H cos(phi) / (p f V)`` s [1]_. During ``t`` the image moves
    ``f V t / (H a) = cos(phi) / p`` pixels.
    """
    phi = float(phi_rad) if isinstance(phi_rad, (int, float)) else float("nan")

    def fail(reason: str) -> IntervalResult:
        return IntervalResult(
            False,
            reason,
            None,
            phi if math.isfinite(phi) else 0.0,
            float(p) if isinstance(p, (int, float)) else float("nan"),
        )

    if not (isinstance(p, (int, float)) and math.isfinite(p)) or p < 2:
        return fail(f"p must be a finite number >= 2 (got {p!r})")
    if not (isinstance(speed_mps, (int, float)) and math.isfinite(speed_mps)):
        return fail(f"ground speed is not a finite number ({speed_mps!r})")
    if speed_mps <= 0:
        return fail(
            f"ground speed {speed_mps:g} m/s <= 0: the carrier does not move, "
            "no interval gives a 1/p step"
        )
    for name, val in (
        ("height", height_m),
        ("focal length", focal_length_m),
        ("pixel pitch", pixel_pitch_m),
    ):
        if not _finite_positive(val):
            return fail(f"{name} must be finite and > 0 (got {val!r})")
    if not math.isfinite(phi):
        return fail(f"phi is not a finite angle ({phi_rad!r})")
    c = math.cos(phi)
    if c <= 1e-12:
        return fail(
            f"cos(phi) <= 0 for phi = {math.degrees(phi):g} deg: "
            "the detector axis is across the track"
        )
    t = pixel_pitch_m * height_m * c / (p * focal_length_m * speed_mps)
    if not (math.isfinite(t) and t > 0):
        return fail(f"interval not finite ({t!r})")
    rate = image_speed_px_s(speed_mps, height_m, focal_length_m, pixel_pitch_m)
    return IntervalResult(True, "", t, phi, float(p), rate, rate * t, 1.0 / t)


def expected_shift_px(
    speed_mps: float,
    course_rad: float,
    height_m: float,
    focal_length_m: float,
    pixel_pitch_m: float,
    dt_s: float,
    image_heading_rad: float = 0.0,
) -> Tuple[float, float]:
    """Return the expected scene shift over ``dt_s`` seconds.

    Parameters
    ----------
    speed_mps : float
        Ground speed ``V``, m/s.
    course_rad : float
        Ground-track course, rad clockwise from north.
    height_m, focal_length_m, pixel_pitch_m : float
        ``H``, ``f`` and ``a`` as in :func:`image_speed_px_s`, m.
    dt_s : float
        Time between the two frames, s (>= 0).
    image_heading_rad : float
        Where the image's top points, rad clockwise from north.

    Returns
    -------
    tuple of float
        ``(u, v)``: rows, columns; pixels.

    Raises
    ------
    ValueError
        On non-finite or out-of-range input (negative speed, non-positive
        height/f/pitch, negative dt).

    Notes
    -----
    ``u = s dt cos(course - heading)``, ``v = -s dt sin(course - heading)``
    with ``s = f V / (H a)`` (angle convention: module docstring).
    """
    if not (math.isfinite(dt_s) and dt_s >= 0):
        raise ValueError(f"dt_s must be finite and >= 0 (got {dt_s!r})")
    if not (math.isfinite(course_rad) and math.isfinite(image_heading_rad)):
        raise ValueError("course and image heading must be finite angles")
    s = image_speed_px_s(speed_mps, height_m, focal_length_m, pixel_pitch_m) * dt_s
    alpha = course_rad - image_heading_rad
    return (s * math.cos(alpha), -s * math.sin(alpha))


@dataclass
class FrameDecision:
    """One decision of :class:`FrameSelector`.

    Parameters
    ----------
    keep, reason : bool, str
        Whether the frame is kept, and why.
    step_px : tuple of float or None
        The (u, v) shift predicted since the last kept frame, px (None when unknown).
    step_norm_px : float or None
        Its length, pixels.
    """

    keep: bool
    reason: str
    step_px: Optional[Tuple[float, float]] = None
    step_norm_px: Optional[float] = None

    def as_dict(self) -> dict:
        """Return the fields as a plain dict."""
        return asdict(self)


@dataclass
class FrameSelector:
    """Choose which frames of a fixed-rate stream to keep so kept frames step by ~1/p px.

    Parameters
    ----------
    p : float
        Sub-pixel factor (>= 2): the target step is ``1/p`` pixel.
    mode : {"step", "phase"}
        What is matched to the target (Notes).
    max_age_s : float
        Telemetry older than this relative to the frame stamp is stale, s.
    tolerance_px : float or None
        Tolerance around the target, pixels (default ``0.25 / p``).

    Raises
    ------
    ValueError
        On ``p < 2``, an unknown mode or a non-positive age or tolerance.

    Notes
    -----
    The inverse of eq. (1): instead of choosing the frame interval, the
    selector integrates the expected image motion (pixels/s, from telemetry
    via :func:`expected_shift_px` with ``dt_s=1``) between frames and keeps a
    frame when the predicted shift since the last kept frame is the closest
    it will get to the target.

    ``"step"`` (default): target ``1/p`` pixel. A frame is kept when
    ``|acc| + |next| / 2 >= 1/p``, where ``acc`` is the accumulated shift
    since the last kept frame and ``next`` the shift predicted for the next
    frame (current rate times the last frame interval): this keeps whichever
    frame lies closest to the target. If the stream is too slow for the
    target (one frame already moves more than ``1/p + tolerance``), every
    frame is kept and the reason says so.

    ``"phase"``: only the sub-pixel phase matters (fast flight, several
    pixels per frame; registration removes whole pixels). A frame is kept
    when the fractional part of ``|acc|`` is within ``tolerance_px`` of
    ``1/p``.

    Telemetry that is missing (``rate_px_s=None``), non-finite, or older than
    ``max_age_s`` relative to the frame stamp makes the selector keep every
    frame, with the reason. So does the first frame and a frame whose stamp
    does not increase.
    """

    p: float
    mode: str = "step"
    max_age_s: float = 1.0
    tolerance_px: Optional[float] = None
    _prev_stamp: Optional[float] = field(default=None, init=False, repr=False)
    _acc: Tuple[float, float] = field(default=(0.0, 0.0), init=False, repr=False)
    _have_kept: bool = field(default=False, init=False, repr=False)

    def __post_init__(self) -> None:
        if not (isinstance(self.p, (int, float)) and math.isfinite(self.p)) or self.p < 2:
            raise ValueError(f"p must be a finite number >= 2 (got {self.p!r})")
        if self.mode not in ("step", "phase"):
            raise ValueError(f"mode must be 'step' or 'phase' (got {self.mode!r})")
        if not _finite_positive(self.max_age_s):
            raise ValueError("max_age_s must be finite and > 0")
        if self.tolerance_px is None:
            self.tolerance_px = 0.25 / self.p
        elif not _finite_positive(self.tolerance_px):
            raise ValueError("tolerance_px must be finite and > 0")

    @property
    def target_px(self) -> float:
        """Target step between kept frames, ``1/p`` pixel."""
        return 1.0 / self.p

    def reset(self) -> None:
        """Forget the stream (the next frame is kept as a new start)."""
        self._prev_stamp = None
        self._acc = (0.0, 0.0)
        self._have_kept = False

    def _keep(
        self, stamp_s: float, reason: str, step: Optional[Tuple[float, float]]
    ) -> FrameDecision:
        """Keep the frame: restart the accumulation from it."""
        self._prev_stamp = stamp_s
        self._acc = (0.0, 0.0)
        self._have_kept = True
        norm = None if step is None else math.hypot(*step)
        return FrameDecision(True, reason, step, norm)

    def decide(
        self,
        stamp_s: float,
        rate_px_s: Optional[Sequence[float]] = None,
        rate_stamp_s: Optional[float] = None,
    ) -> FrameDecision:
        """Keep or skip a frame.

        Parameters
        ----------
        stamp_s : float
            Frame stamp, s.
        rate_px_s : sequence of float or None
            Expected image motion (u, v), pixels/s (e.g.
            ``expected_shift_px(..., dt_s=1.0)``), or None without telemetry.
        rate_stamp_s : float or None
            Time the telemetry refers to, s (None: assumed current).

        Returns
        -------
        FrameDecision
            Keep or skip, with the reason and the predicted step.

        Raises
        ------
        ValueError
            On a non-finite frame stamp.
        """
        if not math.isfinite(stamp_s):
            raise ValueError(f"frame stamp must be finite (got {stamp_s!r})")
        if self._prev_stamp is None or not self._have_kept:
            return self._keep(stamp_s, "first frame", None)
        dt = stamp_s - self._prev_stamp
        if dt <= 0:
            return self._keep(
                stamp_s, f"frame stamp did not increase (dt = {dt:g} s): restarting selection", None
            )
        if rate_px_s is None:
            return self._keep(stamp_s, "no telemetry: keeping every frame", None)
        ru, rv = (float(rate_px_s[0]), float(rate_px_s[1]))
        if not (math.isfinite(ru) and math.isfinite(rv)):
            return self._keep(stamp_s, "telemetry rate not finite: keeping every frame", None)
        if rate_stamp_s is not None:
            age = stamp_s - float(rate_stamp_s)
            if not math.isfinite(age) or age > self.max_age_s:
                return self._keep(
                    stamp_s,
                    f"telemetry stale ({age:.3g} s old > {self.max_age_s:g} s): "
                    "keeping every frame",
                    None,
                )
        # Integrate the motion since the previous frame (kept or not).
        acc = (self._acc[0] + ru * dt, self._acc[1] + rv * dt)
        self._prev_stamp = stamp_s
        nxt = math.hypot(ru, rv) * dt
        if self.mode == "step":
            return self._decide_step(stamp_s, acc, nxt)
        return self._decide_phase(stamp_s, acc)

    def _decide_step(self, stamp_s: float, acc: Tuple[float, float], nxt: float) -> FrameDecision:
        """Keep the frame closest to a ``1/p`` step (``acc`` so far, ``nxt`` px to the next)."""
        norm = math.hypot(*acc)
        target = self.target_px
        if nxt > target + self.tolerance_px:
            return self._keep(
                stamp_s,
                f"frame rate too low for a 1/p step: {nxt:.3g} px per frame > {target:.3g} px; "
                "keeping every frame",
                acc,
            )
        if norm + 0.5 * nxt >= target:
            return self._keep(stamp_s, f"step {norm:.3g} px ~ 1/p = {target:.3g} px", acc)
        self._acc = acc
        return FrameDecision(False, f"step {norm:.3g} px < 1/p = {target:.3g} px", acc, norm)

    def _decide_phase(self, stamp_s: float, acc: Tuple[float, float]) -> FrameDecision:
        """Keep the frame whose sub-pixel phase of ``|acc|`` is within tolerance of ``1/p``."""
        norm = math.hypot(*acc)
        target = self.target_px
        frac = norm - math.floor(norm)
        dist = abs(((frac - target) + 0.5) % 1.0 - 0.5)
        if norm >= target - self.tolerance_px and dist <= self.tolerance_px:
            return self._keep(
                stamp_s,
                f"sub-pixel phase {frac:.3g} px ~ 1/p = {target:.3g} px (total {norm:.3g} px)",
                acc,
            )
        self._acc = acc
        return FrameDecision(
            False,
            f"sub-pixel phase {frac:.3g} px not within {self.tolerance_px:.3g} "
            f"of 1/p = {target:.3g}",
            acc,
            norm,
        )
