"""mosaic_node: live overview mosaic for the operator.

Subscribes ``image`` / ``image/compressed``; every frame at least
``min_interval_s`` after the last one taken (queued for the mosaic) is
registered to the previous one and chained into a bounded preview canvas
(METHODS.md C; :class:`~subpix_ros.stages.MosaicStage`). Publishes
``mosaic`` (sensor_msgs/Image bgr8) and ``mosaic/compressed``
(sensor_msgs/CompressedImage, JPEG) at ``publish_rate_hz`` with reliable +
transient-local depth-1 QoS, so an operator tool that joins late gets the
latest mosaic at once. Per-frame seam residuals go to /diagnostics.
"""

from __future__ import annotations

from sensor_msgs.msg import CompressedImage, Image

from subpix_ros.io import cdr
from subpix_ros.nodes import payloads as pl
from subpix_ros.nodes.base import StageNode, ros_params
from subpix_ros.nodes.params import Param
from subpix_ros.nodes.qos import camera_qos, latched_qos
from subpix_ros.nodes.run import run_nodes
from subpix_ros.nodes.stamps import steady_timer
from subpix_ros.stages import MosaicStage


class MosaicNode(StageNode):
    """The mosaic stage as a node: camera frames in, the mosaic preview out."""

    MAIN_INPUTS = ("image", "image/compressed")
    PARAMS = (
        Param(
            "camera_reliable",
            False,
            "subscribe to the camera with reliable QoS instead of SensorDataQoS",
            read_only=True,
        ),
        Param(
            "publish_rate_hz",
            1.0,
            "how often the mosaic is published (Hz, wall time: also once /clock stops)",
            0.01,
            30.0,
        ),
        *ros_params(MosaicStage.PARAMS),
        Param("jpeg_quality", 85, "JPEG quality of mosaic/compressed", 10, 100),
        Param(
            "queue_size",
            2,
            "frames waiting for the worker; the oldest is dropped beyond this",
            1,
            100,
        ),
    )

    def __init__(self, *, subscribe_inputs: bool = True, name: str = "mosaic_node", **kw) -> None:
        super().__init__(name, subscribe_inputs=subscribe_inputs, **kw)
        self.make_stage(MosaicStage)
        self._dirty = False
        self.pub = self.create_publisher(
            Image, "mosaic", latched_qos(), event_callbacks=self.output_events("mosaic")
        )
        self.pub_c = self.create_publisher(
            CompressedImage,
            "mosaic/compressed",
            latched_qos(),
            event_callbacks=self.output_events("mosaic/compressed"),
        )
        self.make_worker(self._process, self.param("queue_size"))
        # wall time: with use_sim_time the node's clock stops with /clock (a replay that ended),
        # and the last frames' mosaic must still be published
        self.timer = steady_timer(self, 1.0 / self.param("publish_rate_hz"), self._publish)
        if subscribe_inputs:
            q = camera_qos(
                self.param("camera_reliable"), depth=30 if self.param("camera_reliable") else 5
            )
            self.create_subscription(
                Image, "image", self._on_image, q, raw=True, event_callbacks=self.events("image")[0]
            )
            self.create_subscription(
                CompressedImage,
                "image/compressed",
                self._on_compressed,
                q,
                raw=True,
                event_callbacks=self.events("image/compressed")[0],
            )

    mosaic = property(lambda self: self.stage.mosaic)
    skipped = property(lambda self: self.stage.stats.skipped)
    added = property(lambda self: self.stage.stats.in_canvas)

    def _on_param_change(self, name: str, value) -> None:
        super()._on_param_change(name, value)
        if name == "publish_rate_hz":
            self.timer.cancel()
            self.destroy_timer(self.timer)
            self.timer = steady_timer(self, 1.0 / value, self._publish)

    def _on_image(self, raw: bytes) -> None:
        self._decode(raw, pl.frame_from_cdr)

    def _on_compressed(self, raw: bytes) -> None:
        self._decode(raw, pl.frame_from_compressed_cdr)

    def _decode(self, raw: bytes, decode) -> None:
        try:
            frame = decode(raw)
        except Exception as exc:  # noqa: BLE001
            self.diag.error(f"bad image dropped: {exc}")
            return
        self.handle_frame(frame)

    def handle_frame(self, frame: pl.Frame) -> None:
        """Queue a frame that passes the stage's interval gate."""
        self.diag.rate("input").tick()
        if self.stage.take(frame):  # the min_interval_s gate, by stamp (a skip is not a drop)
            self.worker.put(frame)

    def reset(self) -> None:
        """Start a new mosaic (time jumped back)."""
        self.stage.reset()  # frames queued behind the one that jumped back belong to the new stream

    def _process(self, frame: pl.Frame) -> None:
        self.check_time(frame.stamp_ns)
        if not self.stage.draw(frame):
            return
        self._dirty = True
        self.latency_since(frame.received)
        st = self.stage.stats
        seam = "n/a" if st.seam_residual_px is None else st.seam_residual_px
        self.diag.set(frames_added=st.in_canvas, frames_skipped=st.skipped, seam_residual_px=seam)
        self.diag.stage_time("add_ms", st.times.last)
        self.diag.ok()

    def _publish(self) -> None:
        if not self._dirty:
            return
        self._dirty = False
        img = self.stage.canvas()
        if img is None:
            return
        stamp = self.stage.last_stamp_ns
        self.pub.publish(pl.image_cdr(img, stamp, "mosaic"))
        self.pub_c.publish(
            cdr.compressed_to_cdr(img, stamp, "mosaic", "jpeg", self.param("jpeg_quality"))
        )
        self.diag.rate("output").tick()


def main(args=None) -> int:
    """Run the mosaic node (console entry point)."""
    return run_nodes([MosaicNode], args)


if __name__ == "__main__":
    raise SystemExit(main())
