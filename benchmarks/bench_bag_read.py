#!/usr/bin/env python3
"""Reading a bag of camera frames: the package's verifying reader against rosbags' own reader.

``subpix_ros.io.bags.read_messages`` checks every chunk (record lengths, ``uncompressed_crc``,
message count against the chunk index) before delivering its messages, and runs
``PRAGMA quick_check`` on sqlite3 storage; ``rosbags`` (the reference, same run) checks a CRC
only where the writer set one and nothing on sqlite3. The bag: N real Seneca frames (1800x1350
bgr8, 7.3 MB each) written by ``BagWriter`` (mcap with chunk CRCs; sqlite3), read whole, bytes
touched (``len``) but not decoded. Times: median and best of several runs, MB/s of message
bytes; the load average is printed (the machine may be shared).
Usage: ``python benchmarks/bench_bag_read.py [--frames N] [--runs R]``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import cv2

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from subpix_ros.data import seneca_frame_paths  # noqa: E402
from subpix_ros.io.bags import BagWriter, read_messages  # noqa: E402
from subpix_ros.io.cdr import image_to_cdr  # noqa: E402


def _rosbags(bag: Path) -> int:
    from rosbags.rosbag2 import Reader

    n = 0
    with Reader(bag) as r:
        for _, _, raw in r.messages():
            n += len(raw)
    return n


def _ours(bag: Path) -> int:
    return sum(len(m.raw) for m in read_messages(bag))


def _time(fn, bag: Path, runs: int) -> tuple[float, float, int]:
    nbytes = fn(bag)  # warm-up (page cache)
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        assert fn(bag) == nbytes
        times.append(time.perf_counter() - t0)
    return statistics.median(times), min(times), nbytes


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--runs", type=int, default=5)
    args = ap.parse_args()
    frames = [cv2.imread(str(p)) for p in seneca_frame_paths()]
    print(
        f"load average {os.getloadavg()[0]:.2f}; {args.frames} frames "
        f"{frames[0].shape[1]}x{frames[0].shape[0]} bgr8"
    )
    print(f"{'storage':8s} {'reader':28s} {'median s':>9s} {'best s':>8s} {'MB/s':>7s}")
    with tempfile.TemporaryDirectory(prefix="bench_bag_") as tmp:
        for storage in ("mcap", "sqlite3"):
            bag = Path(tmp) / storage
            with BagWriter(bag, storage=storage) as w:
                for i in range(args.frames):
                    t = 10**18 + i * 10**8
                    w.write(
                        "/camera/image_raw",
                        "sensor_msgs/msg/Image",
                        t,
                        image_to_cdr(frames[i % len(frames)], "bgr8", t, "cam"),
                    )
            for name, fn in (
                ("rosbags Reader (reference)", _rosbags),
                ("read_messages (verifying)", _ours),
            ):
                med, best, nbytes = _time(fn, bag, args.runs)
                print(f"{storage:8s} {name:28s} {med:9.3f} {best:8.3f} {nbytes / 1e6 / med:7.0f}")


if __name__ == "__main__":
    main()
