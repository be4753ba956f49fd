"""reconstruction_node with max_memory_mb, fed over DDS: the set is reduced to fit, and it says so."""

import rclpy
from conftest import SET_SHIFTS, AlignedFeed, node_diagnostics, spin
from rclpy.parameter import Parameter
from sensor_msgs.msg import Image

from subpix_ros.core.render import render_sequence
from subpix_ros.core.superres import estimate_peak_mb
from subpix_ros.io import cdr
from subpix_ros.nodes.qos import latched_qos

T0 = 1_700_000_000_000_000_000
SHIFTS = SET_SHIFTS


def _harness():
    """Return a harness node feeding aligned frames, its /super_resolved (image, header) list."""
    h = rclpy.create_node("harness")
    got = []
    h.create_subscription(
        Image, "/super_resolved", lambda r: got.append(cdr.cdr_to_image(r)), latched_qos(), raw=True
    )
    return h, got, AlignedFeed(h)


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
    h, got, feed = _harness()
    diags, value = node_diagnostics(h, node)

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


def _colour(frame):
    """Return a uint8 BGR frame made from a rendered mono one (chroma varying across it)."""
    import numpy as np

    g = np.clip(frame, 0, 255) / 255.0
    ramp = np.linspace(0.0, 1.0, g.shape[1])[None, :]
    bgr = np.dstack([g, 0.6 * g + 0.4 * ramp, np.clip(1.2 - g - 0.3 * ramp, 0, 1)])
    return np.round(bgr * 255).astype(np.uint8)


def test_packed_members_over_dds_give_the_image_of_unpacked_ones(ctx, crops):
    """pack_members (config/onboard.yaml) in the node: the set's image within 1 DN of unpacked.

    Colour frames over DDS; the node holds the waiting members packed and publishes bgr8; the
    same set through an unpacked stage in this process is the reference.
    """
    import numpy as np

    from subpix_ros.nodes.reconstruction_node import ReconstructionNode
    from subpix_ros.stages import Aligned, Frame, ReconstructionStage, Shift

    seq = render_sequence(crops["crop_trees"][:256, :256], 2, SHIFTS, 0.4, snr_db=40, seed=5)
    frames = [_colour(f) for f in seq.frames]
    params = dict(n_frames=8, pack_members=True, blur_sigma="0.4")
    node = ReconstructionNode(
        parameter_overrides=[Parameter(k, value=v) for k, v in params.items()]
    )
    h, got, feed = _harness()
    try:
        assert spin([node, h], lambda: feed.matched(), 10)
        feed.reference(frames[0], T0)
        assert spin([node, h], lambda: len(node.inputs.refs.refs) == 1, 10)
        for k in range(1, 7):
            feed.frame(frames[k], T0 + k * 33_333_333, T0, *SHIFTS[k])

        def waiting():
            return [a for members in node.stage.sets.values() for _, a in members]

        assert spin([node, h], lambda: len(waiting()) == 6, 10)
        assert all(a.packed and a.image.dtype == np.uint16 for a in waiting())  # 2 B/px held
        feed.frame(frames[7], T0 + 7 * 33_333_333, T0, *SHIFTS[7])
        assert spin([node, h], lambda: bool(got), 30), "no super-resolved image"
    finally:
        node.close()
        node.destroy_node()
        h.destroy_node()
    image, header = got[0]
    h0, w0 = frames[0].shape[:2]
    assert image.dtype == np.uint8 and image.shape == (2 * h0, 2 * w0, 3)
    stage = ReconstructionStage(n_frames=8, pack_members=False, blur_sigma="0.4")
    ref = Frame(T0, frames[0])
    out = []
    for k in range(1, 8):
        stamp = T0 + k * 33_333_333
        a = Aligned(stamp, frames[k], np.ones((h0, w0), bool), ref, np.eye(3))
        s = Shift(stamp, T0, float(SHIFTS[k][0]), float(SHIFTS[k][1]), 0.0, 0.01, 0.01)
        out += stage.add(s, a)
    (want,) = out
    d = np.abs(image.astype(int) - want.image)
    assert d.max() <= 1 and (d > 0).mean() < 0.01


def test_max_cpu_cores_skips_a_set_over_dds_and_says_so(ctx, crops):
    """A CPU budget in the node (issue 22): the set after a measured one is skipped, loudly.

    Sets of 4 frames; 1e-4 cores: after the first set (0.05 ms to 10 s of CPU: a pause of
    0.5 s to 1e5 s) the set 0.5 s later is skipped and the one 1e6 s later is reconstructed;
    the skip is a WARN on /diagnostics when it happens and a count beside the next image.
    """
    from subpix_ros.nodes.reconstruction_node import ReconstructionNode

    seq = render_sequence(crops["crop_trees"][:128, :128], 2, SHIFTS, 0.4, snr_db=40, seed=5)
    node = ReconstructionNode(
        parameter_overrides=[
            Parameter("n_frames", value=4),
            Parameter("max_cpu_cores", value=1e-4),
            Parameter("blur_sigma", value="0.4"),
        ]
    )
    h, got, feed = _harness()
    diags, value = node_diagnostics(h, node)

    def one_set(t0):
        feed.reference(seq.frames[0], t0)
        assert spin([node, h], lambda: t0 in node.inputs.refs.refs, 10)
        for k in range(1, 4):
            feed.frame(seq.frames[k], t0 + k * 33_333_333, t0, *SHIFTS[k])

    try:
        assert spin([node, h], lambda: feed.matched(), 10)
        one_set(T0)
        assert spin([node, h], lambda: len(got) == 1, 30), "no image of the first set"
        one_set(T0 + 500_000_000)
        assert spin(
            [node, h], lambda: node.stage.stats.skipped_by_reason.get("cpu_budget") == 3, 10
        )
        assert spin(
            [node, h],
            lambda: any("max_cpu_cores" in s.message and s.level[0] == 1 for s in diags),
            5,
        ), "the skip was not reported as a warning"
        one_set(T0 + 10**6 * 10**9)
        assert spin([node, h], lambda: len(got) == 2, 30), "no image after the pause"
        assert spin([node, h], lambda: value("sets_skipped_budget") == "1", 5)
    finally:
        node.close()
        node.destroy_node()
        h.destroy_node()
    assert [cdr.header_to_ns(hd) for _, hd in got] == [T0, T0 + 10**6 * 10**9]
    assert float(value("set_cpu_time_s")) > 0
