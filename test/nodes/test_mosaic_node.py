"""mosaic_node in this process: the min_interval_s gate takes frames by stamp, it does not drop them."""

import time

import cv2
from rclpy.parameter import Parameter

from subpix_ros.data import seneca_frame_paths
from subpix_ros.nodes import payloads as pl


def _frame(img, stamp_ns):
    return pl.Frame(stamp_ns=stamp_ns, image=img, frame_id="camera", received=time.monotonic())


def test_min_interval_gate_skips_by_stamp_without_drops(ctx):
    from subpix_ros.nodes.mosaic_node import MosaicNode

    paths = seneca_frame_paths()[:3]
    imgs = [cv2.resize(cv2.imread(str(p)), (900, 675), interpolation=cv2.INTER_AREA) for p in paths]
    node = MosaicNode(
        subscribe_inputs=False,
        parameter_overrides=[
            Parameter("min_interval_s", value=1.0),
            Parameter("queue_size", value=3),
        ],
    )
    try:
        # a burst at 10 Hz of three scenes, 1 s apart: the gate must take exactly the first frame of each second,
        # even though all frames arrive before the worker has added anything (the old gate queued them all: 27 drops)
        for k in range(30):
            node.handle_frame(_frame(imgs[k // 10], k * 100_000_000))
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not node.worker.idle():
            time.sleep(0.05)
        assert node.skipped == 27
        assert node.worker.dropped == 0 and node.added == 3
        assert node.mosaic.image() is not None
    finally:
        node.close()
        node.destroy_node()
