"""Real frames for the stage tests: a Seneca scene moved by known offsets.

The rendered sample flight is the ``flight`` fixture of test/conftest.py.
"""

import cv2
import numpy as np

from subpix_ros.data import seneca_frame_paths


def scene_frames(offsets, w=640, h=480):
    """Frames of a real Seneca scene whose content moves by ``offsets[k]`` = (rows, cols) px."""
    scene = cv2.imread(str(seneca_frame_paths()[4]), cv2.IMREAD_COLOR)
    out = []
    for u, v in offsets:
        m = np.float32([[1, 0, -200 + v], [0, 1, -200 + u]])
        out.append(cv2.warpAffine(scene, m, (w, h), flags=cv2.INTER_LINEAR))
    return out


def stamp(k, t0=1_000_000_000, dt=100_000_000):
    return t0 + k * dt
