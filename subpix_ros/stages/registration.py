"""RegistrationStage: frame selection, reference keeping, tracking and the quality gate.

Keeps frames so consecutive kept frames step by about 1/p pixel (every frame
when telemetry is absent or stale, with a warning), registers each kept frame
to the current reference frame and returns it aligned to pixel accuracy
(sub-pixel remainder left in). A new reference starts on the first frame,
after ``max_frames_per_reference`` aligned frames, when registration fails or
its quality drops (inliers, residual, overlap), and, without trying a
registration, when the predicted homography leaves less than half of
``min_overlap`` (a strip of widely spaced frames: ``references_predicted``).

Video-rate tracking (``tracking``): the reference's luminance, pyramid and tie
points are prepared once per reference, and each frame is registered from a
predicted homography (the previous frame's moved on by the last
frame-to-frame motion: constant velocity), which skips the coarse search;
when the prediction is wrong the core falls back to the full pipeline by
itself (counted as ``fallbacks``).

The telemetry the selection rests on is checked against the frames: each aligned frame's
displacement and METHODS eq. 1's expectation over the same interval are fitted by a scale and
a rotation over the last ``TELEMETRY_CHECK_PAIRS`` frames (``telemetry_*`` in the stats); a
disagreement (a stream downscaled against ``pixel_pitch_um``, a wrong height or yaw offset)
is a warning naming the parameters that would fit.
"""

from __future__ import annotations

import math
import time
from collections import deque

import numpy as np

from subpix_ros.core import registration as reg
from subpix_ros.core.motion import MotionTracker
from subpix_ros.core.telemetry import TelemetryBuffer, TelemetrySample, validate_sample
from subpix_ros.core.timing import FrameSelector, expected_shift_px
from subpix_ros.core.timing_check import telemetry_agreement, what_would_fit
from subpix_ros.stages.base import Stage
from subpix_ros.stages.params import Spec
from subpix_ros.stages.stats import RegistrationStats
from subpix_ros.stages.types import Aligned, Frame, NewReference, Skipped

#: Aligned frames the live telemetry check fits (the last ones).
TELEMETRY_CHECK_PAIRS = 50
#: Seconds of stamps between two warnings while the telemetry disagrees with the frames.
TELEMETRY_WARN_EVERY_S = 10.0
#: The parameters of METHODS eq. 1's expectation: a change starts the check afresh.
EQ1_PARAMS = (
    "focal_length_mm",
    "pixel_pitch_um",
    "camera_yaw_offset_deg",
    "telemetry_time_offset_s",
    "min_speed_mps",
)

PARAMS = (
    Spec("p", 2.0, "target sub-pixel step between kept frames is 1/p pixel", 2.0, 16.0),
    Spec(
        "selection",
        "step",
        "frame selection: step (1/p px steps), phase (sub-pixel phase), all",
        choices=("step", "phase", "all"),
    ),
    Spec(
        "telemetry_timeout_s",
        1.0,
        "telemetry older than this is stale: keep every frame",
        0.05,
        60.0,
    ),
    Spec(
        "min_speed_mps",
        0.02,
        "below this ground speed (hover) frame selection keeps every frame",
        0.0,
        10.0,
    ),
    Spec(
        "telemetry_time_offset_s",
        0.0,
        "telemetry time = image stamp + this offset (s)",
        -10.0,
        10.0,
    ),
    Spec("focal_length_mm", 4.3, "camera focal length (mm)", 0.1, 2000.0),
    Spec(
        "pixel_pitch_um", 1.54, "detector pixel pitch of the images as published (um)", 0.1, 100.0
    ),
    Spec(
        "camera_yaw_offset_deg",
        0.0,
        "compass angle of the image top relative to the vehicle heading (deg)",
        -180.0,
        180.0,
    ),
    Spec("model", "projective", "registration model", choices=("projective", "affine")),
    Spec("n_points", 700, "tie points sought per pair (fewer: faster, less accurate)", 50, 5000),
    Spec(
        "want_inliers",
        200,
        "a pair with fewer inliers is searched again with extra tie-point "
        "candidates (more accurate on weak texture, slower; 0: never)",
        0,
        100000,
    ),
    Spec(
        "distortion",
        True,
        "estimate a radial distortion term per pair (off: projective only, faster)",
    ),
    Spec(
        "max_frames_per_reference",
        7,
        "aligned frames per reference frame before a new reference (with the reference they "
        "make one set: the reconstruction's n_frames - 1)",
        1,
        10000,
    ),
    Spec("min_inliers", 30, "fewer inlier tie points start a new reference", 4, 100000),
    Spec("max_rms_px", 1.5, "a larger inlier RMS residual (px) starts a new reference", 0.01, 50.0),
    Spec("min_overlap", 0.3, "a smaller overlap fraction starts a new reference", 0.0, 1.0),
    Spec(
        "tracking",
        True,
        "register each frame from the previous frame's motion (constant velocity), "
        "skipping the coarse search; falls back to the full search when the prediction is wrong",
    ),
    Spec(
        "track_radius_px",
        4,
        "search radius around the predicted position when tracking (px)",
        1,
        64,
    ),
    Spec(
        "warp_threshold_px",
        0.1,
        "rotation/perspective beyond this (px at the corners) is warped out",
        0.0,
        100.0,
    ),
)


class RegistrationStage(Stage):
    """Frame selection and co-registration to a reference frame, without ROS.

    ``add(frame)`` returns :class:`Aligned` (registered to the current
    reference), :class:`NewReference` (the frame starts a reference set) or
    :class:`Skipped` (``reason`` ``"selection"``: frame selection left it out).
    """

    PARAMS = PARAMS
    STATS = RegistrationStats
    SELECTOR_PARAMS = ("p", "selection", "telemetry_timeout_s")

    def __init__(self, **params) -> None:
        super().__init__(**params)
        self.selector = self._make_selector()
        self.telemetry = self._make_buffer()
        self.reference: Frame | None = None
        self._ref_prepared: reg.ReferenceFrame | None = None
        self.motion = MotionTracker()  # constant-velocity prediction for tracking (core.motion)
        self.since_reference = 0
        # (measured, expected) shifts of the last aligned frames: METHODS eq. 1 checked
        self._motion_pairs: deque = deque(maxlen=TELEMETRY_CHECK_PAIRS)
        self._next_check_warning_s = -math.inf
        self._previous_ns: int | None = None  # the last frame's stamp given to add

    def _make_selector(self) -> FrameSelector:
        mode = self.param("selection")
        return FrameSelector(
            p=self.param("p"),
            mode="step" if mode == "all" else mode,
            max_age_s=self.param("telemetry_timeout_s"),
        )

    def _make_buffer(self) -> TelemetryBuffer:
        """Return an empty telemetry buffer (stale after ``telemetry_timeout_s``)."""
        return TelemetryBuffer(max_age_s=60.0, stale_after_s=self.param("telemetry_timeout_s"))

    def configure(self, **changes) -> None:
        """Change parameters at run time; a new frame selector when its parameters change."""
        super().configure(**changes)
        if any(k in self.SELECTOR_PARAMS for k in changes):
            self.selector = self._make_selector()  # takes effect from the next frame
        if "telemetry_timeout_s" in changes:  # the samples kept stay
            self.telemetry.stale_after_s = float(self.param("telemetry_timeout_s"))
        if any(k in EQ1_PARAMS for k in changes):  # expectations of other parameters
            self._forget_motion_check()

    def add_telemetry(self, sample: TelemetrySample) -> None:
        """Keep a telemetry sample for frame selection."""
        self.telemetry.add(sample)

    def reset(self) -> None:
        """Forget the reference, the motion, the selection and the telemetry."""
        super().reset()
        self.reference = None
        self._ref_prepared = None
        self.motion = MotionTracker()
        self.since_reference = 0
        self.selector.reset()
        self.telemetry = self._make_buffer()
        self._forget_motion_check()

    def _forget_motion_check(self) -> None:
        """Start the telemetry check afresh (new parameters, a reset)."""
        self._motion_pairs.clear()
        self._next_check_warning_s = -math.inf
        st = self.stats
        st.telemetry_pairs, st.telemetry_agrees, st.telemetry_check = 0, None, ""
        st.telemetry_scale = st.telemetry_rotation_deg = None

    def _check_motion(self, frame: Frame, homography: np.ndarray) -> None:
        """Add the aligned frame's shift and the telemetry's expected one; refit; warn if off.

        The frames' shift is the homography's displacement of the reference's centre; the
        expected one METHODS eq. 1 over the interval (the image rates at both stamps averaged),
        as ``subpix process``'s report fits them (:func:`telemetry_agreement`). While they
        disagree a warning names the parameters, at most every ``TELEMETRY_WARN_EVERY_S`` s of
        stamps.
        """
        ref = self.reference
        measured = reg.centre_shift(homography, ref.image.shape)
        rate_ref, _ = self._image_rate(ref.stamp_s)
        rate, _ = self._image_rate(frame.stamp_s)
        if measured is None or rate_ref is None or rate is None:
            return
        dt = frame.stamp_s - ref.stamp_s
        expected = (0.5 * (rate_ref[0] + rate[0]) * dt, 0.5 * (rate_ref[1] + rate[1]) * dt)
        self._motion_pairs.append((measured, expected))
        pairs = np.array(self._motion_pairs, dtype=np.float64)
        check = telemetry_agreement(pairs[:, 0], pairs[:, 1])
        st = self.stats
        st.telemetry_pairs, st.telemetry_agrees, st.telemetry_check = (
            check.pairs,
            check.agrees,
            check.reason,
        )
        st.telemetry_scale, st.telemetry_rotation_deg = check.scale, check.rotation_deg
        if check.agrees is False and frame.stamp_s >= self._next_check_warning_s:
            self._next_check_warning_s = frame.stamp_s + TELEMETRY_WARN_EVERY_S
            advice = what_would_fit(
                check,
                self.param("focal_length_mm"),
                self.param("pixel_pitch_um"),
                self.param("camera_yaw_offset_deg"),
            )
            self.warn(f"telemetry {check.reason}: {advice}")

    # ---------------------------------------------------------------- selection
    def _image_rate(self, stamp_s: float):
        """Return the expected image motion (u, v) px/s at the frame's stamp, or (None, reason)."""
        sample, why = self.telemetry.at(stamp_s + self.param("telemetry_time_offset_s"))
        if sample is None:  # ("telemetry stale: ...", "telemetry unusable: ..." said as they are)
            return None, why if why.startswith("telemetry") else f"telemetry: {why}"
        ok, why = validate_sample(sample)
        if not ok:
            return None, f"telemetry: {why}"
        if sample.ground_speed_mps < self.param("min_speed_mps"):
            return None, f"hovering ({sample.ground_speed_mps:.3f} m/s < min_speed_mps)"
        heading = (
            sample.yaw_rad if sample.yaw_rad is not None else sample.course_rad
        ) + math.radians(self.param("camera_yaw_offset_deg"))
        try:
            rate = expected_shift_px(
                sample.ground_speed_mps,
                sample.course_rad,
                sample.height_agl_m,
                self.param("focal_length_mm") * 1e-3,
                self.param("pixel_pitch_um") * 1e-6,
                1.0,
                heading,
            )
        except ValueError as exc:
            return None, f"telemetry unusable: {exc}"
        return rate, ""

    def _select(self, frame: Frame) -> Skipped | None:
        if self.param("selection") == "all":
            return None
        rate, why = self._image_rate(frame.stamp_s)
        decision = self.selector.decide(frame.stamp_s, rate, None)
        if rate is None:
            self.warn(f"frame selection: {why}; keeping every frame")
        self.stats.last_selection = decision.reason
        if decision.keep:
            return None
        self.stats.skip("selection")
        return Skipped(frame.stamp_ns, "selection", decision.reason)

    # ---------------------------------------------------------------- registration
    def add(self, frame: Frame) -> Aligned | NewReference | Skipped:
        """Select, register and align one frame (see the class docstring)."""
        self.stats.frames_in += 1
        if frame.stamp_ns == self._previous_ns:  # (a node checks the time before add)
            return self._duplicate(frame)
        self._previous_ns = frame.stamp_ns
        self.check_time(frame.stamp_ns)
        skipped = self._select(frame)
        if skipped is not None:
            return skipped
        self.stats.kept += 1
        if self.reference is None or self.since_reference >= self.param("max_frames_per_reference"):
            return self._new_reference(
                frame, "first frame" if self.reference is None else "set complete"
            )
        t0 = time.monotonic()
        prior = self.motion.predict(frame.stamp_s) if self.param("tracking") else None
        if prior is not None:
            ov = reg.overlap_fraction(prior, self.reference.image.shape, frame.image.shape)
            if ov < 0.5 * self.param(
                "min_overlap"
            ):  # would fail on overlap: no search that cannot succeed
                self.stats.references_predicted += 1
                return self._new_reference(
                    frame, f"predicted overlap {ov:.2f} < min_overlap / 2", predicted=True
                )
        result = reg.register(
            self._ref_prepared,
            frame.image,
            model=self.param("model"),
            n_points=self.param("n_points"),
            distortion=self.param("distortion"),
            prior=prior,
            track_radius=self.param("track_radius_px"),
            want_inliers=self.param("want_inliers"),
        )
        if prior is not None:
            if result.tracked:
                self.stats.tracked += 1
            else:
                self.stats.fallbacks += 1
                self.stats.last_tracking_fallback = result.track_failure or "tracking failed"
        why = self.quality_problem(result)
        if why:
            self.motion.forget()
            self.stats.registration_failures += 1
            self.warn(f"registration to reference failed ({why}): new reference")
            return self._new_reference(frame, why)
        self.motion.update(result.homography, frame.stamp_s)
        al = reg.align(
            self.reference.image,
            frame.image,
            result,
            warp_threshold_px=self.param("warp_threshold_px"),
        )
        out = Aligned(
            frame.stamp_ns,
            al.aligned,
            al.mask if al.box is None else None,  # an integer crop: its rectangle only
            self.reference,
            np.asarray(result.homography),
            tuple(al.prior_shift) if al.prior_shift is not None else None,
            frame.frame_id,
            frame.received,
            box=al.box,
        )
        self.since_reference += 1
        self._check_motion(frame, result.homography)
        ac = result.residual_along_cross()
        st = self.stats
        st.times.add(1000 * (time.monotonic() - t0))
        st.inliers, st.rms_px, st.warped = result.inliers, float(result.rms_px), bool(al.warped)
        st.rms_along_px, st.rms_cross_px = (
            (None, None) if ac is None else (float(ac[0]), float(ac[1]))
        )
        return out

    def _duplicate(self, frame: Frame) -> Skipped:
        """Leave out a frame whose stamp repeats the previous frame's, and say so.

        Every output downstream (shift, homography, the sets' members) is matched by its
        source frame's stamp; a second frame of one stamp would overwrite the first's or be
        paired with it. A camera driver that leaves its images unstamped gives this on every
        frame.
        """
        self.stats.skip("duplicate_stamp")
        why = (
            f"stamp {frame.stamp_ns} ns repeats the previous frame's: left out (outputs are "
            "matched by stamp; does the camera driver stamp its images?)"
        )
        self.warn(f"frame {why}")
        return Skipped(frame.stamp_ns, "duplicate_stamp", why)

    def quality_problem(self, result) -> str:
        """Why a registration result is not good enough to align to (empty if it is)."""
        if not result.ok:
            return result.reason or "registration failed"
        if result.inliers < self.param("min_inliers"):
            return f"{result.inliers} inliers < {self.param('min_inliers')}"
        if not result.rms_px <= self.param("max_rms_px"):
            return f"residual {result.rms_px:.2f} px > {self.param('max_rms_px')}"
        if result.overlap < self.param("min_overlap"):
            return f"overlap {result.overlap:.2f} < {self.param('min_overlap')}"
        return ""

    def _new_reference(self, frame: Frame, why: str, predicted: bool = False) -> NewReference:
        self._ref_prepared = reg.prepare_reference(frame.image)  # once per reference, not per frame
        self.motion.restart(
            frame.stamp_s
        )  # the chain restarts at the identity; the motion carries on
        self.reference = frame
        self.since_reference = 0
        self.stats.references += 1
        self.stats.reference_stamp_ns = frame.stamp_ns
        self.stats.reference_reason = why
        return NewReference(frame, why, predicted)
