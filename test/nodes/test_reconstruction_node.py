"""reconstruction_node in this process, fed over DDS: a stream's last incomplete set is not lost."""

import time

import numpy as np
import rclpy
from conftest import SET_SHIFTS, AlignedFeed, node_diagnostics, rendered_set, spin
from rclpy.parameter import Parameter
from sensor_msgs.msg import Image

from subpix_ros.io import cdr
from subpix_ros.nodes import payloads as pl
from subpix_ros.nodes.qos import latched_qos

T0 = 1_700_000_000_000_000_000


def test_an_incomplete_last_set_is_reconstructed_after_flush_after_s(ctx, crops):
    """Reconstruct an 8-frame flight with one frame lost (issue 19 item 3).

    Issue 19 item 3: n_frames 8 and an 8-frame flight with one frame lost (frame 5): the set
    never
    completes and no next reference comes. After flush_after_s (default 2 s) without a new frame the
    node reconstructs the 7 frames it has (>= min_frames). The old node waited for ever.
    """
    from subpix_ros.nodes.reconstruction_node import ReconstructionNode

    seq = rendered_set(crops["crop_trees"])
    node = ReconstructionNode(parameter_overrides=[Parameter("method", value="map")])
    h = rclpy.create_node("harness")
    got = []
    h.create_subscription(
        Image,
        "/super_resolved",
        lambda r: got.append((time.monotonic(), cdr.cdr_to_image(r))),
        latched_qos(),
        raw=True,
    )
    diags, _ = node_diagnostics(h, node)
    feed = AlignedFeed(h)
    try:
        assert spin([node, h], lambda: feed.matched() and got == [], 10)
        feed.reference(seq.frames[0], T0)
        assert spin([node, h], lambda: len(node.inputs.refs.refs) == 1, 10)
        for k in (1, 2, 3, 4, 6, 7):  # frame 5 lost on the way
            stamp = T0 + k * 33_333_333
            feed.frame(seq.frames[k], stamp, T0, *SET_SHIFTS[k])
        assert spin([node, h], lambda: len(node.sets.get(T0, ())) == 6, 10)
        t_last = time.monotonic()
        assert spin([node, h], lambda: bool(got), 30), (
            "no super-resolved image from the incomplete last set"
        )
        assert spin(
            [node, h],
            lambda: any(
                kv.key == "sets_flushed" and kv.value == "1" for s in diags for kv in s.values
            ),
            5,
        )
    finally:
        node.close()
        node.destroy_node()
        h.destroy_node()
    t_out, (image, header) = got[0]
    assert t_out - t_last >= 2.0 - 0.3  # not before flush_after_s without a new frame
    assert cdr.header_to_ns(header) == T0 and image.shape == (
        2 * seq.frames[0].shape[0],
        2 * seq.frames[0].shape[1],
    )
    assert len(got) == 1 and node.stage.stats.sets_flushed == 1 and node.stage.stats.frames == 7


def test_close_publishes_the_open_set_first(ctx, crops):
    """Reconstruct and publish the open set at shutdown.

    Shutdown (close() while ROS is up, e.g. a node destroyed by its owner): the open set of
    >= min_frames is reconstructed and published before the node goes.
    """
    from subpix_ros.nodes.reconstruction_node import ReconstructionNode

    seq = rendered_set(crops["crop_trees"])
    node = ReconstructionNode(
        subscribe_inputs=False,
        parameter_overrides=[Parameter("flush_after_s", value=600.0)],  # no idle flush here
    )
    h = rclpy.create_node("harness")
    got = []
    h.create_subscription(
        Image, "/super_resolved", lambda r: got.append(cdr.cdr_to_image(r)), latched_qos(), raw=True
    )
    ref = pl.Frame(T0, seq.frames[0])
    full = np.ones(seq.frames[0].shape, bool)
    try:
        for k in range(1, 5):  # 5 frames with the reference: >= min_frames 4, < n_frames 8
            stamp = T0 + k * 33_333_333
            a = pl.Aligned(stamp, seq.frames[k], full, ref, np.eye(3))
            node.handle_shift((pl.Shift(stamp, T0, *SET_SHIFTS[k], 0.0, 0.01, 0.01), a))
        spin([node, h], lambda: False, 1.0)
        assert got == [] and len(node.sets[T0]) == 4
        node.close()
        assert spin([h], lambda: bool(got), 10), "the open set was not published at close()"
    finally:
        node.destroy_node()
        h.destroy_node()
    image, header = got[0]
    assert cdr.header_to_ns(header) == T0 and len(got) == 1
    assert node.stage.stats.frames == 5 and node.stage.stats.sets_flushed == 1


def test_a_volatile_output_is_made_only_while_subscribed(ctx, crops):
    """latch_output false: no message is made for nobody; a follower then gets the image.

    Nothing is kept for a late joiner (volatile), so a set finished while nothing subscribes is
    not encoded at all (``images_published`` in /diagnostics, beside ``images_made``).
    """
    from subpix_ros.nodes.qos import FollowingSubscription
    from subpix_ros.nodes.reconstruction_node import ReconstructionNode

    seq = rendered_set(crops["crop_trees"])
    colour = [np.repeat(f[..., None], 3, axis=2) for f in seq.frames]
    node = ReconstructionNode(
        subscribe_inputs=False, parameter_overrides=[Parameter("latch_output", value=False)]
    )
    made = []
    node.listen("super_resolved", lambda sr: made.append(np.array(sr.image)))
    h = rclpy.create_node("harness")
    got = []

    def one_set(t0):
        ref = pl.Frame(t0, colour[0])
        full = np.ones(colour[0].shape[:2], bool)
        for k in range(1, 8):  # 8 frames with the reference: a complete set
            stamp = t0 + k * 33_333_333
            a = pl.Aligned(stamp, colour[k], full, ref, np.eye(3))
            node.handle_shift((pl.Shift(stamp, t0, *SET_SHIFTS[k], 0.0, 0.01, 0.01), a))

    try:
        one_set(T0)
        assert spin([node, h], lambda: len(made) == 1, 30)
        assert node.sent == 0
        FollowingSubscription(
            h, Image, "/super_resolved", lambda r: got.append(cdr.cdr_to_image(r)), raw=True
        )
        assert spin([node, h], lambda: node.pub.get_subscription_count() == 1, 10)
        one_set(T0 + 10**9)
        assert spin([node, h], lambda: len(got) == 1, 30), node.sent
        spin([node, h], lambda: False, 0.5)
        assert node.sent == 1 and len(got) == 1 and len(made) == 2
    finally:
        node.close()
        node.destroy_node()
        h.destroy_node()
    image, header = got[0]
    assert cdr.header_to_ns(header) == T0 + 10**9 and np.array_equal(image, made[1])
    # latch_output is the node's (QoS), not a solver option the stage would warn it ignores
    assert node.stage.ignored == {} and node.stage.stats.warnings == 0, node.stage.stats


def test_with_sim_time_the_last_set_is_flushed_once_the_clock_stops(ctx, crops):
    """use_sim_time and a /clock that stops (a replay ended): the last incomplete set still comes.

    (Was: the idle check ran on the node's clock, which stops with /clock: the set that
    flush_after_s should have closed "in wall time once the stream stops" never was.)
    """
    from rosgraph_msgs.msg import Clock

    from subpix_ros.nodes.reconstruction_node import ReconstructionNode
    from subpix_ros.nodes.stamps import ns_to_stamp

    seq = rendered_set(crops["crop_trees"])
    node = ReconstructionNode(
        parameter_overrides=[
            Parameter("method", value="map"),
            Parameter("use_sim_time", value=True),
        ]
    )
    h = rclpy.create_node("harness")
    clock = h.create_publisher(Clock, "/clock", 10)
    got = []
    h.create_subscription(
        Image, "/super_resolved", lambda r: got.append(cdr.cdr_to_image(r)), latched_qos(), raw=True
    )
    feed = AlignedFeed(h)

    def tick(stamp_ns):
        clock.publish(Clock(clock=ns_to_stamp(stamp_ns, type(Clock().clock))))

    try:
        assert spin([node, h], lambda: tick(T0) or node.get_clock().now().nanoseconds == T0, 10)
        assert spin([node, h], lambda: feed.matched(), 10)
        feed.reference(seq.frames[0], T0)
        assert spin([node, h], lambda: len(node.inputs.refs.refs) == 1, 10)
        for k in (1, 2, 3, 4, 6, 7):  # frame 5 lost: the set never completes
            stamp = T0 + k * 33_333_333
            tick(stamp)  # the replay's clock goes with its frames ...
            feed.frame(seq.frames[k], stamp, T0, *SET_SHIFTS[k])
        assert spin([node, h], lambda: len(node.sets.get(T0, ())) == 6, 10)
        stopped = node.get_clock().now().nanoseconds  # ... and stops here
        assert spin([node, h], lambda: bool(got), 30), (
            "no super-resolved image after /clock stopped"
        )
        assert node.get_clock().now().nanoseconds == stopped  # the node's clock stood still
    finally:
        node.close()
        node.destroy_node()
        h.destroy_node()
    image, header = got[0]
    assert cdr.header_to_ns(header) == T0 and node.stage.stats.sets_flushed == 1
    assert node.stage.stats.frames == 7
