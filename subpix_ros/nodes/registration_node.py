"""registration_node: frame selection from telemetry and automatic co-registration.

Subscribes ``image`` (sensor_msgs/Image) and ``image/compressed``
(sensor_msgs/CompressedImage), and the telemetry node's ``telemetry/velocity``,
``telemetry/height`` and ``telemetry/imu``. Keeps frames so consecutive kept
frames step by about 1/p pixel (every frame when telemetry is absent or
stale, with a diagnostic), registers each kept frame to the current
reference frame and publishes:

* ``aligned`` (sensor_msgs/Image): the frame on the reference grid to pixel
  accuracy, sub-pixel remainder left in; header stamp = the source frame's;
* ``aligned/mask`` (sensor_msgs/Image mono8, 255 = pixel from the frame);
* ``homography`` (std_msgs/Float64MultiArray): 3x3 row-major H mapping the
  source frame's pixel coordinates (x = column, y = row, homogeneous) to the
  reference frame's;
* ``aligned/reference`` (sensor_msgs/Image, reliable + transient local): the
  reference frame, each time a new one starts. Aligned frames belong to the
  latest reference whose stamp is not later than theirs;
* ``aligned/reference_stamp`` (sensor_msgs/TimeReference): per aligned frame,
  header = the frame's, ``time_ref`` = its reference's stamp, so a consumer
  pairs them exactly whatever order the topics arrive in.

A new reference starts on the first frame, after ``max_frames_per_reference``
aligned frames, when registration fails or its quality drops
(inliers, residual, overlap), and, without trying a registration, when the
predicted homography (below) leaves less than half of ``min_overlap``
(a strip of widely spaced frames: counted as ``references_predicted``).

Video-rate tracking (``tracking``, on by default): the reference's luminance,
pyramid and tie points are prepared once per reference
(:func:`~subpix_ros.core.registration.prepare_reference`), and each frame is
registered starting from a predicted homography (the previous frame's,
moved on by the last frame-to-frame motion: constant velocity), which skips
the coarse search; when the prediction is wrong the core falls back to the
full pipeline by itself (counted in /diagnostics as ``tracking_fallbacks``).
"""
from __future__ import annotations

import math
import time

import numpy as np

from geometry_msgs.msg import TwistStamped
from sensor_msgs.msg import CompressedImage, Image, Imu, TimeReference
from std_msgs.msg import Float64, Float64MultiArray

from subpix_ros.core import registration as reg
from subpix_ros.core.motion import MotionTracker
from subpix_ros.core.telemetry import (TelemetryBuffer, TelemetrySample, heading_from_quaternion_enu,
                                       sample_from_enu, validate_sample)
from subpix_ros.core.timing import FrameSelector, expected_shift_px
from subpix_ros.nodes import payloads as pl
from subpix_ros.nodes.base import StageNode
from subpix_ros.nodes.common import (Param, camera_qos, latched_qos, publish_if_subscribed, reliable_qos, run_nodes,
                                    stamp_to_ns)


class RegistrationNode(StageNode):
    MAIN_INPUTS = ("image", "image/compressed")
    PARAMS = (
        Param("camera_reliable", False, "subscribe to the camera with reliable QoS instead of SensorDataQoS"),
        Param("queue_size", 2, "frames waiting for the worker; the oldest is dropped beyond this", 1, 100),
        Param("p", 2.0, "target sub-pixel step between kept frames is 1/p pixel", 2.0, 16.0),
        Param("selection", "step", "frame selection: step (1/p px steps), phase (sub-pixel phase), all",
              choices=("step", "phase", "all")),
        Param("telemetry_timeout_s", 1.0, "telemetry older than this is stale: keep every frame", 0.05, 60.0),
        Param("min_speed_mps", 0.02, "below this ground speed (hover) frame selection keeps every frame", 0.0, 10.0),
        Param("telemetry_time_offset_s", 0.0, "telemetry time = image stamp + this offset (s)", -10.0, 10.0),
        Param("focal_length_mm", 4.3, "camera focal length (mm)", 0.1, 2000.0),
        Param("pixel_pitch_um", 1.54, "detector pixel pitch of the images as published (um)", 0.1, 100.0),
        Param("camera_yaw_offset_deg", 0.0, "compass angle of the image top relative to the vehicle heading (deg)",
              -180.0, 180.0),
        Param("model", "projective", "registration model", choices=("projective", "affine")),
        Param("n_points", 700, "tie points sought per pair (fewer: faster, less accurate)", 50, 5000),
        Param("want_inliers", 200, "a pair with fewer inliers is searched again with extra tie-point candidates "
              "(more accurate on weak texture, slower; 0: never)", 0, 100000),
        Param("distortion", True, "estimate a radial distortion term per pair (off: projective only, faster)"),
        Param("max_frames_per_reference", 8, "aligned frames per reference frame before a new reference", 1, 10000),
        Param("min_inliers", 30, "fewer inlier tie points start a new reference", 4, 100000),
        Param("max_rms_px", 1.5, "a larger inlier RMS residual (px) starts a new reference", 0.01, 50.0),
        Param("min_overlap", 0.3, "a smaller overlap fraction starts a new reference", 0.0, 1.0),
        Param("tracking", True, "register each frame from the previous frame's motion (constant velocity), skipping "
              "the coarse search; falls back to the full search when the prediction is wrong"),
        Param("track_radius_px", 4, "search radius around the predicted position when tracking (px)", 1, 64),
        Param("warp_threshold_px", 0.1, "rotation/perspective beyond this (px at the corners) is warped out", 0.0, 100.0),
    )

    def __init__(self, *, subscribe_inputs: bool = True, name: str = "registration_node", **kw) -> None:
        super().__init__(name, subscribe_inputs=subscribe_inputs, **kw)
        self.selector = self._make_selector()
        self.telemetry = TelemetryBuffer(max_age_s=60.0, stale_after_s=self.p("telemetry_timeout_s"))
        self._height: float | None = None
        self._yaw: float | None = None
        self.reference: pl.Frame | None = None
        self._ref_prepared: reg.ReferenceFrame | None = None
        self.motion = MotionTracker()  # constant-velocity prediction for tracking (core.motion)
        self.tracked = 0
        self.track_fallbacks = 0
        self.since_reference = 0
        self.kept = 0
        self.skipped = 0
        self.failures = 0
        self.references_predicted = 0
        sub_ev, pub_ev = self.events("image")
        self.pub_aligned = self.create_publisher(Image, "aligned", reliable_qos(10), event_callbacks=pub_ev)
        self.pub_mask = self.create_publisher(Image, "aligned/mask", reliable_qos(10))
        self.pub_h = self.create_publisher(Float64MultiArray, "homography", reliable_qos(10))
        self.pub_ref = self.create_publisher(Image, "aligned/reference", latched_qos())
        # which reference each aligned frame belongs to, by stamp (consumers need not infer it from arrival order)
        self.pub_link = self.create_publisher(TimeReference, "aligned/reference_stamp", reliable_qos(10))
        self.make_worker(self._process, self.p("queue_size"))
        if subscribe_inputs:
            qos = camera_qos(self.p("camera_reliable"), depth=30 if self.p("camera_reliable") else 5)
            self.create_subscription(Image, "image", self._on_image, qos, raw=True, event_callbacks=sub_ev)
            self.create_subscription(CompressedImage, "image/compressed", self._on_compressed, qos, raw=True)
            tq = reliable_qos(50)
            self.create_subscription(TwistStamped, "telemetry/velocity", self._on_velocity, tq)
            self.create_subscription(Float64, "telemetry/height", self._on_height, tq)
            self.create_subscription(Imu, "telemetry/imu", self._on_imu, tq)

    def _make_selector(self) -> FrameSelector:
        mode = self.p("selection")
        return FrameSelector(p=self.p("p"), mode="step" if mode == "all" else mode,
                             max_age_s=self.p("telemetry_timeout_s"))

    def _on_param_change(self, name: str, value) -> None:
        super()._on_param_change(name, value)
        if name in ("p", "selection", "telemetry_timeout_s"):
            self.selector = self._make_selector()  # takes effect from the next frame

    # ---------------------------------------------------------------- inputs
    def _on_image(self, raw: bytes) -> None:
        self._enqueue(raw, pl.frame_from_cdr)

    def _on_compressed(self, raw: bytes) -> None:
        self._enqueue(raw, pl.frame_from_compressed_cdr)

    def _enqueue(self, raw: bytes, decode) -> None:
        self.diag.rate("input").tick()
        try:
            frame = decode(raw)
        except Exception as exc:  # noqa: BLE001 - bad input must not kill the node
            self.diag.error(f"bad image dropped: {exc}")
            return
        self.handle_frame(frame)

    def handle_frame(self, frame: pl.Frame) -> None:
        """Queue one frame (called by the subscription or, in the pipeline, directly)."""
        self.worker.put(frame)

    def handle_telemetry(self, sample: TelemetrySample) -> None:
        self.telemetry.add(sample)

    def _on_velocity(self, msg: TwistStamped) -> None:
        if self._height is None:
            return
        v = msg.twist.linear
        self.telemetry.add(sample_from_enu(stamp_to_ns(msg.header.stamp) * 1e-9, (v.x, v.y, v.z), self._height,
                                           heading_rad=self._yaw))

    def _on_height(self, msg: Float64) -> None:
        self._height = float(msg.data) if math.isfinite(msg.data) else None

    def _on_imu(self, msg: Imu) -> None:
        q = msg.orientation
        self._yaw = heading_from_quaternion_enu(q.x, q.y, q.z, q.w)

    # ---------------------------------------------------------------- work
    def reset(self) -> None:
        self.reference = None
        self._ref_prepared = None
        self.motion = MotionTracker()
        self.since_reference = 0
        self.selector.reset()
        self.telemetry = TelemetryBuffer(max_age_s=60.0, stale_after_s=self.p("telemetry_timeout_s"))
        if self.worker is not None:
            self.worker.clear()

    def _image_rate(self, stamp_s: float):
        """Expected image motion (u, v) px/s at the frame's stamp, or (None, reason)."""
        t = stamp_s + self.p("telemetry_time_offset_s")
        s, why = self.telemetry.at(t)
        if s is None:
            return None, f"telemetry: {why}"
        ok, why = validate_sample(s)
        if not ok:
            return None, f"telemetry: {why}"
        if s.ground_speed_mps < self.p("min_speed_mps"):
            return None, f"hovering ({s.ground_speed_mps:.3f} m/s < min_speed_mps)"
        heading = (s.yaw_rad if s.yaw_rad is not None else s.course_rad) + math.radians(self.p("camera_yaw_offset_deg"))
        try:
            rate = expected_shift_px(s.ground_speed_mps, s.course_rad, s.height_agl_m, self.p("focal_length_mm") * 1e-3,
                                     self.p("pixel_pitch_um") * 1e-6, 1.0, heading)
        except ValueError as exc:
            return None, f"telemetry unusable: {exc}"
        return rate, ""

    def _process(self, frame: pl.Frame) -> None:
        self.check_time(frame.stamp_ns)
        if self.p("selection") != "all":
            rate, why = self._image_rate(frame.stamp_s)
            decision = self.selector.decide(frame.stamp_s, rate, None)
            if rate is None:
                self.diag.warn(f"frame selection: {why}; keeping every frame")
            if not decision.keep:
                self.skipped += 1
                self.diag.set(frames_skipped=self.skipped, last_selection=decision.reason)
                return
            self.diag.set(last_selection=decision.reason)
        self.kept += 1
        if self.reference is None or self.since_reference >= self.p("max_frames_per_reference"):
            self._new_reference(frame, "first frame" if self.reference is None else "set complete")
            return
        t0 = time.monotonic()
        prior = self.motion.predict(frame.stamp_s) if self.p("tracking") else None
        if prior is not None:
            ov = reg.overlap_fraction(prior, self.reference.image.shape, frame.image.shape)
            if ov < 0.5 * self.p("min_overlap"):  # would fail on overlap: no full search that cannot succeed
                self.references_predicted += 1
                self.diag.set(references_predicted=self.references_predicted)
                self._new_reference(frame, f"predicted overlap {ov:.2f} < min_overlap / 2")
                return
        result = reg.register(self._ref_prepared, frame.image, model=self.p("model"), n_points=self.p("n_points"),
                              distortion=self.p("distortion"), prior=prior, track_radius=self.p("track_radius_px"),
                              want_inliers=self.p("want_inliers"))
        if prior is not None:
            if result.tracked:
                self.tracked += 1
            else:
                self.track_fallbacks += 1
                self.diag.set(last_tracking_fallback=result.track_failure or "tracking failed")
            self.diag.set(frames_tracked=self.tracked, tracking_fallbacks=self.track_fallbacks)
        why = self._quality_problem(result)
        if why:
            self.motion.forget()
            self.failures += 1
            self.diag.warn(f"registration to reference failed ({why}): new reference")
            self.diag.set(registration_failures=self.failures)
            self._new_reference(frame, why)
            return
        self.motion.update(result.homography, frame.stamp_s)
        al = reg.align(self.reference.image, frame.image, result, warp_threshold_px=self.p("warp_threshold_px"))
        out = pl.Aligned(frame.stamp_ns, al.aligned, al.mask, self.reference, np.asarray(result.homography),
                         tuple(al.prior_shift) if al.prior_shift is not None else None, frame.frame_id, frame.received)
        self.since_reference += 1
        self.pub_link.publish(pl.reference_link_cdr(out.stamp_ns, self.reference.stamp_ns, out.frame_id))
        publish_if_subscribed(self.pub_aligned, lambda: pl.image_cdr(out.image, out.stamp_ns, out.frame_id))
        publish_if_subscribed(self.pub_mask, lambda: pl.mask_cdr(out.mask, out.stamp_ns, out.frame_id))
        self.pub_h.publish(pl.homography_cdr(out.homography))
        self.emit("aligned", out)
        self.diag.rate("output").tick()
        self.latency_since(frame.received)
        ac = result.residual_along_cross()
        self.diag.stage_time("registration_ms", 1000 * (time.monotonic() - t0))
        self.diag.set(inliers=result.inliers, rms_px=float(result.rms_px),
                      frames_kept=self.kept, warped=bool(al.warped),
                      rms_along_px="n/a" if ac is None else ac[0], rms_cross_px="n/a" if ac is None else ac[1])
        self.diag.ok()

    def _quality_problem(self, result) -> str:
        if not result.ok:
            return result.reason or "registration failed"
        if result.inliers < self.p("min_inliers"):
            return f"{result.inliers} inliers < {self.p('min_inliers')}"
        if not result.rms_px <= self.p("max_rms_px"):
            return f"residual {result.rms_px:.2f} px > {self.p('max_rms_px')}"
        if result.overlap < self.p("min_overlap"):
            return f"overlap {result.overlap:.2f} < {self.p('min_overlap')}"
        return ""

    def _new_reference(self, frame: pl.Frame, why: str) -> None:
        self._ref_prepared = reg.prepare_reference(frame.image)  # once per reference, not per frame
        self.motion.restart(frame.stamp_s)  # the chain restarts at the identity; the last motion carries on
        self.reference = frame
        self.since_reference = 0
        self.pub_ref.publish(pl.image_cdr(frame.image, frame.stamp_ns, frame.frame_id))
        self.emit("reference", frame)
        self.diag.set(reference_stamp=f"{frame.stamp_s:.3f}", reference_reason=why)


def main(args=None) -> int:
    return run_nodes([RegistrationNode], args)


if __name__ == "__main__":
    raise SystemExit(main())
