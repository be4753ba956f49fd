"""Stopping the pipeline as the camera stops: the frames still queued reach the products."""

import rclpy
from conftest import ROOT
from rclpy.executors import SingleThreadedExecutor

from subpix_ros.io.bags import read_messages
from subpix_ros.nodes import payloads
from subpix_ros.nodes.pipeline import build
from subpix_ros.nodes.run import shutdown_nodes

QUEUED = ("registration_node", "shift_node", "mosaic_node")


def test_a_pipeline_stopped_with_frames_still_queued_handles_them_first(sample_bags, tmp_path):
    """The sample flight's 24 frames handed in at once, then the process's Ctrl-C teardown.

    (Was: each node's ``close()`` stopped its worker with its queue as it was, so the frames
    the registration and shift workers still held were dropped unsaid, and the open set went
    out short or fell below ``min_frames``: "set of reference ... dropped: 2 frames <
    min_frames 4" in a loaded CI run.) Sets of 16 here: the first set and the open one (8
    frames) both come out, every frame in one of them.
    """
    queues = tmp_path / "queues.yaml"  # the workers keep every frame of the burst
    queues.write_text("".join(f"{n}:\n  ros__parameters:\n    queue_size: 30\n" for n in QUEUED))
    rclpy.init(
        args=[
            "--ros-args",
            "--params-file",
            str(ROOT / "config" / "bench.yaml"),
            "--params-file",
            str(queues),
            "-p",
            "pixel_pitch_um:=3.08",
            "-p",
            "flush_after_s:=60.0",
        ]
    )
    try:
        nodes = build(with_telemetry=False)
        reg, recon = nodes[0], nodes[2]
        images = []
        recon.listen("super_resolved", images.append)
        executor = SingleThreadedExecutor()
        for n in nodes:
            executor.add_node(n)
        frames = [
            payloads.frame_from_cdr(m.raw)
            for m in read_messages(sample_bags / "subpixel", ["/camera/image_raw"])
        ]
        assert len(frames) == 24
        for f in frames:
            reg.handle_frame(f)
        assert reg.worker.depth > 0  # still queued when the teardown starts
        shutdown_nodes(nodes, executor)
        members = sorted(sr.n_frames for sr in images)
        assert reg.worker.dropped == 0 and nodes[1].worker.dropped == 0
        assert len(images) == 2 and sum(members) == 24, members
    finally:
        if rclpy.ok():
            rclpy.shutdown()
