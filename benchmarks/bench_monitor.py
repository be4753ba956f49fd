#!/usr/bin/env python3
"""Live monitor: CPU per camera frame at 1080p 10 Hz, and bytes per channel per second at a budget.

A real Seneca frame (cut to 1920x1080) is fed to :class:`subpix_ros.monitor.Monitor` as the camera
at
10 Hz with a shift per frame, a 2048-px mosaic changing every second and a 3840x2160 super-resolved
pair every 1.6 s, for ``--seconds``; a foxglove.sdk.v1 client in another process
(``python -m subpix_ros.monitor.client``) subscribes to everything and reports what it received.
CPU is this process's (the feeder's calls, the monitor's sender thread, the SDK's server threads)
divided by the camera frames fed. Reference in the same run: JPEG-encoding every full frame
(q85), what serving the camera without the monitor's decimation would cost.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from subpix_ros.monitor import Monitor, MonitorConfig  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument(
        "--kbps", type=float, default=2000.0, help="bandwidth_kbps (default: the node's default)"
    )
    ap.add_argument("--rate", type=float, default=10.0, help="camera rate, Hz")
    a = ap.parse_args()

    src = cv2.imread(str(ROOT / "data" / "seneca" / "IMG_0461.jpg"), cv2.IMREAD_COLOR)
    frames = [
        np.ascontiguousarray(np.roll(src, 3 * i, axis=1)[135:1215, :][:, :1920]) for i in range(8)
    ]
    frames = [cv2.resize(f, (1920, 1080)) if f.shape[:2] != (1080, 1920) else f for f in frames]
    mosaic = cv2.resize(src, (2048, 1536))
    sr = cv2.resize(frames[0], (3840, 2160), interpolation=cv2.INTER_CUBIC)

    # reference: encode every full frame
    t = time.process_time()
    for f in frames * 2:
        cv2.imencode(".jpg", f, [cv2.IMWRITE_JPEG_QUALITY, 85])
    ref_ms = 1000 * (time.process_time() - t) / (2 * len(frames))

    mon = Monitor(MonitorConfig(port=0, bandwidth_kbps=a.kbps))
    client = subprocess.Popen(
        [sys.executable, "-m", "subpix_ros.monitor.client", mon.url, str(a.seconds + 1)],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    time.sleep(1.0)
    n = int(a.seconds * a.rate)
    call_s = 0.0
    cpu0, t0 = time.process_time(), time.monotonic()
    for i in range(n):
        stamp = time.time_ns()
        c = time.perf_counter()
        mon.on_camera(frames[i % len(frames)], stamp)
        mon.on_shift(stamp, 0.41, 0.27, 0.002, 0.002, True, 0.4, 0.3)
        call_s += time.perf_counter() - c
        if i % int(a.rate) == 0:
            mon.on_mosaic(np.roll(mosaic, i, axis=1), stamp)
            mon.on_fix(42.8, -76.7 + i * 1e-6, 120.0, stamp)
        if i % 16 == 0:
            mon.on_super_resolved(sr, sr, stamp, 2)
        time.sleep(max(0.0, t0 + (i + 1) / a.rate - time.monotonic()))
    cpu = time.process_time() - cpu0
    stats = mon.link_stats()
    out = client.communicate(timeout=30)[0]
    mon.close()

    print(
        f"camera 1920x1080 at {a.rate:g} Hz for {a.seconds:g} s, "
        f"bandwidth_kbps {a.kbps:g}, 1 client\n"
    )
    print("| what | ms per camera frame |\n|---|---|")
    print(
        "| monitor, whole process CPU (feeder calls + sender + server threads) | "
        f"{1000 * cpu / n:.2f} |"
    )
    print(f"| the feeder's on_camera + on_shift calls (wall) | {1000 * call_s / n:.3f} |")
    print(f"| reference: JPEG q85 of every full frame | {ref_ms:.2f} |")
    print("\nreceived by the client (python -m subpix_ros.monitor.client):\n")
    print(out)
    print(
        f"monitor's own count: {stats['sent_kbps']} kbit/s sent (5 s window); "
        f"rungs {stats['levels']}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
