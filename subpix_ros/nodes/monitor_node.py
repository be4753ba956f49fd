"""monitor_node: the flight served live to Foxglove.

A thin rclpy adapter of :class:`subpix_ros.monitor.Monitor`.

Subscribes ``mosaic/compressed`` (or ``mosaic`` with ``mosaic_compressed:=false``),
``super_resolved`` (or ``super_resolved/compressed``, as ``subpix process`` records it)
with ``aligned/reference`` (for the bicubic beside it),
``image`` (kept, sent every ``camera_period_s``), ``shift`` with ``shift/std``
(joined by stamp: a shift waits at most ``shift_std_wait_s`` for its errors),
``telemetry/expected_shift``, ``telemetry/frame_interval``, ``telemetry/fix``,
``telemetry/height``, ``telemetry/velocity`` and ``/diagnostics``, and feeds the
monitor, which serves one Foxglove WebSocket server (``ws://host:port``) within
``bandwidth_kbps``. The server refuses to start on a non-loopback ``host``
without ``tls_cert``/``tls_key`` or ``allow_insecure:=true``: the node then
exits with that one line.
"""

from __future__ import annotations

import math
import sys
import threading
import time
from typing import Any

import cv2
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import TwistStamped, Vector3Stamped
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import CompressedImage, Image, NavSatFix
from std_msgs.msg import Float64

from subpix_ros.io import cdr
from subpix_ros.monitor import Monitor, MonitorConfig, MonitorError
from subpix_ros.monitor.encoding import same_as_bicubic
from subpix_ros.monitor.geo import footprint_lonlat
from subpix_ros.monitor.join import ShiftStdJoin
from subpix_ros.nodes.base import StageNode
from subpix_ros.nodes.params import Param
from subpix_ros.nodes.qos import FollowingSubscription, camera_qos, latched_qos, reliable_qos
from subpix_ros.nodes.run import run_nodes
from subpix_ros.nodes.stamps import stamp_to_ns, steady_timer

# the parameters that are the Monitor's own settings (MonitorConfig fields of the same names)
_MONITOR_PARAMS = (
    Param(
        "host",
        "127.0.0.1",
        "address the WebSocket server binds to; anything but loopback needs TLS or allow_insecure",
        read_only=True,
    ),
    Param("port", 8765, "WebSocket port (0: any free port, logged)", 0, 65535, read_only=True),
    Param("tls_cert", "", "PEM certificate file: serve wss:// (with tls_key)", read_only=True),
    Param("tls_key", "", "PEM PKCS#8 private key file matching tls_cert", read_only=True),
    Param(
        "allow_insecure",
        False,
        "serve plain ws:// on a non-loopback host (a trusted link only)",
        read_only=True,
    ),
    Param(
        "bandwidth_kbps",
        2000.0,
        "link budget (kbit/s) for everything served; images degrade to fit it",
        8.0,
        1000000.0,
    ),
    Param(
        "burst_s",
        0.5,
        "largest burst above the budget, seconds of budget",
        0.05,
        10.0,
        read_only=True,
    ),
    Param(
        "backlog_messages",
        64,
        "messages queued per client before the oldest is dropped (stalled clients)",
        4,
        4096,
        read_only=True,
    ),
    Param(
        "mosaic_max_px", 1024, "largest side of the mosaic sent (px), before degradation", 64, 8192
    ),
    Param(
        "mosaic_period_s",
        2.0,
        "the mosaic is sent when it changes, at most this often (s)",
        0.1,
        600.0,
    ),
    Param("sr_crop_px", 512, "side of the super-resolved / bicubic crops (output px)", 32, 8192),
    Param(
        "camera_max_px",
        640,
        "largest side of the camera frame sent (px), before degradation",
        32,
        8192,
    ),
    Param("camera_period_s", 1.0, "the newest camera frame is sent this often (s)", 0.05, 600.0),
    Param(
        "geo_period_s",
        2.0,
        "track and footprints (GeoJSON) at most this often (s); longer on a small link (at most "
        "5 % of bandwidth_kbps)",
        0.1,
        600.0,
    ),
    Param(
        "health_period_s",
        1.0,
        "health table period (s); longer on a small link (at most 10 % of bandwidth_kbps, "
        "but every stale_after_s at least)",
        0.1,
        60.0,
    ),
    Param(
        "values_period_s",
        5.0,
        "every key of every node's status (/health/values) at most this often (s); longer on "
        "a small link (at most 5 % of bandwidth_kbps)",
        0.5,
        600.0,
    ),
    Param(
        "stale_after_s",
        5.0,
        "a node with no /diagnostics status for this long is shown STALE (s)",
        1.0,
        3600.0,
    ),
    Param("max_footprints", 30, "frame footprints kept on the map", 0, 10000),
    Param(
        "track_tolerance_m",
        2.0,
        "the map's GNSS track is thinned to this tolerance (m, Douglas-Peucker; 0: evenly to "
        "500 points)",
        0.0,
        1000.0,
    ),
    Param(
        "record_mcap",
        "",
        "write everything served to this MCAP file (empty: no recording)",
        read_only=True,
    ),
)


class MonitorNode(StageNode):
    """The flight served live to Foxglove: ROS topics in, :class:`Monitor` out."""

    #: declares ``input_timeout_s``; the watch itself (camera and mosaic) is set in ``__init__``
    MAIN_INPUTS = ("image",)

    PARAMS = _MONITOR_PARAMS + (
        Param(
            "mosaic_compressed",
            True,
            "subscribe to mosaic/compressed (JPEG) instead of mosaic (raw)",
            read_only=True,
        ),
        Param(
            "camera_reliable",
            False,
            "subscribe to the camera with reliable QoS instead of SensorDataQoS",
            read_only=True,
        ),
        Param(
            "shift_std_wait_s",
            0.5,
            "a shift waits this long for its standard errors (shift/std), then goes without",
            0.0,
            10.0,
            read_only=True,
        ),
        Param("focal_length_mm", 4.3, "camera focal length (mm), for the footprints", 0.1, 2000.0),
        Param(
            "pixel_pitch_um",
            1.54,
            "detector pixel pitch of the images as published (um)",
            0.1,
            100.0,
        ),
        Param(
            "telemetry_timeout_s",
            3.0,
            "telemetry older than this (s) is not used: shifts go without expected values and no "
            "footprint is drawn at a stale position; silence after telemetry was heard is a WARN",
            0.2,
            3600.0,
        ),
        Param(
            "camera_yaw_offset_deg",
            0.0,
            "compass angle of the image top relative to the course (deg)",
            -180.0,
            180.0,
        ),
    )

    def __init__(self, *, subscribe_inputs: bool = True, name: str = "monitor_node", **kw) -> None:
        super().__init__(name, subscribe_inputs=subscribe_inputs, **kw)
        cfg = MonitorConfig.from_mapping({q.name: self.param(q.name) for q in _MONITOR_PARAMS})
        # MonitorError (exposure, port in use) ends the process in main()
        self.monitor = Monitor(cfg)
        self.get_logger().info(
            f"serving Foxglove on {self.monitor.url} within {cfg.bandwidth_kbps:g} kbit/s"
            + (f", recording {cfg.record_mcap}" if cfg.record_mcap else "")
        )
        self._lock = threading.Lock()
        # reference stamp -> image, for the bicubic beside the SR image
        self._refs: dict[int, object] = {}
        # the latest telemetry, each with the time.monotonic() it arrived (used while fresh)
        self._telemetry: dict[str, tuple[Any, float]] = {}
        self._last_camera_ns = 0
        self._stale_logged: set[str] = set()
        self._telemetry_lost = False
        self._budget_said: str | None = None
        self._fixes_ignored = 0
        # wall time (use_sim_time: /clock stops when a replay ends; a stale node must still be said)
        self._timer = steady_timer(self, 1.0, self._publish_own_health)
        self._shift_join = ShiftStdJoin(self._serve_shift, wait_s=self.param("shift_std_wait_s"))
        self._join_timer = steady_timer(self, 0.1, self._expire_shifts)  # the join waits wall time
        self.diag.set(shifts_without_std=0)  # shown from the start, not only once one is late
        self._subscribe(subscribe_inputs)
        # what the operator looks at: the camera (or the frames handed over in memory) and the
        # mosaic; silence on both is said, whatever else (telemetry, /diagnostics) still arrives
        mosaic = "mosaic/compressed" if self.param("mosaic_compressed") else "mosaic"
        self.diag.watch_inputs(
            ("image", mosaic) if subscribe_inputs else (mosaic,),
            lambda: self.param("input_timeout_s"),
            meter="images",
        )

    def _subscribe(self, stage_inputs: bool) -> None:
        """Subscribe the monitor's inputs.

        The mosaic, telemetry and /diagnostics always come over DDS; the camera, shifts and
        super-resolved images too, unless the single-process pipeline hands them over in memory
        (:meth:`handle_frame`, :meth:`handle_shift`, :meth:`handle_super_resolved`).
        """
        tel = QoSProfile(
            depth=20,
            reliability=ReliabilityPolicy.BEST_EFFORT,
            history=qos_profile_sensor_data.history,
        )
        if self.param("mosaic_compressed"):
            self.create_subscription(
                CompressedImage,
                "mosaic/compressed",
                self._guard(self._on_mosaic_c),
                latched_qos(),
                raw=True,
            )
        else:
            self.create_subscription(
                Image, "mosaic", self._guard(self._on_mosaic), latched_qos(), raw=True
            )
        if stage_inputs:
            self.create_subscription(
                Image,
                "aligned/reference",
                self._guard(self._on_reference),
                latched_qos(4),
                raw=True,
            )
            # transient local or volatile, as the reconstruction's latch_output makes it
            self._sr_subs = (
                FollowingSubscription(
                    self, Image, "super_resolved", self._guard(self._on_sr), raw=True
                ),
                FollowingSubscription(  # what `subpix process` records: replayed results bags
                    self,
                    CompressedImage,
                    "super_resolved/compressed",
                    self._guard(self._on_sr_c),
                    raw=True,
                ),
            )
            self.create_subscription(
                Image,
                "image",
                self._guard(self._on_camera),
                camera_qos(self.param("camera_reliable"), depth=1),
                raw=True,
                event_callbacks=self.events("image")[0],  # frames lost in transport: a WARN
            )
            self.create_subscription(
                Vector3Stamped, "shift", self._guard(self._on_shift), reliable_qos(100), raw=True
            )
            self.create_subscription(
                Vector3Stamped,
                "shift/std",
                self._guard(self._on_shift_std),
                reliable_qos(100),
                raw=True,
            )
        self.create_subscription(
            Vector3Stamped, "telemetry/expected_shift", self._guard(self._on_expected), tel
        )
        self.create_subscription(
            Float64, "telemetry/frame_interval", self._guard(self._on_interval), tel
        )
        self.create_subscription(Float64, "telemetry/height", self._guard(self._on_height), tel)
        self.create_subscription(
            TwistStamped, "telemetry/velocity", self._guard(self._on_velocity), tel
        )
        self.create_subscription(NavSatFix, "telemetry/fix", self._guard(self._on_fix), tel)
        self.create_subscription(
            DiagnosticArray, "/diagnostics", self._guard(self._on_diagnostics), 50
        )

    def _guard(self, fn):
        """Bad input: a diagnostic and a Log entry, the node keeps running."""

        def call(msg) -> None:
            try:
                self.diag.rate("input").tick()
                fn(msg)
            except Exception as exc:  # noqa: BLE001
                text = f"{fn.__name__}: {type(exc).__name__}: {exc}"
                self.diag.error(text)
                self.monitor.on_log(2, text, name=self.diag.name)

        return call

    def _on_param_change(self, name: str, value) -> None:
        super()._on_param_change(name, value)
        if name == "bandwidth_kbps":
            self.monitor.set_bandwidth_kbps(value)
        elif hasattr(self.monitor.cfg, name):
            setattr(self.monitor.cfg, name, value)

    # ---------------------------------------------------------------- images
    def _on_mosaic_c(self, raw: bytes) -> None:
        self.diag.rate("images").tick()
        img, header = cdr.cdr_to_compressed(raw)
        self.monitor.on_mosaic(img, cdr.header_to_ns(header))

    def _on_mosaic(self, raw: bytes) -> None:
        self.diag.rate("images").tick()
        img, header = cdr.cdr_to_image(raw, "bgr8")
        self.monitor.on_mosaic(img.copy(), cdr.header_to_ns(header))

    def _on_reference(self, raw: bytes) -> None:
        img, header = cdr.cdr_to_image(raw)
        with self._lock:
            self._refs[cdr.header_to_ns(header)] = img.copy()
            for k in sorted(self._refs)[:-4]:
                del self._refs[k]

    def _on_sr(self, raw: bytes) -> None:
        sr, header = cdr.cdr_to_image(raw)
        self._sr_received(sr.copy(), header)

    def _on_sr_c(self, raw: bytes) -> None:
        self._sr_received(*cdr.cdr_to_compressed(raw))

    def _sr_received(self, sr, header) -> None:
        stamp = cdr.header_to_ns(header)  # the reference frame's stamp: the image lies on its grid
        with self._lock:
            ref = self._refs.get(stamp)
        self._serve_sr(sr, ref, stamp)

    def _serve_sr(
        self, sr, ref, stamp: int, fallback: str | None = None, known: bool = False
    ) -> None:
        """Serve a super-resolved image beside its reference's bicubic upscale.

        ``fallback``: why the reconstruction fell back; ``known``: the stage said whether it
        did (in memory). Over DDS (not known) an image equal to the bicubic upscale is taken
        for a fallback (:func:`~subpix_ros.monitor.encoding.same_as_bicubic`). Either way a
        fallback is labelled as one, not as super-resolved.
        """
        bic, factor = None, None
        if ref is not None and sr.shape[0] % ref.shape[0] == 0:
            factor = sr.shape[0] // ref.shape[0]
            bic = cv2.resize(ref, (sr.shape[1], sr.shape[0]), interpolation=cv2.INTER_CUBIC)
            if bic.ndim != sr.ndim:
                bic = (
                    cv2.cvtColor(bic, cv2.COLOR_GRAY2BGR)
                    if bic.ndim == 2
                    else cv2.cvtColor(bic, cv2.COLOR_BGR2GRAY)
                )
        if not known and fallback is None and bic is not None and same_as_bicubic(sr, bic):
            fallback = "the image equals the bicubic upscale of its reference"
        self.monitor.on_super_resolved(sr, bic, stamp, factor, fallback)

    def _camera_due(self) -> bool:
        # the camera may come at 30 Hz: take only what the monitor can send (a few per period);
        # wall (steady) time: with use_sim_time a looped replay's clock jumps back
        now = time.monotonic_ns()
        if now - self._last_camera_ns < 0.25e9 * self.monitor.cfg.camera_period_s:
            return False
        self._last_camera_ns = now
        return True

    def _on_camera(self, raw: bytes) -> None:
        self.diag.rate("images").tick()
        if not self._camera_due():
            return
        img, header = cdr.cdr_to_image(raw)
        self._serve_camera(img.copy(), cdr.header_to_ns(header))

    def _serve_camera(self, img, stamp: int) -> None:
        self.monitor.on_camera(img, stamp)
        self._footprint(img.shape[1], img.shape[0], stamp)

    # ---------------------------------------------------- in memory (single-process pipeline)
    def handle_frame(self, frame) -> None:
        """Take a camera frame (``payloads.Frame``) handed over in memory (not written to later)."""
        self.diag.rate("images").tick()
        if self._camera_due():
            self._serve_camera(frame.image, frame.stamp_ns)

    def handle_shift(self, shift_and_frame) -> None:
        """Take the shift stage's ``(payloads.Shift, Aligned)``, with its standard errors."""
        s = shift_and_frame[0]
        e = self._fresh("expected")
        self.monitor.on_shift(
            s.stamp_ns, s.u, s.v, s.u_std, s.v_std, True, e[0] if e else None, e[1] if e else None
        )

    def handle_super_resolved(self, sr) -> None:
        """Take the reconstruction stage's :class:`~subpix_ros.stages.SuperResolved`."""
        why = (sr.reason or "fell back") if sr.fell_back else None
        self._serve_sr(sr.image, sr.reference.image, sr.reference.stamp_ns, why, known=True)

    def _footprint(self, w: int, h: int, stamp: int) -> None:
        fix, height = self._fresh("fix"), self._fresh("height")
        if fix is None or height is None or not height > 0:
            return
        course = self._fresh("course")
        heading = (course or 0.0) + math.radians(self.param("camera_yaw_offset_deg"))
        self.monitor.on_footprint(
            footprint_lonlat(
                fix[0],
                fix[1],
                height,
                heading,
                w,
                h,
                self.param("focal_length_mm"),
                self.param("pixel_pitch_um"),
            ),
            stamp,
        )

    # ---------------------------------------------------------------- numbers
    def _on_shift(self, raw: bytes) -> None:
        vec, header = cdr.cdr_to_vector3_stamped(raw)
        self._shift_join.shift(cdr.header_to_ns(header), float(vec[0]), float(vec[1]))

    def _on_shift_std(self, raw: bytes) -> None:
        vec, header = cdr.cdr_to_vector3_stamped(raw)
        self._shift_join.std(cdr.header_to_ns(header), float(vec[0]), float(vec[1]))

    def _expire_shifts(self) -> None:
        if self._shift_join.expire():
            n = self._shift_join.unmatched
            self.diag.set(shifts_without_std=n)
            self.diag.warn(
                f"{n} shift(s) served without standard errors: no shift/std came within "
                "shift_std_wait_s (is shift_node publishing shift/std?)"
            )

    def _fresh(self, key: str) -> Any:
        """Return the latest telemetry ``key`` unless older than ``telemetry_timeout_s``."""
        value, t = self._telemetry.get(key, (None, -math.inf))
        return value if time.monotonic() - t <= self.param("telemetry_timeout_s") else None

    def _keep(self, key: str, value: Any) -> None:
        self._telemetry[key] = (value, time.monotonic())

    def _telemetry_silence(self) -> float | None:
        """Seconds since the last telemetry, once some was heard (None before)."""
        if not self._telemetry:
            return None
        return time.monotonic() - max(t for _, t in self._telemetry.values())

    def _serve_shift(self, stamp_ns: int, u: float, v: float, u_std, v_std) -> None:
        # the shift topic carries screened estimates only (shift_node's max_std_px): converged
        e = self._fresh("expected")
        self.monitor.on_shift(
            stamp_ns, u, v, u_std, v_std, True, e[0] if e else None, e[1] if e else None
        )

    def _on_expected(self, msg: Vector3Stamped) -> None:
        self._keep("expected", (msg.vector.x, msg.vector.y))
        self._keep("stamp", stamp_to_ns(msg.header.stamp))
        self.monitor.on_telemetry(
            stamp_to_ns(msg.header.stamp), expected_u=msg.vector.x, expected_v=msg.vector.y
        )

    def _on_interval(self, msg: Float64) -> None:
        # Float64 has no stamp: the latest telemetry header's (the same time base as the rest of
        # /telemetry: a replay's, not the wall clock), else the node's clock
        stamp = self._fresh("stamp")
        stamp = self.get_clock().now().nanoseconds if stamp is None else stamp
        self.monitor.on_telemetry(stamp, frame_interval_s=msg.data)

    def _on_height(self, msg: Float64) -> None:
        self._keep("height", float(msg.data))

    def _on_velocity(self, msg: TwistStamped) -> None:
        e, n = msg.twist.linear.x, msg.twist.linear.y  # ENU
        speed = math.hypot(e, n)
        if speed > 0.2:
            self._keep("course", math.atan2(e, n))
        self._keep("stamp", stamp_to_ns(msg.header.stamp))
        self.monitor.on_telemetry(
            stamp_to_ns(msg.header.stamp), speed_mps=speed, height_m=self._fresh("height")
        )

    def _on_fix(self, msg: NavSatFix) -> None:
        finite = math.isfinite(msg.latitude) and math.isfinite(msg.longitude)
        if msg.status.status < 0 or not finite:
            self._fixes_ignored += 1
            self.diag.set(fixes_ignored=self._fixes_ignored)
            why = "not finite" if not finite else f"status {msg.status.status} (no fix)"
            self.diag.warn(f"GNSS fix ignored ({self._fixes_ignored} so far): {why}; no map track")
            return
        self._keep("fix", (msg.latitude, msg.longitude))
        self.monitor.on_fix(
            msg.latitude, msg.longitude, msg.altitude, stamp_to_ns(msg.header.stamp)
        )

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        self.monitor.on_diagnostics(
            {
                "name": s.name,
                "level": s.level[0] if isinstance(s.level, (bytes, bytearray)) else int(s.level),
                "message": s.message,
                "values": {kv.key: kv.value for kv in s.values},
            }
            for s in msg.status
        )

    def _publish_own_health(self) -> None:
        link = self.monitor.link_stats()
        self.diag.set(
            sent_kbps=float(link["sent_kbps"]),
            budget_kbps=float(link["budget_kbps"]),
            essential_kbps=float(link["essential_kbps"]),
            clients=link["clients"],
            **{f"{k}_quality": v["quality"] for k, v in link["levels"].items()},
            **{f"{k}_sent": v["sent"] for k, v in link["levels"].items()},
        )
        stale = {n: a for n, a in self.monitor.stale_nodes().items() if n != self.diag.name}
        quiet = self._telemetry_silence()
        self.diag.set(telemetry_age_s="none heard" if quiet is None else round(quiet, 1))
        lost = quiet is not None and quiet > self.param("telemetry_timeout_s")
        self.diag.set(stale_nodes=", ".join(sorted(stale)) or "none")
        for name in sorted(set(stale) - self._stale_logged):
            self.get_logger().warning(f"no /diagnostics status from {name} for {stale[name]:.0f} s")
        self._stale_logged = set(stale)
        # the essentials alone over the budget: said once in this node's log (and in /log by
        # the monitor), held in the status while it lasts
        over = self.monitor.budget_problem()
        if over and over != self._budget_said:
            self.get_logger().warning(over)
        self._budget_said = over
        if self.monitor.errors:
            self.diag.warn(self.monitor.errors[-1])
        elif stale or lost or over:
            said = [over] if over else []
            if stale:
                said.append(  # no ages in the text: a new text each second is a new Log entry
                    "no /diagnostics status from "
                    + ", ".join(sorted(stale))
                    + f" for over {self.param('stale_after_s'):g} s: stopped, or no longer reachable"
                )
            if lost:
                said.append(
                    f"no telemetry for over {self.param('telemetry_timeout_s'):g} s (link lost?): "
                    "shifts served without expected values, no frame footprints"
                )
            if lost and not self._telemetry_lost:
                self.get_logger().warning(said[-1])
            self.diag.hold_warning("; ".join(said))
        else:
            self.diag.ok()
        self._telemetry_lost = lost

    def close(self) -> None:
        """Stop the node and the monitor's server."""
        super().close()
        self.monitor.close()


def main(args=None) -> int:
    """Run monitor_node (console entry point); 2 when the server refuses to start."""
    try:
        return run_nodes([MonitorNode], args, large_messages=False)  # publishes nothing over DDS
    except MonitorError as exc:
        print(str(exc), file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
