"""The monitor's labels: a bicubic fallback is never labelled super-resolved."""

import cv2
import numpy as np

from subpix_ros.core.superres.result import bicubic_integer
from subpix_ros.monitor.encoding import same_as_bicubic, sr_label


def test_the_label_says_fallback_and_why():
    assert sr_label(" x2 rows 0-512") == "super-resolved x2 rows 0-512"
    text = sr_label(" x2", "bicubic upscale of the reference:\n no plan fits 250 MB")
    assert text.startswith("BICUBIC FALLBACK, not super-resolved x2: bicubic upscale")
    assert "\n" not in text and "super-resolved x2 rows" not in text
    assert sr_label("", "x" * 200).endswith("x" * 60) and len(sr_label("", "x" * 200)) < 110


def test_same_as_bicubic_tells_the_fallback_from_a_super_resolved_image():
    rng = np.random.default_rng(0)
    ref = cv2.GaussianBlur(rng.integers(0, 256, (80, 120, 3), dtype=np.uint8), (0, 0), 1.0)
    opencv = cv2.resize(ref, (240, 160), interpolation=cv2.INTER_CUBIC)  # the monitor's own
    fallback = bicubic_integer(ref, 2, np.uint8)  # the reconstruction's (float32, rounded)
    assert same_as_bicubic(fallback, opencv)
    sharper = cv2.addWeighted(fallback, 1.5, cv2.GaussianBlur(fallback, (0, 0), 1.5), -0.5, 0)
    assert not same_as_bicubic(sharper, opencv)
    assert not same_as_bicubic(fallback, opencv[:100])  # sizes differ: not taken for it
