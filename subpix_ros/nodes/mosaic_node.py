"""mosaic_node: live overview mosaic for the operator.

Subscribes ``image`` / ``image/compressed``; every frame at least
``min_interval_s`` after the last one taken (queued for the mosaic) is
registered to the previous one and chained into a bounded preview canvas (METHODS.md C). Publishes
``mosaic`` (sensor_msgs/Image bgr8) and ``mosaic/compressed``
(sensor_msgs/CompressedImage, JPEG) at ``publish_rate_hz`` with reliable +
transient-local depth-1 QoS, so an operator tool that joins late gets the
latest mosaic at once. Per-frame seam residuals go to /diagnostics.
"""
from __future__ import annotations

import threading

from sensor_msgs.msg import CompressedImage, Image

from subpix_ros.core.mosaic import Mosaic
from subpix_ros.io import cdr
from subpix_ros.nodes import payloads as pl
from subpix_ros.nodes.base import StageNode
from subpix_ros.nodes.common import Param, camera_qos, latched_qos, run_nodes


class MosaicNode(StageNode):
    MAIN_INPUTS = ("image", "image/compressed")
    PARAMS = (
        Param("camera_reliable", False, "subscribe to the camera with reliable QoS instead of SensorDataQoS"),
        Param("publish_rate_hz", 1.0, "how often the mosaic is published (Hz)", 0.01, 30.0),
        Param("min_interval_s", 0.0, "frames closer in time than this to the last frame taken for the mosaic are "
              "skipped (not counted as dropped)", 0.0, 60.0),
        Param("max_size_px", 2048, "largest side of the preview canvas (px); the scale shrinks to fit", 256, 16384),
        Param("frame_max_px", 1280, "frames are reduced to this larger side before registration and drawing "
              "(0: as received); the preview rarely needs more", 0, 16384),
        Param("jpeg_quality", 85, "JPEG quality of mosaic/compressed", 10, 100),
        Param("queue_size", 2, "frames waiting for the worker; the oldest is dropped beyond this", 1, 100),
    )

    def __init__(self, *, subscribe_inputs: bool = True, name: str = "mosaic_node", **kw) -> None:
        super().__init__(name, subscribe_inputs=subscribe_inputs, **kw)
        self.mosaic = self._new_mosaic()
        self._lock = threading.Lock()
        self._dirty = False
        self._last_taken_ns: int | None = None
        self.skipped = 0
        self._last_stamp_out = 0
        self.added = 0
        self.pub = self.create_publisher(Image, "mosaic", latched_qos())
        self.pub_c = self.create_publisher(CompressedImage, "mosaic/compressed", latched_qos())
        self.make_worker(self._process, self.p("queue_size"))
        self.timer = self.create_timer(1.0 / self.p("publish_rate_hz"), self._publish)
        if subscribe_inputs:
            q = camera_qos(self.p("camera_reliable"), depth=30 if self.p("camera_reliable") else 5)
            self.create_subscription(Image, "image", self._on_image, q, raw=True)
            self.create_subscription(CompressedImage, "image/compressed", self._on_compressed, q, raw=True)

    def _new_mosaic(self) -> Mosaic:
        fmax = self.p("frame_max_px")
        return Mosaic(max_size_px=self.p("max_size_px"), frame_max_px=max(64, fmax) if fmax else None)

    def _on_param_change(self, name: str, value) -> None:
        super()._on_param_change(name, value)
        if name == "publish_rate_hz":
            self.timer.cancel()
            self.timer = self.create_timer(1.0 / value, self._publish)

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
        self.diag.rate("input").tick()
        last = self._last_taken_ns
        if last is not None and 0 <= frame.stamp_ns - last < self.p("min_interval_s") * 1e9:
            self.skipped += 1  # by design (min_interval_s), not a drop
            return
        self._last_taken_ns = frame.stamp_ns  # gate on what was taken, so frames arriving during an add wait their turn
        self.worker.put(frame)

    def reset(self) -> None:
        with self._lock:
            self.mosaic = self._new_mosaic()
            self._last_taken_ns = None
            self.added = 0

    def _process(self, frame: pl.Frame) -> None:
        self.check_time(frame.stamp_ns)
        with self._lock:
            upd = self.mosaic.add(frame.image)
        if not upd.ok:
            self.diag.warn(f"frame not added to the mosaic: {upd.reason}")
            return
        self._last_stamp_out = frame.stamp_ns
        self.added += 1
        self._dirty = True
        self.latency_since(frame.received)
        seam = upd.seam_residual_px
        self.diag.set(frames_added=self.added, frames_skipped=self.skipped, seam_residual_px=float(seam) if seam is not None else "n/a")
        self.diag.stage_time("add_ms", 1000 * float(upd.time_s))
        self.diag.ok()

    def _publish(self) -> None:
        if not self._dirty:
            return
        with self._lock:
            img = self.mosaic.image()
            self._dirty = False
        if img is None or img.size == 0:
            return
        stamp = self._last_stamp_out
        self.pub.publish(pl.image_cdr(img, stamp, "mosaic"))
        self.pub_c.publish(cdr.compressed_to_cdr(img, stamp, "mosaic", "jpeg", self.p("jpeg_quality")))
        self.diag.rate("output").tick()


def main(args=None) -> int:
    return run_nodes([MosaicNode], args)


if __name__ == "__main__":
    raise SystemExit(main())
