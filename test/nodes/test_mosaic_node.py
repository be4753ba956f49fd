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


def test_with_sim_time_the_mosaic_is_published_once_the_clock_stops(ctx):
    """use_sim_time and a /clock that stops (a replay ended): the last frames' mosaic comes.

    (Was: the publishing timer ran on the node's clock, which stops with /clock: the mosaic of
    the frames drawn last was never published.)
    """
    import rclpy
    from conftest import spin
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import Image

    from subpix_ros.io import cdr
    from subpix_ros.nodes.mosaic_node import MosaicNode
    from subpix_ros.nodes.qos import latched_qos
    from subpix_ros.nodes.stamps import ns_to_stamp

    t0 = 1_700_000_000_000_000_000
    paths = seneca_frame_paths()[:2]
    imgs = [cv2.resize(cv2.imread(str(p)), (900, 675), interpolation=cv2.INTER_AREA) for p in paths]
    node = MosaicNode(
        subscribe_inputs=False,
        parameter_overrides=[
            Parameter("use_sim_time", value=True),
            Parameter("publish_rate_hz", value=2.0),
        ],
    )
    h = rclpy.create_node("harness")
    clock = h.create_publisher(Clock, "/clock", 10)
    got = []
    h.create_subscription(
        Image, "/mosaic", lambda r: got.append(cdr.cdr_to_image(r)), latched_qos(), raw=True
    )

    def tick(stamp_ns):
        clock.publish(Clock(clock=ns_to_stamp(stamp_ns, type(Clock().clock))))

    try:
        assert spin([node, h], lambda: tick(t0) or node.get_clock().now().nanoseconds == t0, 10)
        for k, img in enumerate(imgs):  # the replay's clock goes with its frames ...
            tick(t0 + k * 10**9)
            node.handle_frame(_frame(img, t0 + k * 10**9))
        assert spin([node, h], lambda: node.worker.idle() and node.added == 2, 60)
        stopped = node.get_clock().now().nanoseconds  # ... and stops here
        assert spin([node, h], lambda: bool(got), 10), "no mosaic after /clock stopped"
        assert node.get_clock().now().nanoseconds == stopped
    finally:
        node.close()
        node.destroy_node()
        h.destroy_node()
    image, header = got[-1]
    assert cdr.header_to_ns(header) == t0 + 10**9 and image.ndim == 3
