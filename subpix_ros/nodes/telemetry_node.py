"""telemetry_node: MAVLink (or mavros) telemetry in, ROS telemetry and frame timing out.

Source ``mavlink`` (default): a pymavlink connection given by ``connection``
(``udpin:127.0.0.1:14550``, ``udpout:HOST:PORT``, ``tcp:HOST:PORT``, a serial
device with ``baud``, or a ``.tlog`` file to replay), read on its own thread
with heartbeat and link-loss detection. Source ``mavros``: the same inputs
from mavros' standard-message topics (``mavros_*`` parameters).

Publishes (relative names): ``telemetry/fix`` (NavSatFix), ``telemetry/velocity``
(TwistStamped, ENU, REP-103), ``telemetry/height`` (Float64, m above ground),
``telemetry/imu`` (Imu, orientation only), ``telemetry/frame_interval``
(Float64, s: METHODS.md eq. 1 for the configured camera, published only when
defined), ``telemetry/detector_angle`` (Float64, rad: eq. 2 for p, latched) and
``telemetry/expected_shift`` (Vector3Stamped: x = u rows, y = v columns, in
pixels per camera frame at ``camera_rate_hz``; z = image speed, px/s).
"""

from __future__ import annotations

import dataclasses
import math
import threading
import time
from pathlib import Path

from geometry_msgs.msg import TwistStamped, Vector3Stamped
from sensor_msgs.msg import Imu, NavSatFix
from std_msgs.msg import Float64

from subpix_ros.core.telemetry import (
    TelemetrySample,
    heading_from_quaternion_enu,
    sample_from_enu,
    validate_sample,
)
from subpix_ros.core.timing import detector_angle, expected_shift_px, frame_interval
from subpix_ros.io import cdr
from subpix_ros.io import telemetry_msgs as tm
from subpix_ros.nodes.base import StageNode
from subpix_ros.nodes.params import Param
from subpix_ros.nodes.qos import best_effort_qos, latched_qos, reliable_qos
from subpix_ros.nodes.run import run_nodes
from subpix_ros.nodes.stamps import stamp_to_ns, steady_timer


class TelemetryNode(StageNode):
    """MAVLink (or mavros) telemetry in, the telemetry topics and expected shift out."""

    PARAMS = (
        Param(
            "source",
            "mavlink",
            "telemetry source",
            choices=("mavlink", "mavros"),
            read_only=True,
        ),
        Param(
            "connection",
            "udpin:127.0.0.1:14550",
            "pymavlink connection: udpin:/udpout:/tcp:HOST:PORT, serial device, or .tlog",
            read_only=True,
        ),
        Param("baud", 57600, "serial baud rate", 1200, 4000000, read_only=True),
        Param(
            "system_id",
            0,
            "MAVLink system id to follow (0: the first vehicle seen)",
            0,
            255,
            read_only=True,
        ),
        Param(
            "link_timeout_s", 2.0, "no message for this long: link lost", 0.1, 60.0, read_only=True
        ),
        Param(
            "input_timeout_s",
            5.0,
            "no MAVLink message (mavros: no telemetry) for this long: diagnostics WARN naming "
            "the connection (mavros: its topics and their publishers)",
            0.5,
            3600.0,
        ),
        Param(
            "open_retry_s",
            2.0,
            "a connection that cannot be opened (serial device absent, port in use) is tried "
            "again this often (s); the status stays ERROR meanwhile",
            0.1,
            60.0,
            read_only=True,
        ),
        Param(
            "tlog_rate",
            1.0,
            "tlog replay speed (0: as fast as possible)",
            0.0,
            1000.0,
            read_only=True,
        ),
        Param(
            "tlog_start_delay_s",
            1.0,
            "tlog replay starts this long after start-up (subscribers connect)",
            0.0,
            60.0,
            read_only=True,
        ),
        Param("focal_length_mm", 4.3, "camera focal length (mm)", 0.1, 2000.0),
        Param("pixel_pitch_um", 1.54, "detector pixel pitch (um)", 0.1, 100.0),
        Param("p", 2.0, "sub-pixel factor: frames should step by 1/p pixel", 2.0, 16.0),
        Param(
            "phi_deg",
            0.0,
            "angle between the detector's long axis and the ground track (deg), eq. 1",
            -89.0,
            89.0,
        ),
        Param(
            "camera_rate_hz",
            30.0,
            "camera frame rate, for the expected shift per frame",
            0.1,
            1000.0,
        ),
        Param(
            "camera_yaw_offset_deg",
            0.0,
            "compass angle of the image top relative to the vehicle heading (deg)",
            -180.0,
            180.0,
        ),
        Param(
            "mavros_fix_topic",
            "/mavros/global_position/global",
            "mavros source: NavSatFix topic",
            read_only=True,
        ),
        Param(
            "mavros_velocity_topic",
            "/mavros/local_position/velocity_local",
            "mavros source: TwistStamped (ENU)",
            read_only=True,
        ),
        Param(
            "mavros_height_topic",
            "/mavros/global_position/rel_alt",
            "mavros source: Float64 relative altitude",
            read_only=True,
        ),
        Param("mavros_imu_topic", "/mavros/imu/data", "mavros source: Imu", read_only=True),
        Param(
            "gps_frame_id",
            "gps",
            "frame_id of telemetry/fix (e.g. drone1/gps with several vehicles)",
        ),
        Param("world_frame_id", "map", "frame_id of telemetry/velocity (ENU)"),
        Param("base_frame_id", "base_link", "frame_id of telemetry/imu (body FLU)"),
        Param("camera_frame_id", "camera", "frame_id of telemetry/expected_shift"),
    )

    def __init__(self, *, name: str = "telemetry_node", **kw) -> None:
        super().__init__(name, **kw)
        # 100 deep: a tlog replayed at 10x gives ~40 messages/s per topic; a recorder or a
        # subscriber that stalls for a second must not lose the unacknowledged ones (20 did)
        q = reliable_qos(100)
        self.pubs = {
            key: self.create_publisher(
                _cls(t),
                f"telemetry/{key}",
                q,
                event_callbacks=self.output_events(f"telemetry/{key}"),
            )
            for key, t in tm.TOPICS.items()
        }
        self.pub_shift = self.create_publisher(
            Vector3Stamped,
            "telemetry/expected_shift",
            q,
            event_callbacks=self.output_events("telemetry/expected_shift"),
        )
        self.pub_angle = self.create_publisher(Float64, "telemetry/detector_angle", latched_qos())
        self.pub_angle.publish(Float64(data=detector_angle(self.param("p"))))
        self.samples = 0
        self.reader = None
        self._lock = threading.Lock()
        self._mavros: dict[str, object] = {}
        self._mavros_counts = {"fix": 0, "h": 0, "imu": 0, "velocity": 0}
        self._open_problem: str | None = None  # why the MAVLink connection is not open
        self._open_may_pass = False  # and whether trying again may open it
        self._open_retry = None
        self._no_fix: str | None = None  # the no-fix warning while there is no fix
        if self.param("source") == "mavlink":
            self._start_mavlink()
        else:
            self._start_mavros()
        self._link_loss = None  # the MAVLink link's loss meter (LinkLoss), with the reader
        # wall time, as the MAVLink link (use_sim_time: /clock may stop or never come)
        steady_timer(self, 1.0, self._report)

    def _on_param_change(self, name: str, value) -> None:
        super()._on_param_change(name, value)
        if name == "p":  # the latched detector angle (eq. 2) follows p
            self.pub_angle.publish(Float64(data=detector_angle(value)))

    # ---------------------------------------------------------------- sources
    def _start_mavlink(self) -> None:
        if not self._open_mavlink() and self._open_may_pass:
            self._open_retry = steady_timer(self, self.param("open_retry_s"), self._retry_open)

    def _open_mavlink(self) -> bool:
        """Open the MAVLink connection; True if open (or opening later: a delayed tlog).

        A failure is an ERROR held while it lasts (``_open_problem``, :meth:`_report`); one
        that may pass (a serial device not plugged in yet, a port in use: OSError) is tried
        again by :meth:`_retry_open`, a malformed URL is not.
        """
        from subpix_ros.io.mavlink import MavlinkReader

        url = self.param("connection")
        is_log = url.endswith(".tlog")
        try:
            if is_log and not Path(url).is_file():
                raise FileNotFoundError(f"tlog file not found: {url}")
            reader = MavlinkReader(
                url,
                baud=self.param("baud"),
                system_id=self.param("system_id") or None,
                link_timeout_s=self.param("link_timeout_s"),
                on_sample=self.handle_sample,
                on_status=self._on_link,
                on_packet=lambda _mtype: self.diag.rate("input").tick(),
                rate=(self.param("tlog_rate") or None) if is_log else None,
            )
            if is_log and self.param("tlog_start_delay_s") > 0:
                self._delay = steady_timer(
                    self, self.param("tlog_start_delay_s"), self._start_reader
                )
            else:
                reader.start()
                self._watch_mavlink(url)
        except (ValueError, OSError, RuntimeError) as exc:
            text = str(exc) if str(exc).startswith("tlog file not found") else None
            problem = text or f"cannot open MAVLink connection {url!r}: {exc}"
            if problem != self._open_problem:  # logged and counted once per problem
                self.diag.error(problem)
            else:
                self.diag.hold_error(problem)
            self._open_problem = problem
            self._open_may_pass = isinstance(exc, OSError)
            self.diag.set(link="not open")
            return False
        if self._open_problem is not None:
            self.get_logger().info(f"MAVLink connection {url!r} opened")
        self._open_problem = None
        self.reader = reader
        return True

    def _retry_open(self) -> None:
        if self._open_mavlink():
            self._open_retry.cancel()

    def _watch_mavlink(self, url: str) -> None:
        """Watch the link for silence from now on (the connection is open)."""

        def describe(limit: float, heard: bool) -> str:
            reader = self.reader
            if reader is not None and reader.link_state == "end_of_log":
                return f"telemetry log {url} ended: no more telemetry"
            st = reader.stats if reader is not None else None
            bad = (
                f"; {st.garbage_bytes} bytes and {st.bad_crc} frames that are not valid MAVLink "
                "arrived (wrong baud rate or protocol?)"
                if st is not None and (st.garbage_bytes or st.bad_crc)
                else ""
            )
            since = " since the last one" if heard else ""
            ask = {
                "serial": "is the autopilot connected, and sending at this baud rate?",
                "udpin": "is the autopilot sending to this port?",
                "udpout": "is the autopilot listening there?",
            }.get(reader.spec.kind if reader is not None else "", "is the autopilot sending?")
            return (
                f"no MAVLink message received on {url} for over {limit:g} s{since} "
                f"(input_timeout_s){bad}: {ask}"
            )

        self.diag.watch_inputs((), lambda: self.param("input_timeout_s"), describe=describe)

    def _start_reader(self) -> None:
        self._delay.cancel()
        self.reader.start()
        self._watch_mavlink(self.param("connection"))

    def _start_mavros(self) -> None:
        # best effort: mavros publishes these with SensorDataQoS (a reliable subscription
        # would match no publisher of it); best effort also takes a reliable publisher's
        q = best_effort_qos(20)
        topics = {
            "velocity": self.param("mavros_velocity_topic"),
            "fix": self.param("mavros_fix_topic"),
            "h": self.param("mavros_height_topic"),
            "imu": self.param("mavros_imu_topic"),
        }

        def keep(key: str, value) -> None:
            self._mavros[key] = value
            self._mavros_counts[key] += 1

        self.create_subscription(NavSatFix, topics["fix"], lambda m: keep("fix", m), q)
        self.create_subscription(Float64, topics["h"], lambda m: keep("h", m.data), q)
        self.create_subscription(Imu, topics["imu"], lambda m: keep("imu", m), q)
        self.create_subscription(TwistStamped, topics["velocity"], self._on_mavros_velocity, q)

        def describe(limit: float, heard: bool) -> str:
            """Each topic a sample needs: its publishers, or nothing received on it."""
            parts = []
            for key in ("velocity", "fix", "h"):
                name = self.resolve_topic_name(topics[key])
                pubs = self.diag.publishers(name)
                if not pubs:
                    parts.append(f"{name}: no publisher")
                elif not self._mavros_counts[key]:
                    parts.append(f"{name}: nothing received from {', '.join(pubs)}")
            waiting = "; ".join(parts) or "every topic received, no sample since"
            since = " since the last one" if heard else ""
            none = all(p.endswith(": no publisher") for p in parts) and len(parts) == 3
            return (
                f"no mavros telemetry for over {limit:g} s{since} (input_timeout_s): {waiting}"
                + (" (is mavros running?)" if none else "")
            )

        self.diag.watch_inputs((), lambda: self.param("input_timeout_s"), describe=describe)

    def _on_mavros_velocity(self, msg: TwistStamped) -> None:
        self._mavros_counts["velocity"] += 1
        fix, h = self._mavros.get("fix"), self._mavros.get("h")
        if fix is None or h is None:
            self.diag.warn("mavros: waiting for fix and rel_alt before publishing")
            return
        self.diag.rate("input").tick()
        imu = self._mavros.get("imu")
        heading = (
            None
            if imu is None
            else heading_from_quaternion_enu(
                imu.orientation.x, imu.orientation.y, imu.orientation.z, imu.orientation.w
            )
        )
        v = msg.twist.linear
        s = sample_from_enu(
            stamp_to_ns(msg.header.stamp) * 1e-9,
            (v.x, v.y, v.z),
            float(h),
            lat_deg=fix.latitude,
            lon_deg=fix.longitude,
            alt_msl_m=fix.altitude,
            heading_rad=heading,
        )
        self.handle_sample(dataclasses.replace(s, fix_status=int(fix.status.status)))

    def _on_link(self, event) -> None:
        text = f"MAVLink link {event.state}: {event.reason}"
        if event.state in ("lost", "end_of_log"):
            self.diag.warn(text)
        else:
            self.get_logger().info(text)
        self.diag.set(link=event.state)

    # ---------------------------------------------------------------- output
    def handle_sample(self, s: TelemetrySample) -> None:
        """Publish one telemetry sample (reader thread or mavros callback).

        A sample without a GNSS fix (:attr:`TelemetrySample.has_fix`) publishes only
        ``telemetry/fix`` (status STATUS_NO_FIX) and ``telemetry/imu``: its velocity and
        relative altitude are the autopilot's estimate without GNSS (ArduPilot sends 0 for
        both, and a height above a home that was never set), so neither they nor a frame
        interval or expected shift from them are published, nor handed to the in-process
        stages, which then go on as without telemetry.
        """
        ok, why = validate_sample(s)
        if not ok:
            self.diag.warn(f"telemetry sample rejected: {why}")
            return
        if not s.has_fix:
            self._publish_no_fix(s)
            return
        if self._no_fix is not None:
            self.get_logger().info(
                f"GNSS fix again (status {s.navsat_status}) after: {self._no_fix}"
            )
            self._no_fix = None
        self.diag.set(gnss_status=s.navsat_status)
        f_m, a_m, p = (
            self.param("focal_length_mm") * 1e-3,
            self.param("pixel_pitch_um") * 1e-6,
            self.param("p"),
        )
        iv = frame_interval(
            a_m, s.height_agl_m, f_m, s.ground_speed_mps, p, math.radians(self.param("phi_deg"))
        )
        with self._lock:
            frames = self._frame_ids()
            for topic, msgtype, raw in tm.sample_messages(
                s, iv.interval_s if iv.ok else None, frames
            ):
                self.pubs[topic.split("/", 1)[1]].publish(raw)
            heading = (s.yaw_rad if s.yaw_rad is not None else s.course_rad) + math.radians(
                self.param("camera_yaw_offset_deg")
            )
            try:
                u, v = expected_shift_px(
                    s.ground_speed_mps,
                    s.course_rad,
                    s.height_agl_m,
                    f_m,
                    a_m,
                    1.0 / self.param("camera_rate_hz"),
                    heading,
                )
                self.pub_shift.publish(
                    cdr.vector3_stamped_to_cdr(
                        (u, v, math.hypot(u, v) * self.param("camera_rate_hz")),
                        int(round(s.t * 1e9)),
                        frames.camera,
                    )
                )
            except ValueError as exc:
                self.diag.warn(f"expected shift undefined: {exc}")
        self.samples += 1
        self.emit("sample", s)
        self.diag.rate("output").tick()
        self.diag.set(
            samples=self.samples,
            height_m=float(s.height_agl_m),
            ground_speed_mps=float(s.ground_speed_mps),
            frame_interval_s=iv.interval_s if iv.ok else f"undefined: {iv.reason}",
        )
        if not iv.ok:
            self.diag.warn(f"no frame interval: {iv.reason}")

    def _frame_ids(self) -> tm.FrameIds:
        """Return the messages' frame ids, as the ``*_frame_id`` parameters give them now."""
        return tm.FrameIds(
            gps=self.param("gps_frame_id"),
            world=self.param("world_frame_id"),
            base=self.param("base_frame_id"),
            camera=self.param("camera_frame_id"),
        )

    def _publish_no_fix(self, s: TelemetrySample) -> None:
        """Publish the fix (STATUS_NO_FIX) and attitude of ``s``; WARN while there is no fix."""
        stamp = int(round(s.t * 1e9))
        frames = self._frame_ids()
        with self._lock:
            self.pubs["fix"].publish(tm.fix_cdr(s, stamp, frames.gps))
            if s.has_attitude:
                self.pubs["imu"].publish(tm.imu_cdr(s, stamp, frames.base))
        gps = self.reader.gps_raw if self.reader is not None else None
        if gps is not None:
            sats = "satellites unknown" if gps[1] == 255 else f"{gps[1]} satellites"
            why = f"fix_type {gps[0]}, {sats}"
            if gps[0] > 1:  # a fix, but no position from the autopilot yet
                why = f"GLOBAL_POSITION_INT lat and lon 0; {why}"
        elif self.reader is not None:
            why = "no GPS_RAW_INT; GLOBAL_POSITION_INT lat and lon 0"
        else:
            why = f"mavros NavSatFix status {s.navsat_status}"
        message = (
            f"GNSS: no fix ({why}): no velocity, height, frame interval or expected shift published"
        )
        if message != self._no_fix:
            self.diag.warn(message)  # logged and counted once per episode
        else:
            self.diag.hold_warning(message)
        self._no_fix = message
        self.diag.set(gnss_status=s.navsat_status)

    def _report(self) -> None:
        if self._open_problem is not None:
            self.diag.hold_error(self._open_problem)  # ERROR for as long as it is not open
        if self.reader is None:
            return
        st = self.reader.stats
        if self._link_loss is None:
            from subpix_ros.io.mavlink import LinkLoss  # with the reader: pymavlink loaded

            self._link_loss = LinkLoss(window_s=10.0)
        loss = self._link_loss.add(time.monotonic(), st.packets, st.packets_lost)
        self.diag.set(
            link=self.reader.link_state,
            packets=st.packets,
            packets_lost=st.packets_lost,
            loss_percent_10s="n/a" if loss is None else round(100.0 * loss, 1),
            bad_crc=st.bad_crc,
            garbage_bytes=st.garbage_bytes,
            other_system=st.other_system,
            rejected=st.rejected,
            last_reject=st.last_reject,
        )
        if self.reader.link_state == "lost":
            self.diag.warn("MAVLink link lost")
        elif loss is not None and loss > self._link_loss.WARN_ABOVE:
            self.diag.warn(
                f"MAVLink link losing more than {100 * self._link_loss.WARN_ABOVE:.0f} % of its frames "
                "(loss_percent_10s, from the senders' sequence numbers): telemetry samples come "
                "late or not at all"
            )

    def close(self) -> None:
        """Stop the MAVLink reader and the node's worker."""
        if self.reader is not None:
            self.reader.stop()
        super().close()


def _cls(msgtype: str):
    from subpix_ros.io.player import message_class

    return message_class(msgtype)


def main(args=None) -> int:
    """Run the telemetry node (console entry point)."""
    return run_nodes([TelemetryNode], args, large_messages=False)  # no image: a small segment


if __name__ == "__main__":
    raise SystemExit(main())
