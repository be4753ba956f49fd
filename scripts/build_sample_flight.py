#!/usr/bin/env python3
"""Build the two bundled sample flights (rosbag2, mcap) reproducibly.

Inputs are the real frames committed under data/ (see
scripts/extract_seneca_assets.py); outputs go to ``--out`` (default
data/bags, not committed: ``make sample`` runs this):

``seneca/``     rosbag2 (mcap): the nine real Seneca frames (1800x1350 bgr8)
                on /camera/image_raw at their real capture times, and the
                telemetry the telemetry node publishes (/telemetry/fix,
                /telemetry/velocity, /telemetry/height, /telemetry/imu at
                10 Hz) along the real GPS track of frames.csv.
``seneca.tlog`` the same telemetry as MAVLink 2 (GLOBAL_POSITION_INT,
                VFR_HUD, ATTITUDE at 10 Hz, HEARTBEAT at 1 Hz).
``subpixel/``   rosbag2 (mcap): a rendered low-altitude pass over a real
                full-resolution Seneca crop at 30 Hz: every frame optically
                blurred, pixel-integrated (METHODS.md eq. 3), noisy and 8-bit,
                the platform drifting so consecutive frames differ by a known
                sub-pixel step, with matching telemetry.
``subpixel/truth.json``, ``subpixel/truth_hr.png``: the true shift of every
                frame against frame 0 and the sharp high-resolution truth on
                frame 0's grid (LR pixel i covers HR pixels 2i, 2i+1).
``subpixel.tlog`` its telemetry as MAVLink.

``--storage sqlite3`` writes the bags with sqlite3 storage instead.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import shutil
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from subpix_ros.core.render import render_frame  # noqa: E402
from subpix_ros.core.telemetry import trajectory_straight  # noqa: E402
from subpix_ros.core.timing import expected_shift_px, frame_interval  # noqa: E402
from subpix_ros.io.bags import BagWriter  # noqa: E402
from subpix_ros.io.cdr import image_to_cdr  # noqa: E402
from subpix_ros.io.frame_metadata import read_frames_csv, trajectory_from_frames_csv  # noqa: E402
from subpix_ros.io.mavlink import write_tlog  # noqa: E402
from subpix_ros.io.telemetry_msgs import sample_messages  # noqa: E402

CAMERA_TOPIC = "/camera/image_raw"
SENECA_CAMERA = dict(focal_length_m=4.3e-3, pixel_pitch_m=2 * 1.54e-6)  # frames downscaled 2x
GROUND_ALT_M = 230.0

# The rendered pass: LR pixel = 2 HR pixels of the real crop.
SUB_FACTOR = 2
SUB_RATE_HZ = 30.0
SUB_FRAMES = 24
SUB_SIZE = 448  # LR frame size (px)
SUB_MARGIN = 32  # LR px of scene kept outside frame 0 for the drift
SUB_STEP = (0.41, 0.27)  # true (u, v) per frame, LR px
SUB_BLUR = 0.4  # optics blur sigma, LR px
SUB_NOISE = 1.0  # read noise sigma, DN
SUB_HEIGHT_M = 56.0  # LR ground pixel 4 cm: the real crop's 2 cm pixels, 2x2 binned
SUB_HEADING_DEG = 60.0  # where the image top points (compass)
SUB_CAMERA = dict(focal_length_m=4.3e-3, pixel_pitch_m=2 * 1.54e-6)
SUB_T0 = 1_717_000_000.0  # POSIX seconds of frame 0


def _telemetry(writer: BagWriter, samples, camera: dict, p: float = 2.0) -> None:
    for s in samples:
        iv = frame_interval(
            camera["pixel_pitch_m"], s.height_agl_m, camera["focal_length_m"], s.ground_speed_mps, p
        )
        for topic, msgtype, raw in sample_messages(s, iv.interval_s if iv.ok else None):
            writer.write("/" + topic, msgtype, int(round(s.t * 1e9)), raw)


def build_seneca(out: Path, storage: str) -> None:
    data = ROOT / "data" / "seneca"
    fixes = read_frames_csv(data / "frames.csv")
    samples = trajectory_from_frames_csv(
        data / "frames.csv", ground_alt_m=GROUND_ALT_M, rate_hz=10.0
    )

    bag = out / "seneca"
    with BagWriter(bag, storage=storage) as w:
        _telemetry(w, samples, SENECA_CAMERA)
        for name, t in zip(fixes.names, fixes.t):
            img = cv2.imread(str(data / name), cv2.IMREAD_COLOR)
            ns = int(round(t * 1e9))
            w.write(
                CAMERA_TOPIC, "sensor_msgs/msg/Image", ns, image_to_cdr(img, "bgr8", ns, "camera")
            )
    write_tlog(out / "seneca.tlog", samples)
    print(f"seneca: {len(fixes.names)} frames, {len(samples)} telemetry samples -> {bag}")


def build_subpixel(out: Path, storage: str) -> None:
    hr = cv2.imread(str(ROOT / "data" / "crops" / "colour_hr.jpg"), cv2.IMREAD_COLOR).astype(
        np.float64
    )
    f = SUB_FACTOR
    # Motion that gives SUB_STEP px per frame: speed and course from the camera geometry.
    gsd = SUB_HEIGHT_M * SUB_CAMERA["pixel_pitch_m"] / SUB_CAMERA["focal_length_m"]  # m per LR px
    step_px = math.hypot(*SUB_STEP)
    speed = step_px * SUB_RATE_HZ * gsd
    heading = math.radians(SUB_HEADING_DEG)
    course = heading + math.atan2(-SUB_STEP[1], SUB_STEP[0])  # inverse of expected_shift_px
    check = expected_shift_px(
        speed,
        course,
        SUB_HEIGHT_M,
        SUB_CAMERA["focal_length_m"],
        SUB_CAMERA["pixel_pitch_m"],
        1.0 / SUB_RATE_HZ,
        heading,
    )
    assert np.allclose(check, SUB_STEP, atol=1e-9), (check, SUB_STEP)
    duration = SUB_FRAMES / SUB_RATE_HZ
    samples = trajectory_straight(
        t0=SUB_T0 - 1.0,
        duration_s=duration + 2.0,
        rate_hz=10.0,
        lat0_deg=41.0357,
        lon0_deg=-83.3054,
        course_rad=course,
        speed_mps=speed,
        height_agl_m=SUB_HEIGHT_M,
        ground_alt_m=GROUND_ALT_M,
    )
    # The airframe (and camera top) points along SUB_HEADING_DEG while it drifts along ``course``.
    samples = [dataclasses.replace(s, yaw_rad=heading) for s in samples]
    rng = np.random.default_rng(20240604)
    truth = []
    bag = out / "subpixel"
    m = SUB_MARGIN
    with BagWriter(bag, storage=storage) as w:
        _telemetry(w, samples, SUB_CAMERA)
        for k in range(SUB_FRAMES):
            shift = (k * SUB_STEP[0], k * SUB_STEP[1])
            chans = [render_frame(hr[..., c], f, shift, SUB_BLUR, SUB_NOISE, rng) for c in range(3)]
            frame = np.ascontiguousarray(np.dstack(chans)[m : m + SUB_SIZE, m : m + SUB_SIZE])
            ns = int(round((SUB_T0 + k / SUB_RATE_HZ) * 1e9))
            w.write(
                CAMERA_TOPIC, "sensor_msgs/msg/Image", ns, image_to_cdr(frame, "bgr8", ns, "camera")
            )
            truth.append({"index": k, "stamp_ns": ns, "u": shift[0], "v": shift[1]})
    hr_truth = hr[m * f : (m + SUB_SIZE) * f, m * f : (m + SUB_SIZE) * f]
    cv2.imwrite(str(bag / "truth_hr.png"), np.clip(np.rint(hr_truth), 0, 255).astype(np.uint8))
    (bag / "truth.json").write_text(
        json.dumps(
            {
                "description": "true (u, v) of every frame against frame 0, LR px: content at (r, c) in frame 0 "
                "appears at (r + u, c + v); truth_hr.png is the sharp HR scene on frame 0's grid "
                "(LR pixel i covers HR pixels factor*i .. factor*i + factor - 1)",
                "topic": CAMERA_TOPIC,
                "factor": f,
                "blur_sigma_lr_px": SUB_BLUR,
                "noise_sigma_dn": SUB_NOISE,
                "rate_hz": SUB_RATE_HZ,
                "step_px": list(SUB_STEP),
                "height_m": SUB_HEIGHT_M,
                "speed_mps": speed,
                "course_deg": math.degrees(course),
                "heading_deg": SUB_HEADING_DEG,
                "camera": SUB_CAMERA,
                "frames": truth,
            },
            indent=1,
        )
    )
    write_tlog(out / "subpixel.tlog", samples)
    print(
        f"subpixel: {SUB_FRAMES} frames {SUB_SIZE}x{SUB_SIZE} bgr8, step {SUB_STEP} px/frame -> {bag}"
    )


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--out", type=Path, default=ROOT / "data" / "bags")
    ap.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    for name in ("seneca", "subpixel"):
        shutil.rmtree(args.out / name, ignore_errors=True)
    build_seneca(args.out, args.storage)
    build_subpixel(args.out, args.storage)


if __name__ == "__main__":
    main()
