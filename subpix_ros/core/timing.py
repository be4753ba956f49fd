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
    try:
        return math.isfinite(float(x)) and float(x) > 0.0
    except (TypeError, ValueError):
        return False


@dataclass
class IntervalResult:
    """Outcome of :func:`frame_interval`.

    ``interval_s`` is None when ``ok`` is False (``reason`` says why).
    ``shift_px_per_s`` is the image speed ``f V / (H a)`` (pixels/s) and
    ``step_px`` the along-track image displacement during ``interval_s``
    (``cos(phi) / p`` pixels by construction of eq. 1).
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
        return math.degrees(self.phi_rad)

    def as_dict(self) -> dict:
        d = asdict(self)
        d["phi_deg"] = self.phi_deg
        return d


def detector_angle(p: float) -> float:
    """Detector rotation for ``p`` sub-pixel steps, METHODS.md B eq. (2).

    ``phi = arctan(1 / (p - 1))`` radians: the image then steps ``1/p`` pixel
    across and ``(p - 1)/p`` pixel along the detector's long axis. Raises
    ``ValueError`` for ``p < 2`` or non-finite ``p`` (p = 1 would need 90 deg,
    i.e. no sub-pixel step at all).
    """
    if not (isinstance(p, (int, float)) and math.isfinite(p)) or p < 2:
        raise ValueError(f"p must be a finite number >= 2 (got {p!r})")
    return math.atan(1.0 / (p - 1.0))


def image_speed_px_s(
    speed_mps: float, height_m: float, focal_length_m: float, pixel_pitch_m: float
) -> float:
    """Image motion rate ``s = f V / (H a)`` in pixels per second (METHODS.md B, text of eq. 1).

    ``speed_mps`` may be 0 (hovering); negative or non-finite speed, and
    non-positive height, focal length or pitch raise ``ValueError``.
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
    """Time between frames for a ``1/p`` pixel step, METHODS.md B eq. (1).

    ``t = a H cos(phi) / (p f V)`` seconds with ``a`` the pixel pitch (m),
    ``H`` the height above ground (m), ``f`` the focal length (m), ``V`` the
    ground speed (m/s) and ``phi`` (rad) the angle between the detector's
    long axis and the ground-track velocity (use :func:`detector_angle` for
    eq. 2). During ``t`` the image moves ``f V t / (H a) = cos(phi)/p`` pixels.

    Returns ``ok=False`` with a reason (never a negative, zero or infinite
    time) when V <= 0 or non-finite, H, f or a <= 0 or non-finite, p < 2, or
    ``cos(phi) <= 0`` (|phi| >= 90 deg).
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
            f"ground speed {speed_mps:g} m/s <= 0: the carrier does not move, no interval gives a 1/p step"
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
            f"cos(phi) <= 0 for phi = {math.degrees(phi):g} deg: the detector axis is across the track"
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
    """Expected scene shift ``(u, v)`` (rows, cols; pixels) over ``dt_s`` seconds.

    ``u = s dt cos(course - heading)``, ``v = -s dt sin(course - heading)``
    with ``s = f V / (H a)`` (see the module docstring for the angle
    convention: compass angles, clockwise from north; ``image_heading_rad``
    is where the image's top points). Raises ``ValueError`` on non-finite or
    out-of-range input (negative speed, non-positive height/f/pitch,
    negative dt).
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

    ``step_px`` is the (u, v) shift predicted since the last kept frame (None
    when unknown), ``step_norm_px`` its length.
    """

    keep: bool
    reason: str
    step_px: Optional[Tuple[float, float]] = None
    step_norm_px: Optional[float] = None

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass
class FrameSelector:
    """Which frames of a fixed-rate stream to keep so kept frames step by ~1/p px.

    The inverse of eq. (1): instead of choosing the frame interval, the
    selector integrates the expected image motion (pixels/s, from telemetry
    via :func:`expected_shift_px` with ``dt_s=1``) between frames and keeps a
    frame when the predicted shift since the last kept frame is the closest
    it will get to the target.

    Modes
    -----
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
        """Keep or skip the frame stamped ``stamp_s`` (seconds).

        ``rate_px_s`` is the expected image motion (u, v) in pixels per second
        (e.g. ``expected_shift_px(..., dt_s=1.0)``), or None without
        telemetry; ``rate_stamp_s`` the time that telemetry refers to (None:
        assumed current).
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
                    f"telemetry stale ({age:.3g} s old > {self.max_age_s:g} s): keeping every frame",
                    None,
                )
        # Integrate the motion since the previous frame (kept or not).
        acc = (self._acc[0] + ru * dt, self._acc[1] + rv * dt)
        self._prev_stamp = stamp_s
        norm = math.hypot(*acc)
        nxt = math.hypot(ru, rv) * dt
        target = self.target_px
        if self.mode == "step":
            if nxt > target + self.tolerance_px:
                return self._keep(
                    stamp_s,
                    f"frame rate too low for a 1/p step: {nxt:.3g} px per frame > {target:.3g} px; keeping every frame",
                    acc,
                )
            if norm + 0.5 * nxt >= target:
                return self._keep(stamp_s, f"step {norm:.3g} px ~ 1/p = {target:.3g} px", acc)
            self._acc = acc
            return FrameDecision(False, f"step {norm:.3g} px < 1/p = {target:.3g} px", acc, norm)
        # phase mode
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
            f"sub-pixel phase {frac:.3g} px not within {self.tolerance_px:.3g} of 1/p = {target:.3g}",
            acc,
            norm,
        )
