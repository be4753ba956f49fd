"""Bad input and faults at the nodes (issue 7).

Bad input and faults at the nodes (issue 7): clear diagnostics, the node keeps
running, nothing garbage is published, valid data beside bad data is not lost.
"""

import time

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import TwistStamped, Vector3Stamped
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from sensor_msgs.msg import CompressedImage, Image, Imu
from std_msgs.msg import Float64

from subpix_ros.core.render import render_sequence
from subpix_ros.io import cdr
from subpix_ros.nodes import payloads as pl
from subpix_ros.nodes.qos import latched_qos, reliable_qos

T0 = 1_700_000_000_000_000_000


class Harness:
    def __init__(self, node, topics):
        self.node = node
        self.h = rclpy.create_node("harness")
        self.ex = SingleThreadedExecutor()
        self.ex.add_node(node)
        self.ex.add_node(self.h)
        self.diag, self.shift, self.refs = [], [], []
        self.h.create_subscription(
            DiagnosticArray,
            "/diagnostics",
            lambda m: self.diag.extend(s for s in m.status if s.name == node.diag.name),
            50,
        )
        self.h.create_subscription(
            Vector3Stamped,
            "/shift",
            lambda r: self.shift.append(cdr.cdr_to_vector3_stamped(r)),
            reliable_qos(50),
            raw=True,
        )
        self.h.create_subscription(
            Image,
            "/aligned/reference",
            lambda r: self.refs.append(cdr.cdr_to_image(r)),
            latched_qos(),
            raw=True,
        )
        self.pubs = {}
        for topic, cls, qos in topics:
            self.pubs[topic] = self.h.create_publisher(cls, topic, qos)
        self.spin(lambda: all(p.get_subscription_count() for p in self.pubs.values()), 10)

    def spin(self, until, timeout):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and not until():
            self.ex.spin_once(timeout_sec=0.02)
        return until()

    def messages(self):
        return (
            " | ".join(s.message for s in self.diag)
            + " | "
            + " | ".join(
                kv.value
                for s in self.diag
                for kv in s.values
                if kv.key in ("last_error", "recent_problems")
            )
        )

    def close(self):
        self.node.close()
        self.ex.shutdown()
        self.node.destroy_node()
        self.h.destroy_node()


def _bad_image(encoding="mono8", h=64, w=64, step=None, data=None, stamp=T0):
    T = cdr.TYPESTORE.types
    step = w if step is None else step
    data = np.zeros(step * h, np.uint8) if data is None else data
    msg = T["sensor_msgs/msg/Image"](
        header=cdr.make_header(stamp, "cam"),
        height=h,
        width=w,
        encoding=encoding,
        is_bigendian=0,
        step=step,
        data=data,
    )
    return cdr.serialize(msg, "sensor_msgs/msg/Image")


BAD_IMAGES = {
    "misspelled encoding": _bad_image("mono_8"),
    "unknown encoding": _bad_image("hsv8"),
    "data shorter than step*height": _bad_image(data=np.zeros(100, np.uint8)),
    "data longer than step*height": _bad_image(data=np.zeros(64 * 64 + 7, np.uint8)),
    "step smaller than a row": _bad_image(step=10, data=np.zeros(640, np.uint8)),
    "width 0": _bad_image(w=0, step=0, data=np.zeros(0, np.uint8)),
    "odd width yuv422": _bad_image("yuv422", w=63, step=126, data=np.zeros(126 * 64, np.uint8)),
    "odd size bayer": _bad_image("bayer_rggb8", w=63, step=63, data=np.zeros(63 * 64, np.uint8)),
    "not an image message": b"\x00\x01\x00\x00garbage",
}


def test_registration_node_survives_bad_images(ctx):
    from subpix_ros.nodes.registration_node import RegistrationNode

    node = RegistrationNode(
        parameter_overrides=[
            Parameter("camera_reliable", value=True),
            Parameter("selection", value="all"),
        ]
    )
    hs = Harness(
        node,
        [
            ("image", Image, reliable_qos(50)),
            ("image/compressed", CompressedImage, reliable_qos(5)),
        ],
    )
    try:
        for raw in BAD_IMAGES.values():
            hs.pubs["image"].publish(raw)
        T = cdr.TYPESTORE.types
        corrupt = T["sensor_msgs/msg/CompressedImage"](
            header=cdr.make_header(T0, "cam"),
            format="jpeg",
            data=np.frombuffer(b"\xff\xd8\xff\xe0 not really a jpeg", np.uint8),
        )
        hs.pubs["image/compressed"].publish(
            cdr.serialize(corrupt, "sensor_msgs/msg/CompressedImage")
        )
        # a valid frame right after the bad ones is not lost: it becomes the reference
        good = (np.random.default_rng(0).random((64, 80)) * 255).astype(np.uint8)
        hs.pubs["image"].publish(pl.image_cdr(good, T0 + 5))
        assert hs.spin(lambda: len(hs.refs) == 1, 10)
        assert hs.spin(lambda: "bad image dropped" in hs.messages(), 5)
    finally:
        hs.close()
    img, header = hs.refs[0]
    assert cdr.header_to_ns(header) == T0 + 5 and np.array_equal(img, good)
    assert node.worker.errors == 0


def test_shift_node_bad_pairs_and_valid_neighbours(ctx, crops):
    from subpix_ros.nodes.shift_node import ShiftNode

    node = ShiftNode(parameter_overrides=[Parameter("queue_size", value=20)])
    q = reliable_qos(50)
    hs = Harness(
        node,
        [
            ("/aligned/reference", Image, latched_qos()),
            ("/aligned", Image, q),
            ("/aligned/mask", Image, q),
        ],
    )
    seq = render_sequence(
        crops["crop_road"][:320, :320], 2, [(0, 0), (0.2, 0.3), (-0.4, 0.1)], 0.4, snr_db=40, seed=5
    )
    full = np.ones(seq.frames[0].shape, bool)
    try:
        hs.pubs["/aligned/reference"].publish(pl.image_cdr(seq.frames[0], T0))
        assert hs.spin(lambda: len(node.inputs.refs.refs) == 1, 20)
        # 1: valid
        hs.pubs["/aligned"].publish(pl.image_cdr(seq.frames[1], T0 + 1))
        hs.pubs["/aligned/mask"].publish(pl.mask_cdr(full, T0 + 1))
        # 2: frame size changed mid-stream (no estimate, a diagnostic)
        hs.pubs["/aligned"].publish(pl.image_cdr(seq.frames[1][:100, :100], T0 + 2))
        hs.pubs["/aligned/mask"].publish(pl.mask_cdr(full[:100, :100], T0 + 2))
        # 3: 32FC1 with NaN and Inf: those pixels are left out, the rest still gives the shift
        f = seq.frames[2].astype(np.float32)
        f[10:30, 10:30] = np.nan
        f[50, 50] = np.inf
        hs.pubs["/aligned"].publish(pl.image_cdr(f, T0 + 3))
        hs.pubs["/aligned/mask"].publish(pl.mask_cdr(full, T0 + 3))
        # 4: saturated / all-black / textureless frames: failures, nothing published
        for k, v in ((4, 255), (5, 0)):
            hs.pubs["/aligned"].publish(pl.image_cdr(np.full_like(seq.frames[0], v), T0 + k))
            hs.pubs["/aligned/mask"].publish(pl.mask_cdr(full, T0 + k))
        # 6: a mask that does not match the image
        hs.pubs["/aligned"].publish(pl.image_cdr(seq.frames[1], T0 + 6))
        hs.pubs["/aligned/mask"].publish(pl.mask_cdr(full[:50], T0 + 6))
        assert hs.spin(lambda: len(hs.shift) >= 2 and node.failed >= 3, 20)
        hs.spin(lambda: False, 1.5)
    finally:
        hs.close()
    got = {cdr.header_to_ns(h) - T0: v for v, h in hs.shift}
    assert set(got) == {1, 3}, got
    assert np.allclose(got[1][:2], [0.2, 0.3], atol=0.02) and np.allclose(
        got[3][:2], [-0.4, 0.1], atol=0.02
    )
    assert all(np.isfinite(v).all() for v in got.values())
    text = hs.messages()
    assert "differ in size" in text and "does not match" in text
    assert node.worker.errors == 0


def test_slow_consumer_drops_oldest_counts_and_memory_stays_flat(ctx):
    from subpix_ros.nodes.registration_node import RegistrationNode

    def rss_mb():
        for line in open("/proc/self/status"):
            if line.startswith("VmRSS"):
                return int(line.split()[1]) / 1024

    node = RegistrationNode(
        parameter_overrides=[
            Parameter("camera_reliable", value=True),
            Parameter("queue_size", value=1),
            Parameter("selection", value="all"),
        ]
    )
    hs = Harness(node, [("image", Image, reliable_qos(200))])
    rng = np.random.default_rng(1)
    frames = [(rng.random((240, 320)) * 255).astype(np.uint8) for _ in range(4)]
    try:
        rss = []
        for burst in range(3):
            for i in range(60):
                hs.pubs["image"].publish(pl.image_cdr(frames[i % 4], T0 + (burst * 60 + i) * 10**7))
            settle = [time.monotonic(), -1]

            def settled():  # the worker is idle and nothing arrived for 1 s
                total = node.diag.rate("input").total
                if total != settle[1]:
                    settle[:] = [time.monotonic(), total]
                return node.worker.idle() and time.monotonic() - settle[0] > 1.0

            assert hs.spin(settled, 60)
            rss.append(rss_mb())
        assert hs.spin(
            lambda: any(
                kv.key == "dropped_frames" and int(kv.value) > 0 for s in hs.diag for kv in s.values
            ),
            5,
        )
    finally:
        hs.close()
    assert node.worker.dropped > 0
    assert rss[2] - rss[1] < 50, rss  # after warm-up, the bounded queue keeps memory flat


def test_telemetry_loss_falls_back_to_every_frame_and_recovers(ctx):
    from subpix_ros.nodes.registration_node import RegistrationNode

    node = RegistrationNode(
        parameter_overrides=[
            Parameter("camera_reliable", value=True),
            Parameter("pixel_pitch_um", value=3.08),
            Parameter("queue_size", value=100),
            Parameter("telemetry_timeout_s", value=0.5),
        ]
    )
    q = reliable_qos(100)
    hs = Harness(
        node,
        [
            ("image", Image, q),
            ("telemetry/velocity", TwistStamped, q),
            ("telemetry/height", Float64, q),
            ("telemetry/imu", Imu, q),
        ],
    )
    img = (np.random.default_rng(2).random((48, 64)) * 255).astype(np.uint8)

    def frames(k0, n):
        for k in range(k0, k0 + n):
            hs.pubs["image"].publish(pl.image_cdr(img, T0 + k * 33_333_333))
            hs.spin(lambda: False, 0.01)  # a camera paces its frames

    def telemetry(t0_ns, seconds, speed=0.1):
        hs.pubs["telemetry/height"].publish(Float64(data=56.0))
        hs.spin(lambda: node.topics_telemetry.height_m is not None, 2)
        for i in range(int(seconds * 10) + 1):
            m = TwistStamped()
            t = t0_ns + i * 100_000_000
            m.header.stamp.sec, m.header.stamp.nanosec = divmod(t, 10**9)
            m.twist.linear.y = speed  # north, slow drift: 2.5 px/s at 56 m
            hs.pubs["telemetry/velocity"].publish(m)

    try:
        frames(0, 10)  # no telemetry: every frame kept, with a warning
        assert hs.spin(lambda: node.kept == 10, 20)
        assert hs.spin(lambda: "keeping every frame" in hs.messages(), 5)
        telemetry(T0 + 10 * 33_333_333, 3.0)
        assert hs.spin(lambda: len(node.telemetry) == 31, 5)
        frames(10, 60)  # 2 s at 30 Hz, 0.083 px per frame: a 1/2 px step every 6 frames
        assert hs.spin(lambda: node.kept + node.skipped == 70, 30)
        kept_with_telemetry = node.kept - 10
        assert 8 <= kept_with_telemetry <= 12 and node.skipped >= 48
        frames(
            200, 10
        )  # telemetry now stale (last sample 1.2 s before these frames): every frame kept again
        assert hs.spin(lambda: node.kept + node.skipped == 80, 30)
        assert node.kept - 10 - kept_with_telemetry == 10
    finally:
        hs.close()


def test_registration_parameters_at_run_time(ctx):
    from subpix_ros.nodes.registration_node import RegistrationNode

    node = RegistrationNode(
        parameter_overrides=[Parameter("p", value=1.0), Parameter("model", value=3)]
    )
    try:
        assert (
            node.param("p") == 2.0 and node.param("model") == "projective"
        )  # rejected at start: defaults kept
        assert node.selector.p == 2.0
        bad = node.set_parameters([Parameter("p", value=40.0)])[0]
        assert not bad.successful and node.param("p") == 2.0 and node.selector.p == 2.0
        bad = node.set_parameters([Parameter("selection", value=5)])[0]
        assert not bad.successful and node.param("selection") == "step"
        good = node.set_parameters([Parameter("p", value=3.0)])[0]
        assert good.successful and node.selector.p == 3.0  # the frame selection follows
    finally:
        node.close()
        node.destroy_node()


def test_reconstruction_blur_sigma_parameter(ctx, crops):
    # blur_sigma: "auto" (default) or a number in 0..3; bad values are rejected and the old value stays;
    # the blur used and its source are in the diagnostics
    from benchmarks.degrade_independent import degrade, scene_crop, shift_layout
    from subpix_ros.nodes.reconstruction_node import ReconstructionNode

    node = ReconstructionNode(
        subscribe_inputs=False, parameter_overrides=[Parameter("blur_sigma", value="sharp")]
    )
    try:
        assert node.param("blur_sigma") == "auto"  # rejected at start: default kept
        for bad in ("5", "-0.2", "blurry"):
            r = node.set_parameters([Parameter("blur_sigma", value=bad)])[0]
            assert (
                not r.successful and "blur_sigma" in r.reason and node.param("blur_sigma") == "auto"
            )
        fl = degrade(
            scene_crop(crops["crop_road"], 2, 96, 8, (280, 280)),
            2,
            shift_layout("grid", 2),
            0.5,
            roof=True,
            margin=8,
        )
        ref = pl.Frame(T0, fl.frames[0])
        members = [
            (
                pl.Shift(T0 + i, T0, float(u), float(v), 0.0, 0.01, 0.01),
                pl.Aligned(T0 + i, f, np.ones(f.shape, bool), ref, np.eye(3)),
            )
            for i, (f, (u, v)) in enumerate(zip(fl.frames[1:], fl.shifts[1:]), start=1)
        ]
        from subpix_ros.stages.reconstruction import FrameSet

        got = []
        node.listen("super_resolved", got.append)
        node._process(FrameSet(ref, members, True, "complete"))
        res = got[-1]
        assert res.blur_source == "edges" and abs(res.blur_sigma - 0.5) <= 0.05
        assert node.diag._status.values["blur_source"] == "edges"
        fill = float(node.diag._status.values["pixel_fill"])  # the calibration's, reported
        assert 0.7 <= fill <= 1.0 and fill == float(res.result.pixel_fill)
        assert node.set_parameters([Parameter("blur_sigma", value="0.35")])[0].successful
        node._process(FrameSet(ref, members, True, "complete"))
        res = got[-1]
        assert res.blur_source == "parameter" and res.blur_sigma == 0.35
        assert node.diag._status.values["blur_sigma"] == "0.35"
    finally:
        node.close()
        node.destroy_node()


def test_a_failing_callback_is_an_error_in_diagnostics_and_the_node_lives_on(ctx):
    """An exception escaping a subscription callback ended the node's process silently.

    (A looped replay made reconstruction_node's assembler raise KeyError; its /diagnostics
    just stopped.) Now it is an ERROR naming the topic and the error, and the next message
    is taken as usual.
    """
    from subpix_ros.nodes.reconstruction_node import ReconstructionNode

    node = ReconstructionNode()
    calls = []
    real = node.stage.match_shift

    def flaky(s):
        calls.append(s.stamp_ns)
        if len(calls) == 1:
            raise KeyError((T0, T0 + 1))  # a bug, as the assembler's was
        return real(s)

    node.stage.match_shift = flaky
    h = Harness(node, [("shift", Vector3Stamped, reliable_qos(20))])
    try:
        for k in (1, 2):
            h.pubs["shift"].publish(cdr.vector3_stamped_to_cdr((0.25, -0.5, 0.0), T0 + k))
        assert h.spin(lambda: len(calls) == 2 and any(s.level == b"\x02" for s in h.diag), 10), (
            calls,
            h.messages(),
        )
        assert "shift callback failed: KeyError" in h.messages()
    finally:
        h.close()


def test_reconstruction_node_says_when_no_shift_comes_for_its_frames(ctx):
    """Aligned frames arrive, nothing publishes shift (shift_node dead): WARN, not a silent OK."""
    from subpix_ros.nodes.reconstruction_node import ReconstructionNode

    node = ReconstructionNode(parameter_overrides=[Parameter("input_timeout_s", value=2.0)])
    h = Harness(node, [("aligned", Image, reliable_qos(20))])
    try:
        img = np.zeros((48, 64), np.uint8)
        for k in range(30):
            h.pubs["aligned"].publish(cdr.image_to_cdr(img, "mono8", T0 + k * 100_000_000))
            h.spin(lambda: False, 0.05)
        assert h.spin(
            lambda: any(
                s.level == b"\x01" and "no publisher on /shift" in s.message for s in h.diag
            ),
            10,
        ), h.messages()
    finally:
        h.close()
