"""Subscriptions that follow their publishers' durability; the reconstruction's latch_output."""

import uuid

import pytest
import rclpy
from conftest import spin
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy
from std_msgs.msg import String

from subpix_ros.nodes.qos import FollowingSubscription, latched_qos, output_qos


@pytest.fixture
def nodes(ctx):
    """Yield a publishing node, a subscribing node and a topic of their own."""
    pub_node, sub_node = rclpy.create_node("pub"), rclpy.create_node("sub")
    yield pub_node, sub_node, "/qos_" + uuid.uuid4().hex[:8]
    pub_node.destroy_node()  # with its publishers; the subscriber's node with the follower's
    sub_node.destroy_node()  # timer and subscription


def test_a_following_subscription_gets_the_latched_message_of_a_publisher_that_came_first(nodes):
    pub_node, sub_node, topic = nodes
    pub = pub_node.create_publisher(String, topic, output_qos(True))
    pub.publish(String(data="latest"))
    got = []
    f = FollowingSubscription(sub_node, String, topic, lambda m: got.append(m.data))
    assert spin([pub_node, sub_node], lambda: got == ["latest"], 10), got
    assert f.durability == DurabilityPolicy.TRANSIENT_LOCAL and f.changes == 0
    f.destroy()
    assert f.subscription is None and pub.get_subscription_count() == 0


def test_a_following_subscription_receives_from_a_volatile_publisher_a_latched_one_does_not(nodes):
    pub_node, sub_node, topic = nodes
    got, latched_got = [], []
    # subscribed before the publisher exists: the follower waits for it; the plain latched
    # subscription is the QoS mismatch the follower avoids
    f = FollowingSubscription(sub_node, String, topic, lambda m: got.append(m.data))
    sub_node.create_subscription(String, topic, lambda m: latched_got.append(m.data), latched_qos())
    assert f.subscription is None and f.durability is None
    pub = pub_node.create_publisher(String, topic, output_qos(False))
    assert spin([pub_node, sub_node], lambda: f.durability == DurabilityPolicy.VOLATILE, 10)
    assert spin([pub_node, sub_node], lambda: pub.get_subscription_count() == 1, 10)
    for i in range(3):
        pub.publish(String(data=f"image {i}"))
        assert spin([pub_node, sub_node], lambda: len(got) == i + 1, 10), got
    spin([pub_node, sub_node], lambda: False, 0.5)
    assert got == ["image 0", "image 1", "image 2"] and latched_got == []


def test_a_following_subscription_resubscribes_when_the_publisher_restarts_volatile(nodes):
    """A node killed and restarted with latch_output false: the follower switches and receives."""
    pub_node, sub_node, topic = nodes
    got = []
    pub = pub_node.create_publisher(String, topic, output_qos(True))
    pub.publish(String(data="before"))
    f = FollowingSubscription(sub_node, String, topic, lambda m: got.append(m.data), period_s=0.2)
    assert spin([pub_node, sub_node], lambda: got == ["before"], 10), got
    pub_node.destroy_publisher(pub)
    pub = pub_node.create_publisher(String, topic, output_qos(False))
    assert spin([pub_node, sub_node], lambda: f.changes == 1, 10)
    assert f.durability == DurabilityPolicy.VOLATILE
    assert spin([pub_node, sub_node], lambda: pub.get_subscription_count() == 1, 10)
    pub.publish(String(data="after"))
    assert spin([pub_node, sub_node], lambda: got == ["before", "after"], 10), got


def test_latch_output_false_publishes_super_resolved_volatile_and_says_so_to_a_latched_reader(
    ctx,
):
    """latch_output false: the DDS writer keeps no image; a transient-local reader is an ERROR."""
    from sensor_msgs.msg import Image

    from subpix_ros.nodes.reconstruction_node import ReconstructionNode

    node = ReconstructionNode(parameter_overrides=[Parameter("latch_output", value=False)])
    latched = ReconstructionNode(name="reconstruction_latched")
    h = rclpy.create_node("harness")
    try:
        assert spin(
            [node, latched, h],
            lambda: len(h.get_publishers_info_by_topic("/super_resolved")) == 2,
            10,
        )
        by_node = {
            i.node_name: i.qos_profile.durability
            for i in h.get_publishers_info_by_topic("/super_resolved")
        }
        assert by_node == {
            "reconstruction_node": DurabilityPolicy.VOLATILE,
            "reconstruction_latched": DurabilityPolicy.TRANSIENT_LOCAL,
        }
        h.create_subscription(Image, "/super_resolved", lambda m: None, latched_qos())
        assert spin(
            [node, latched, h],
            lambda: "QoS incompatible on /super_resolved (durability)" in node.diag.message,
            10,
        ), node.diag._status.message
        assert "QoS incompatible" not in latched.diag._status.message
    finally:
        for n in (node, latched):
            n.close()
            n.destroy_node()
        h.destroy_node()


def _output_node(kind, args):
    from subpix_ros.nodes.mosaic_node import MosaicNode
    from subpix_ros.nodes.reconstruction_node import ReconstructionNode
    from subpix_ros.nodes.registration_node import RegistrationNode
    from subpix_ros.nodes.shift_node import ShiftNode

    if kind == "super_resolved":
        latch = [Parameter("latch_output", value=False)]
        return ReconstructionNode(subscribe_inputs=False, cli_args=args, parameter_overrides=latch)
    if kind in ("aligned", "homography"):
        return RegistrationNode(subscribe_inputs=False, cli_args=args)
    if kind.startswith("mosaic"):
        return MosaicNode(subscribe_inputs=False, cli_args=args)
    return ShiftNode(subscribe_inputs=False, cli_args=args)


@pytest.mark.parametrize(
    "topic, msg_type, qos, says",
    [
        ("shift", "Vector3Stamped", "latched", "durability): this node offers volatile"),
        ("shift/std", "Vector3Stamped", "latched", "durability): this node offers volatile"),
        ("aligned", "Image", "latched", "durability): this node offers volatile"),
        ("homography", "Float64MultiArray", "latched", "durability): this node offers volatile"),
        ("super_resolved", "Image", "latched", "durability): this node offers volatile"),
        ("mosaic", "Image", "deadline", "deadline): this node offers infinite"),
        (
            "mosaic/compressed",
            "CompressedImage",
            "deadline",
            "deadline): this node offers infinite",
        ),
    ],
)
def test_an_incompatible_subscriber_of_an_output_is_an_error_said_once_by_its_remapped_name(
    ctx, capfd, topic, msg_type, qos, says
):
    """An output's subscriber whose QoS does not match: ERROR naming the topic as remapped.

    With the policy's name and what each side offers and requests, logged once. (Was: the
    main outputs but super_resolved and aligned had no publisher callbacks, so nothing in
    /diagnostics; where there were, the line came twice, with the topic as the node names it
    and the policy as ``rmw_qos_policy_kind_t.RMW_QOS_POLICY_RELIABILITY``.)
    """
    from geometry_msgs.msg import Vector3Stamped
    from rclpy.duration import Duration
    from sensor_msgs.msg import CompressedImage, Image
    from std_msgs.msg import Float64MultiArray

    from subpix_ros.nodes.diagnostics import ERROR

    types = {
        "Vector3Stamped": Vector3Stamped,
        "Image": Image,
        "CompressedImage": CompressedImage,
        "Float64MultiArray": Float64MultiArray,
    }
    remapped = f"/out_{uuid.uuid4().hex[:8]}/{topic}"
    node = _output_node(topic, ["--ros-args", "-r", f"{topic}:={remapped}"])
    h = rclpy.create_node("harness")
    profile = latched_qos()
    if qos == "deadline":  # the latched outputs offer every durability: ask for a deadline
        profile.deadline = Duration(seconds=1)
    try:
        h.create_subscription(types[msg_type], remapped, lambda m: None, profile)
        expect = f"QoS incompatible on {remapped} ({says}"
        assert spin([node, h], lambda: expect in node.diag.message, 10), node.diag.message
        assert node.diag.level == ERROR and "/harness requests " in node.diag.message
        assert "rmw_qos_policy_kind_t" not in node.diag.message
        key = "qos_incompatible_" + topic.replace("/", "_")
        assert _values(node)[key] == "1", _values(node)
        spin([node, h], lambda: False, 0.5)
        logged = [
            line for line in capfd.readouterr().err.splitlines() if "QoS incompatible" in line
        ]
        assert len(logged) == 1 and remapped in logged[0], logged
    finally:
        node.close()
        node.destroy_node()
        h.destroy_node()


def test_an_incompatible_camera_is_an_error_said_once_by_its_remapped_name(ctx, capfd):
    """A best-effort camera and camera_reliable true: the remapped topic, the policy, each side."""
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import CompressedImage

    from subpix_ros.nodes.diagnostics import ERROR
    from subpix_ros.nodes.mosaic_node import MosaicNode

    remapped = f"/cam_{uuid.uuid4().hex[:8]}/image_raw/compressed"
    node = MosaicNode(
        cli_args=["--ros-args", "-r", f"image/compressed:={remapped}"],
        parameter_overrides=[Parameter("camera_reliable", value=True)],
    )
    h = rclpy.create_node("harness")
    try:
        h.create_publisher(CompressedImage, remapped, qos_profile_sensor_data)
        expect = (
            f"QoS incompatible on {remapped} (reliability): this node requests reliable; "
            "/harness offers best_effort (1 total)"
        )
        assert spin([node, h], lambda: node.diag.message == expect, 10), node.diag.message
        assert node.diag.level == ERROR
        spin([node, h], lambda: False, 0.5)
        logged = [
            line for line in capfd.readouterr().err.splitlines() if "QoS incompatible" in line
        ]
        assert len(logged) == 1 and logged[0].endswith(expect), logged
    finally:
        node.close()
        node.destroy_node()
        h.destroy_node()


def _mosaic_node(args):
    from subpix_ros.nodes.mosaic_node import MosaicNode

    return MosaicNode(cli_args=args)


def _monitor_node(args):
    from rclpy.parameter import Parameter

    from subpix_ros.nodes.monitor_node import MonitorNode

    return MonitorNode(cli_args=args, parameter_overrides=[Parameter("port", value=0)])


@pytest.mark.parametrize("make", [_mosaic_node, _monitor_node], ids=["mosaic", "monitor"])
def test_camera_frames_lost_before_the_node_took_them_are_a_warning(ctx, make):
    """Camera frames lost in transport before the node took them: a WARN, and counted.

    (Was: never seen: the node counted only what arrived, and the missing frames showed up
    later as short sets.) A camera in another process, without the package's Fast DDS profile,
    sends 100 frames of 1.5 MB in a burst over UDP while the node does not spin; DDS reports the
    ones lost, and the node says so with the remapped topic's name. The mosaic node, and the
    monitor's camera preview (was: silent there too).
    """
    from conftest import burst_camera

    from subpix_ros.nodes.diagnostics import WARN

    topic = "/cam_" + uuid.uuid4().hex[:8]
    node = make(["--ros-args", "-r", f"image:={topic}"])
    try:
        cam = burst_camera(topic)
        assert "sent 1" in cam.stdout, cam.stdout + cam.stderr
        assert spin([node], lambda: "messages_lost_image" in _values(node), 10), _values(node)
        assert int(_values(node)["messages_lost_image"]) >= 20, _values(node)["messages_lost_image"]
        assert (
            node.diag.level == WARN and f"{topic}: messages lost in transport" in node.diag.message
        )
    finally:
        node.close()
        node.destroy_node()


def _values(node):
    return {kv.key: kv.value for kv in node.diag.snapshot().values}


def test_camera_frames_replaced_in_the_history_before_the_node_took_them_are_a_warning(ctx):
    """Frames a node's keep-last history replaced while it fell behind: a WARN, and counted.

    (Was: silent. Fast DDS reports no event for them: a reliable camera in a burst while the
    node is busy, and the node counted only what it got.) Counted from the publisher's
    sequence numbers: 5 frames taken, then 60 sent while the node does not spin; its reliable
    history keeps 30, so about 30 are missed.
    """
    import numpy as np
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import Image

    from subpix_ros.nodes.diagnostics import WARN
    from subpix_ros.nodes.qos import reliable_qos
    from subpix_ros.nodes.registration_node import RegistrationNode

    topic = "/cam_" + uuid.uuid4().hex[:8]
    node = RegistrationNode(
        cli_args=["--ros-args", "-r", f"image:={topic}"],
        parameter_overrides=[Parameter("camera_reliable", value=True)],
    )
    cam = rclpy.create_node("history_camera")
    pub = cam.create_publisher(Image, topic, reliable_qos(100))
    rng = np.random.default_rng(0)
    sent = [0]

    def send(n):
        for _ in range(n):
            sent[0] += 1
            msg = Image(height=64, width=64, encoding="mono8", step=64)
            msg.header.stamp.sec, msg.header.stamp.nanosec = sent[0], 0
            msg.data = rng.integers(0, 255, 64 * 64, dtype=np.uint8).tobytes()
            pub.publish(msg)

    try:
        assert spin([node, cam], lambda: pub.get_subscription_count() > 0, 10)
        send(5)
        assert spin([node, cam], lambda: node.diag.rate("input").total >= 5, 10)
        assert "messages_missed_image" not in _values(node)
        send(60)  # the node does not spin meanwhile: its history of 30 overflows
        assert spin([node, cam], lambda: node.diag.rate("input").total >= 35, 10)
        spin([node, cam], lambda: False, 0.5)
        missed = int(_values(node)["messages_missed_image"])
        assert missed + node.diag.rate("input").total == 65, (missed, node.diag.rate("input").total)
        assert missed >= 20
        # said (the random frames' own registration warnings may come after it)
        assert node.diag.level >= WARN
        assert f"{topic}: camera frames missed" in _values(node)["recent_problems"]
    finally:
        node.close()
        node.destroy_node()
        cam.destroy_node()


def test_sequence_gaps_count_missed_numbers_and_restart_with_the_publisher(ctx):
    """The counting rule: a jump by k + 1 is k missed; a number not above the last restarts."""
    from subpix_ros.nodes.qos import SequenceGaps

    class Diag:
        values, warnings = {}, []

        def set(self, **kv):
            self.values.update(kv)

        def warn(self, text):
            self.warnings.append(text)

    node = rclpy.create_node("gaps_" + uuid.uuid4().hex[:8])
    try:
        diag = Diag()
        gaps = SequenceGaps(node, "image", diag, 10, "camera frames")
        assert [gaps.see(n) for n in (7, 8, 11, 12, 3, 4, 10, None, 0)] == [
            0,
            0,
            2,
            0,
            0,
            0,
            5,
            0,
            0,
        ]
        assert gaps.missed == 7 and diag.values == {"messages_missed_image": 7}
        assert len(diag.warnings) == 2 and "history of 10" in diag.warnings[0]
    finally:
        node.destroy_node()
