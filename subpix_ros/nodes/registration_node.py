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

The policy (when a new reference starts, video-rate tracking and its
fallback, the quality gate) is :class:`~subpix_ros.stages.RegistrationStage`'s;
tracking fallbacks are counted in /diagnostics as ``tracking_fallbacks``,
references started from the predicted overlap as ``references_predicted``.
"""

from __future__ import annotations

from geometry_msgs.msg import TwistStamped
from sensor_msgs.msg import CompressedImage, Image, Imu, TimeReference
from std_msgs.msg import Float64, Float64MultiArray

from subpix_ros.core.telemetry import TelemetrySample
from subpix_ros.io.telemetry_msgs import TelemetryFromTopics
from subpix_ros.nodes import payloads as pl
from subpix_ros.nodes.base import StageNode, ros_params
from subpix_ros.nodes.params import Param
from subpix_ros.nodes.qos import (
    SequenceGaps,
    camera_qos,
    latched_qos,
    publish_if_subscribed,
    reliable_qos,
)
from subpix_ros.nodes.run import run_nodes
from subpix_ros.stages import Aligned, NewReference, RegistrationStage, Skipped

LINK_HISTORY = 100  # aligned/reference_stamp messages a late-joining consumer still gets


class RegistrationNode(StageNode):
    """The registration stage as a node: camera frames and telemetry in, aligned frames out."""

    MAIN_INPUTS = ("image", "image/compressed")
    CAMERA_INPUT = True
    PARAMS = (
        Param(
            "camera_reliable",
            False,
            "subscribe to the camera with reliable QoS instead of SensorDataQoS",
            read_only=True,
        ),
        Param(
            "queue_size",
            2,
            "frames waiting for the worker; the oldest is dropped beyond this",
            1,
            100,
        ),
        *ros_params(RegistrationStage.PARAMS),
    )

    def __init__(
        self, *, subscribe_inputs: bool = True, name: str = "registration_node", **kw
    ) -> None:
        super().__init__(name, subscribe_inputs=subscribe_inputs, **kw)
        self.make_stage(RegistrationStage)
        self.topics_telemetry = TelemetryFromTopics()  # height and heading kept for velocities
        q = reliable_qos(10)
        self.pub_aligned = self.create_publisher(
            Image, "aligned", q, event_callbacks=self.output_events("aligned")
        )
        self.pub_mask = self.create_publisher(
            Image, "aligned/mask", q, event_callbacks=self.output_events("aligned/mask")
        )
        self.pub_h = self.create_publisher(
            Float64MultiArray, "homography", q, event_callbacks=self.output_events("homography")
        )
        self.pub_ref = self.create_publisher(Image, "aligned/reference", latched_qos())
        # each aligned frame's reference, by stamp (consumers need not infer it from arrival order);
        # transient local, the last 100 kept: a consumer whose link reader matches after its frame
        # reader still gets the links of the frames it received
        self.pub_link = self.create_publisher(
            TimeReference, "aligned/reference_stamp", latched_qos(LINK_HISTORY)
        )
        self.make_worker(self._process, self.param("queue_size"))
        if subscribe_inputs:
            # best effort keeps 10 frames (333 ms at 30 Hz) for the executor to take: with 5, a
            # 30 Hz burst on a loaded 2-core machine lost 35-45 % of the frames in some runs
            depth = 30 if self.param("camera_reliable") else 10
            qos = camera_qos(self.param("camera_reliable"), depth=depth)
            # frames that never reached the callback (transport, or replaced in the history)
            self.camera_gaps = {}
            for msg_type, topic, callback in (
                (Image, "image", self._on_image),
                (CompressedImage, "image/compressed", self._on_compressed),
            ):
                gaps = SequenceGaps(self, topic, self.diag, depth, "camera frames")
                gaps.subscribe(msg_type, callback, qos, event_callbacks=self.events(topic)[0])
                self.camera_gaps[topic] = gaps
            tq = reliable_qos(50)
            self.create_subscription(TwistStamped, "telemetry/velocity", self._on_velocity, tq)
            self.create_subscription(Float64, "telemetry/height", self._on_height, tq)
            self.create_subscription(Imu, "telemetry/imu", self.topics_telemetry.imu, tq)

    # the stage's state and counters, by their former names
    selector = property(lambda self: self.stage.selector)
    telemetry = property(lambda self: self.stage.telemetry)
    reference = property(lambda self: self.stage.reference)
    kept = property(lambda self: self.stage.stats.kept)
    skipped = property(lambda self: self.stage.stats.skipped)
    tracked = property(lambda self: self.stage.stats.tracked)
    track_fallbacks = property(lambda self: self.stage.stats.fallbacks)
    failures = property(lambda self: self.stage.stats.registration_failures)
    references_predicted = property(lambda self: self.stage.stats.references_predicted)

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
        self.camera_frame_received(frame.stamp_ns)
        self.handle_frame(frame)

    def handle_frame(self, frame: pl.Frame) -> None:
        """Queue one frame for registration.

        Called by the subscription or, in the pipeline, directly; listeners of ``frame`` (the
        pipeline's mosaic) get it too.
        """
        self.worker.put(frame)
        self.emit("frame", frame)

    def handle_telemetry(self, sample: TelemetrySample) -> None:
        """Hand a telemetry sample to the stage."""
        self.stage.add_telemetry(sample)

    def _on_velocity(self, msg: TwistStamped) -> None:
        sample = self.topics_telemetry.velocity(msg)
        if sample is not None:
            self.handle_telemetry(sample)

    def _on_height(self, msg: Float64) -> None:
        sample = self.topics_telemetry.height(msg)  # a velocity held for the first height
        if sample is not None:
            self.handle_telemetry(sample)

    # ---------------------------------------------------------------- work
    def _process(self, frame: pl.Frame) -> None:
        self.check_time(frame.stamp_ns)
        out = self.stage.add(frame)
        st = self.stage.stats
        if st.last_selection:
            self.diag.set(last_selection=st.last_selection)
        if isinstance(out, Skipped):
            self.diag.set(frames_skipped=st.skipped)
        elif isinstance(out, NewReference):
            self.pub_ref.publish(pl.image_cdr(frame.image, frame.stamp_ns, frame.frame_id))
            self.emit("reference", frame)
            self.diag.set(
                reference_stamp=f"{frame.stamp_s:.3f}",
                reference_reason=out.reason,
                references_predicted=st.references_predicted,
                registration_failures=st.registration_failures,
            )
        elif isinstance(out, Aligned):
            self._publish(out)
        self.diag.set(frames_tracked=st.tracked, tracking_fallbacks=st.fallbacks)
        if st.last_tracking_fallback:
            self.diag.set(last_tracking_fallback=st.last_tracking_fallback)

    def _publish(self, out: Aligned) -> None:
        self.pub_link.publish(
            pl.reference_link_cdr(out.stamp_ns, out.reference.stamp_ns, out.frame_id)
        )
        publish_if_subscribed(
            self.pub_aligned, lambda: pl.image_cdr(out.image, out.stamp_ns, out.frame_id)
        )
        publish_if_subscribed(
            self.pub_mask, lambda: pl.mask_cdr(out.valid_mask(), out.stamp_ns, out.frame_id)
        )
        self.pub_h.publish(pl.homography_cdr(out.homography))
        st = self.stage.stats
        self.output(
            "aligned",
            out,
            out.received,
            "registration_ms",
            inliers=st.inliers,
            rms_px=st.rms_px,
            frames_kept=st.kept,
            warped=st.warped,
            rms_along_px=_na(st.rms_along_px),
            rms_cross_px=_na(st.rms_cross_px),
            telemetry_check=st.telemetry_check or "no frame pair with telemetry yet",
            telemetry_scale=_na(st.telemetry_scale),
            telemetry_rotation_deg=_na(st.telemetry_rotation_deg),
        )
        if st.telemetry_agrees is False:  # lasting: the stage's warning says what to change
            self.diag.hold_warning(f"telemetry {st.telemetry_check}")
        else:
            self.diag.ok()


def _na(value):
    return "n/a" if value is None else value


def main(args=None) -> int:
    """Run the registration node (console entry point)."""
    return run_nodes([RegistrationNode], args)


if __name__ == "__main__":
    raise SystemExit(main())
