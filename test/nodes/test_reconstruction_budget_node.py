"""reconstruction_node with max_memory_mb, fed over DDS: the set is reduced to fit, and it says so."""

import numpy as np
import rclpy
from conftest import spin
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Vector3Stamped
from rclpy.parameter import Parameter
from sensor_msgs.msg import Image, TimeReference

from subpix_ros.core.render import render_sequence
from subpix_ros.core.superres_budget import estimate_peak_mb
from subpix_ros.io import cdr
from subpix_ros.nodes import payloads as pl
from subpix_ros.nodes.common import latched_qos, reliable_qos

T0 = 1_700_000_000_000_000_000
SHIFTS = [
    (0.0, 0.0),
    (0.5, 0.0),
    (0.0, 0.5),
    (0.5, 0.5),
    (0.25, 0.75),
    (0.75, 0.25),
    (0.3, 0.6),
    (0.6, 0.3),
]


def test_max_memory_mb_reduces_the_set_and_reports_it_in_diagnostics(ctx, crops):
    """Issue 22: a budget below the 8-frame set's working memory: the node publishes an image made
    from fewer frames (256 px frames are too small to tile) and its diagnostics say what was given up."""
    from subpix_ros.nodes.reconstruction_node import ReconstructionNode

    seq = render_sequence(crops["crop_trees"][:256, :256], 2, SHIFTS, 0.4, snr_db=40, seed=5)
    budget = estimate_peak_mb(5, seq.frames[0].shape, 2, colour=False)
    node = ReconstructionNode(
        parameter_overrides=[
            Parameter("n_frames", value=8),
            Parameter("max_memory_mb", value=float(budget)),
        ]
    )
    h = rclpy.create_node("harness")
    got, diags = [], []
    h.create_subscription(
        Image, "/super_resolved", lambda r: got.append(cdr.cdr_to_image(r)), latched_qos(), raw=True
    )
    h.create_subscription(
        DiagnosticArray,
        "/diagnostics",
        lambda m: diags.extend(s for s in m.status if s.name == node.get_name()),
        10,
    )
    ref_pub = h.create_publisher(Image, "/aligned/reference", latched_qos())
    link = h.create_publisher(TimeReference, "/aligned/reference_stamp", latched_qos(20))
    img_pub = h.create_publisher(Image, "/aligned", reliable_qos(20))
    mask_pub = h.create_publisher(Image, "/aligned/mask", reliable_qos(20))
    shift_pub = h.create_publisher(Vector3Stamped, "/shift", reliable_qos(20))
    pubs = (ref_pub, link, img_pub, mask_pub, shift_pub)

    def value(key):
        vals = [kv.value for s in diags for kv in s.values if kv.key == key]
        return vals[-1] if vals else None

    try:
        assert spin([node, h], lambda: all(p.get_subscription_count() for p in pubs), 10)
        ref_pub.publish(pl.image_cdr(seq.frames[0], T0))
        assert spin([node, h], lambda: len(node.inputs.refs.refs) == 1, 10)
        full = np.ones(seq.frames[0].shape, bool)
        for k in range(1, 8):
            stamp = T0 + k * 33_333_333
            link.publish(pl.reference_link_cdr(stamp, T0))
            img_pub.publish(pl.image_cdr(seq.frames[k], stamp))
            mask_pub.publish(pl.mask_cdr(full, stamp))
            shift_pub.publish(pl.shift_cdr(pl.Shift(stamp, T0, *SHIFTS[k], 0.0, 0.01, 0.01)))
        assert spin([node, h], lambda: bool(got), 30), (
            "no super-resolved image under the memory budget"
        )
        assert spin([node, h], lambda: value("memory_reduction") is not None, 5)
    finally:
        node.close()
        node.destroy_node()
        h.destroy_node()
    image, header = got[0]
    assert cdr.header_to_ns(header) == T0 and image.shape == tuple(
        2 * n for n in seq.frames[0].shape
    )
    assert value("memory_reduction") == "5 of 8 frames" and value("frames_used") == "5"
    assert value("memory_reduced") == "1" and float(value("memory_estimate_mb")) <= budget + 0.05
