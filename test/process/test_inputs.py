"""Opening a flight bag: which image topic is the camera."""

import numpy as np

from subpix_ros.io.bags import BagWriter
from subpix_ros.io.cdr import compressed_to_cdr, image_to_cdr
from subpix_ros.process.inputs import COMPRESSED, IMAGE, open_flight

T0 = 1_700_000_000_000_000_000


def test_the_camera_is_the_largest_picture_not_the_busiest_topic(tmp_path):
    """A driver's thumbnail stream (more messages, small frames) is not taken for the camera."""
    rng = np.random.default_rng(0)
    bag = tmp_path / "two_streams"
    with BagWriter(bag) as w:
        for k in range(6):
            t = T0 + k * 100_000_000
            full = rng.integers(0, 255, (240, 320, 3), np.uint8)
            w.write("/left/image_raw", IMAGE, t, image_to_cdr(full, "bgr8", t, "cam"))
            for j in range(2):  # twice the rate
                thumb = np.ascontiguousarray(full[::4, ::4])
                raw = compressed_to_cdr(thumb, t + j, "cam", "jpeg", 90)
                w.write("/left/thumbnail/compressed", COMPRESSED, t + j, raw)
    flight = open_flight(bag)
    assert flight.camera_topic == "/left/image_raw"
    assert "320x240, 6 frames" in flight.camera_note and "80x60, 12 frames" in flight.camera_note
    # asked for by name, the thumbnail it is
    assert open_flight(bag, "/left/thumbnail/compressed").camera_topic == (
        "/left/thumbnail/compressed"
    )
