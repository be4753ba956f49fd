"""reconstruction_node with max_memory_mb, fed over DDS: the set is reduced to fit, and it says so."""

import rclpy
from conftest import SET_SHIFTS, AlignedFeed, spin
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.parameter import Parameter
from sensor_msgs.msg import Image

from subpix_ros.core.render import render_sequence
from subpix_ros.core.superres import estimate_peak_mb
from subpix_ros.io import cdr
from subpix_ros.nodes.qos import latched_qos

T0 = 1_700_000_000_000_000_000
SHIFTS = SET_SHIFTS


def test_max_memory_mb_reduces_the_set_and_reports_it_in_diagnostics(ctx, crops):
    """Reconstruct within a memory budget below the set's working memory (issue 22).

    Issue 22: a budget below the 8-frame set's working memory: the node publishes an image made
    from fewer frames (256 px frames are too small to tile) and its diagnostics say what was given up.
    """
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
    feed = AlignedFeed(h)

    def value(key):
        vals = [kv.value for s in diags for kv in s.values if kv.key == key]
        return vals[-1] if vals else None

    try:
        assert spin([node, h], lambda: feed.matched(), 10)
        feed.reference(seq.frames[0], T0)
        assert spin([node, h], lambda: len(node.inputs.refs.refs) == 1, 10)
        for k in range(1, 8):
            stamp = T0 + k * 33_333_333
            feed.frame(seq.frames[k], stamp, T0, *SHIFTS[k])
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
    assert float(value("workspace_mb")) > 0  # buffers kept for the next set, said
