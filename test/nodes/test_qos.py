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
            lambda: "QoS incompatible on super_resolved" in node.diag._status.message,
            10,
        ), node.diag._status.message
        assert "QoS incompatible" not in latched.diag._status.message
    finally:
        for n in (node, latched):
            n.close()
            n.destroy_node()
        h.destroy_node()
