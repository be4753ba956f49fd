"""shift_node in this process, fed over DDS: parameters, shifts, failures, diagnostics."""

import time

import numpy as np
import pytest
import rclpy
from conftest import spin
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter

from subpix_ros.core.render import render_sequence
from subpix_ros.io import cdr
from subpix_ros.nodes import payloads as pl
from subpix_ros.nodes.qos import latched_qos, reliable_qos


def _harness(node):
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import Vector3Stamped
    from sensor_msgs.msg import Image

    h = rclpy.create_node("harness")
    got, diags = [], []
    h.create_subscription(
        Vector3Stamped,
        "/shift",
        lambda raw: got.append(cdr.cdr_to_vector3_stamped(raw)),
        reliable_qos(20),
        raw=True,
    )
    h.create_subscription(
        DiagnosticArray,
        "/diagnostics",
        lambda m: diags.extend(s for s in m.status if s.name == node.diag.name),
        10,
    )
    pubs = {
        t: h.create_publisher(
            Image, t, latched_qos() if t == "/aligned/reference" else reliable_qos(20)
        )
        for t in ("/aligned/reference", "/aligned", "/aligned/mask")
    }
    spin([node, h], lambda: all(p.get_subscription_count() for p in pubs.values()), 10)
    return h, pubs, got, diags


def test_parameters_rejected_at_start_and_run_time(ctx):
    from subpix_ros.nodes.shift_node import ShiftNode

    node = ShiftNode(
        parameter_overrides=[
            Parameter("max_std_px", value=-1.0),
            Parameter("queue_size", value="x"),
        ]
    )
    try:
        assert (
            node.param("max_std_px") == 0.1 and node.param("queue_size") == 4
        )  # bad start values: defaults kept
        r = node.set_parameters([Parameter("max_std_px", value=50.0)])[0]
        assert not r.successful and node.param("max_std_px") == 0.1
        r = node.set_parameters([Parameter("method", value="magic")])[0]
        assert not r.successful and "not one of" in r.reason and node.param("method") == "default"
        r = node.set_parameters([Parameter("max_std_px", value=0.05)])[0]
        assert r.successful and node.param("max_std_px") == 0.05
    finally:
        node.close()
        node.destroy_node()


def test_shift_published_for_aligned_frames(ctx, crops):
    from subpix_ros.nodes.shift_node import ShiftNode

    node = ShiftNode()
    seq = render_sequence(
        crops["crop_trees"][:384, :384],
        2,
        [(0, 0), (0.3, -0.45), (0.0, 0.0)],
        0.4,
        snr_db=40,
        seed=3,
    )
    h, pubs, got, diags = _harness(node)
    try:
        t0 = 1_700_000_000_000_000_000
        pubs["/aligned/reference"].publish(pl.image_cdr(seq.frames[0], t0))
        assert spin([node, h], lambda: len(node.inputs.refs.refs) == 1, 20)
        full = np.ones(seq.frames[0].shape, bool)
        for k in (1,):
            pubs["/aligned"].publish(pl.image_cdr(seq.frames[k], t0 + k * 10**8))
            pubs["/aligned/mask"].publish(pl.mask_cdr(full, t0 + k * 10**8))
        # a textureless frame: nothing published, the reason in diagnostics
        flat = np.full_like(seq.frames[0], 128)
        pubs["/aligned/reference"].publish(pl.image_cdr(flat, t0 + 2 * 10**8))
        assert spin([node, h], lambda: len(node.inputs.refs.refs) == 2, 20)
        pubs["/aligned"].publish(pl.image_cdr(flat, t0 + 3 * 10**8))
        pubs["/aligned/mask"].publish(pl.mask_cdr(full, t0 + 3 * 10**8))
        assert spin([node, h], lambda: len(got) >= 1 and node.failed >= 1, 40)
        spin([node, h], lambda: any("shift not" in s.message for s in diags), 3)
    finally:
        node.close()
        node.destroy_node()
        h.destroy_node()
    assert len(got) == 1
    vec, header = got[0]
    assert cdr.header_to_ns(header) == t0 + 10**8  # header = the moving frame's
    assert abs(vec[0] - 0.3) < 0.01 and abs(vec[1] + 0.45) < 0.01
    assert any("shift not" in s.message for s in diags)


def _recording_shift_node(crops):
    """Build a shift node whose aligned input records stamps instead of estimating.

    A shift node whose aligned input records (frame stamp, reference stamp) instead of
    estimating, with the harness; and a small image and full mask to publish, and the node's
    diagnostics.
    """
    from subpix_ros.nodes.shift_node import ShiftNode

    node = ShiftNode()
    got = []
    node.inputs.on_aligned = lambda a: got.append((a.stamp_ns, a.reference.stamp_ns))
    img = crops["crop_trees"][:64, :64]
    h, pubs, _, diags = _harness(node)
    return node, got, img, np.ones(img.shape, bool), h, pubs, diags


@pytest.mark.parametrize("executor", ["single", "multi"])
def test_aligned_frames_get_their_own_reference_whatever_order_the_executor_takes_them(
    ctx, crops, executor
):
    """Pair each frame with its own reference when both wait in the node's queues.

    The registration node publishes a new reference before the frames aligned to it, but on another
    topic: when both wait in the node's queues, the frame must still go with ITS reference, never with the
    previous one (and a reference followed at once by the next one must not be overwritten). On both
    executors (the nodes spin on a MultiThreadedExecutor).
    """
    from rclpy.executors import MultiThreadedExecutor

    kind = (
        SingleThreadedExecutor
        if executor == "single"
        else (lambda: MultiThreadedExecutor(num_threads=2))
    )

    node, got, img, full, h, pubs, diags = _recording_shift_node(crops)
    t0 = 1_700_000_000_000_000_000
    try:
        pubs["/aligned/reference"].publish(pl.image_cdr(img, t0))
        assert spin([node, h], lambda: len(node.inputs.refs.refs) == 1, 20)
        # reference 8 and its frame 9 both queued before the node spins
        pubs["/aligned/reference"].publish(pl.image_cdr(img, t0 + 8))
        pubs["/aligned"].publish(pl.image_cdr(img, t0 + 9))
        pubs["/aligned/mask"].publish(pl.mask_cdr(full, t0 + 9))
        time.sleep(0.5)  # all three delivered to the node's readers
        assert spin([node, h], lambda: len(got) == 1, 20, kind)
        # references 16 and 24 back to back, then frame 17 (of 16) and frame 25 (of 24)
        pubs["/aligned/reference"].publish(pl.image_cdr(img, t0 + 16))
        pubs["/aligned/reference"].publish(pl.image_cdr(img, t0 + 24))
        for k in (17, 25):
            pubs["/aligned"].publish(pl.image_cdr(img, t0 + k))
            pubs["/aligned/mask"].publish(pl.mask_cdr(full, t0 + k))
        time.sleep(0.5)
        assert spin([node, h], lambda: len(got) == 3, 20, kind)
    finally:
        node.close()
        node.destroy_node()
        h.destroy_node()
    assert got == [(t0 + 9, t0 + 8), (t0 + 17, t0 + 16), (t0 + 25, t0 + 24)]


def test_aligned_frames_follow_their_reference_link_in_any_arrival_order(ctx, crops):
    """Pair each frame with the reference its aligned/reference_stamp link names.

    With the registration node's aligned/reference_stamp links (sensor_msgs/TimeReference), a frame goes
    with the reference its link names even when the frame arrives BEFORE that reference (it waits; it never
    goes with the previous one), and when its link arrives after the frame.
    """
    from sensor_msgs.msg import TimeReference

    node, got, img, full, h, pubs, diags = _recording_shift_node(crops)
    link = h.create_publisher(TimeReference, "/aligned/reference_stamp", latched_qos(20))
    t0 = 1_700_000_000_000_000_000

    def frame(k, ref):
        if ref is not None:
            link.publish(pl.reference_link_cdr(t0 + k, t0 + ref))
        pubs["/aligned"].publish(pl.image_cdr(img, t0 + k))
        pubs["/aligned/mask"].publish(pl.mask_cdr(full, t0 + k))

    try:
        assert spin(
            [node, h],
            lambda: link.get_subscription_count() and node.inputs.link_sub.get_publisher_count(),
            10,
        )
        pubs["/aligned/reference"].publish(pl.image_cdr(img, t0))
        assert spin([node, h], lambda: len(node.inputs.refs.refs) == 1, 20)
        frame(9, 8)  # reference 8 not published yet
        spin([node, h], lambda: False, 1.0)
        assert got == []  # held, not paired with reference 0
        pubs["/aligned/reference"].publish(pl.image_cdr(img, t0 + 8))
        assert spin([node, h], lambda: len(got) == 1, 20)
        frame(10, None)  # the link comes after the frame
        spin([node, h], lambda: False, 1.0)
        assert len(got) == 1
        link.publish(pl.reference_link_cdr(t0 + 10, t0 + 8))
        assert spin([node, h], lambda: len(got) == 2, 20)
        # frame 11's link is lost; frame 12's link shows it will never come: 11 is skipped, said so
        frame(11, None)
        frame(12, 8)
        assert spin([node, h], lambda: len(got) == 3, 20)
        assert spin([node, h], lambda: any("never came" in d.message for d in diags), 5)
        assert not node.inputs.unlinked
    finally:
        node.close()
        node.destroy_node()
        h.destroy_node()
    assert got == [(t0 + 9, t0 + 8), (t0 + 10, t0 + 8), (t0 + 12, t0 + 8)]


def test_bounded_put_keeps_the_newest_and_says_when_it_drops():
    import collections

    from subpix_ros.nodes.aligned_input import _bounded_put

    d = collections.OrderedDict()
    assert [_bounded_put(d, k, k * 10, 3) for k in range(5)] == [False, False, False, True, True]
    assert list(d.items()) == [(2, 20), (3, 30), (4, 40)]
