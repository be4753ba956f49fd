#!/usr/bin/env python3
"""`subpix process` throughput (issue 20).

One 1080p 10 Hz flight in one process, and 4 flights with --jobs 2 against one after another.

Synthesises flight bags (rosbag2, mcap): 1920x1080 bgr8 frames at 10 Hz of a real Seneca
frame (upscaled) drifting by (0.41, 0.27) px per frame, with the telemetry that drift
implies (the sample-flight builder's /telemetry/* topics: a straight flight at 56 m), and
runs `subpix process` on them with config/bench.yaml (150 tie points, sets of 16, the
mosaic fed at most one frame per second).

Printed: flight time, wall time, real-time factor (flight s / wall s; target >= 2) and CPU of
each of ``--repeat`` runs of one flight in one process and their median; then the wall time of
4 flights one after another (`--jobs 1`) and with `--jobs 2`, their ratio (target <= 0.6) and
the best ratio the CPU allows on a 2-core machine. The page cache is written out before each
timed run (the bags just made, the last run's products). Each run is a fresh `subpix process`
command (start-up included). The machine's load average is printed beside: the 2 cores are
shared.

Usage: python benchmarks/bench_process.py [--seconds 20] [--bags 4] [--repeat 3] [--keep DIR]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine_speed import machine_line  # noqa: E402

from subpix_ros.core.telemetry import trajectory_straight  # noqa: E402
from subpix_ros.io.bags import BagWriter  # noqa: E402
from subpix_ros.io.cdr import image_to_cdr  # noqa: E402

STEP = (0.41, 0.27)  # px per frame
RATE_HZ = 10.0
HEIGHT_M = 56.0
HEADING_DEG = 60.0
CAMERA = dict(
    focal_length_m=4.3e-3, pixel_pitch_m=3.08e-6
)  # config/bench.yaml: pixel_pitch_um 3.08


def build_flight(path: Path, seconds: float, seed: int) -> int:
    """Write a 1080p 10 Hz flight bag at ``path``; return the number of frames."""
    import build_sample_flight as bsf

    scene = cv2.imread(str(ROOT / "data" / "seneca" / "IMG_0463.jpg"), cv2.IMREAD_COLOR)
    scene = cv2.resize(scene, (2400 + 64, 1800), interpolation=cv2.INTER_CUBIC)
    n = int(round(seconds * RATE_HZ))
    gsd = HEIGHT_M * CAMERA["pixel_pitch_m"] / CAMERA["focal_length_m"]
    speed = math.hypot(*STEP) * RATE_HZ * gsd
    heading = math.radians(HEADING_DEG)
    course = heading + math.atan2(-STEP[1], STEP[0])
    t0 = 1_717_000_000.0 + 1000.0 * seed
    samples = trajectory_straight(
        t0=t0 - 1.0,
        duration_s=seconds + 2.0,
        rate_hz=10.0,
        lat0_deg=41.0357,
        lon0_deg=-83.3054,
        course_rad=course,
        speed_mps=speed,
        height_agl_m=HEIGHT_M,
        ground_alt_m=230.0,
    )
    samples = [dataclasses.replace(s, yaw_rad=heading) for s in samples]
    off = 8 * seed  # each flight over a slightly different part of the scene
    with BagWriter(path) as w:
        bsf._telemetry(w, samples, CAMERA)
        for k in range(n):
            # drift by STEP per frame, back and forth over 300 frames so the scene stays in view
            j = k % 600
            j = j if j < 300 else 600 - j
            m = np.float32([[1, 0, -(100 + off) + j * STEP[1]], [0, 1, -100 + j * STEP[0]]])
            frame = cv2.warpAffine(scene, m, (1920, 1080), flags=cv2.INTER_LINEAR)
            ns = int(round((t0 + k / RATE_HZ) * 1e9))
            w.write(
                "/camera/image_raw",
                "sensor_msgs/msg/Image",
                ns,
                image_to_cdr(frame, "bgr8", ns, "camera"),
            )
    return n


def run_process(bags: list[Path], out: Path, jobs: int) -> tuple[float, float]:
    """Run one ``subpix process`` command; return (wall s, CPU s of the command's processes).

    The products of an earlier run are removed and the page cache's dirty pages written out
    first (``os.sync``), so that the disk's write-back of the bags just made, or of the last
    run's 650 MB of products, is not timed with this run.
    """
    shutil.rmtree(out, ignore_errors=True)
    os.sync()
    cpu0 = _children_cpu()
    t0 = time.monotonic()
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "subpix_ros.cli",
            "process",
            *map(str, bags),
            "-o",
            str(out),
            "--params",
            str(ROOT / "config" / "bench.yaml"),
            "--jobs",
            str(jobs),
            "--quiet",
        ],
        capture_output=True,
        text=True,
    )
    wall = time.monotonic() - t0
    if r.returncode != 0:
        raise SystemExit(f"subpix process failed: {r.stderr.strip()}")
    return wall, _children_cpu() - cpu0


def _children_cpu() -> float:
    """User + system CPU seconds of the finished child processes so far."""
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--seconds", type=float, default=20.0, help="flight length (s; default 20)")
    ap.add_argument(
        "--bags", type=int, default=4, help="flights for the --jobs comparison (default 4)"
    )
    ap.add_argument(
        "--keep", type=Path, default=None, help="keep the bags and products in this folder"
    )
    ap.add_argument(
        "--repeat",
        type=int,
        default=3,
        help="runs of the one-flight command (default 3: its run-to-run spread is ~0.5 s)",
    )
    args = ap.parse_args()
    print(machine_line(), flush=True)
    work = args.keep or Path(tempfile.mkdtemp(prefix="bench_process_"))
    work.mkdir(parents=True, exist_ok=True)
    try:
        bags = []
        for i in range(args.bags):
            p = work / f"flight{i}"
            if not p.exists():
                build_flight(p, args.seconds, i)
            bags.append(p)
        load0 = os.getloadavg()[0]
        runs = []
        for _ in range(max(args.repeat, 1)):
            wall, cpu = run_process(bags[:1], work / "out1", 1)
            timing = json.loads((work / "out1" / "flight0" / "timing.json").read_text())
            runs.append((wall, cpu, timing))
        summary = json.loads((work / "out1" / "flight0" / "summary.json").read_text())
        fl = summary["flight"]["duration_s"] + 1.0 / RATE_HZ
        print(
            f"one 1920x1080 bgr8 flight at {RATE_HZ:g} Hz, {summary['frames']['in']} frames "
            f"({fl:.1f} s), "
            f"config/bench.yaml, load average {load0:.1f}; {len(runs)} runs"
        )
        print(
            "| run | wall (s) | in process (s) | real-time factor | CPU (s) | frames kept | "
            "shifts | super-resolved (bicubic fallbacks) | peak RSS (MB) |"
        )
        fell = sum(bool(st.get("fell_back")) for st in summary["sets"])
        print("|---|---|---|---|---|---|---|---|---|")
        for k, (wall1, cpu1, timing) in enumerate(runs, 1):
            print(
                f"| `subpix process` 1 bag, run {k} | {wall1:.2f} | {timing['wall_s']:.2f} | "
                f"{fl / wall1:.2f}x ({fl / timing['wall_s']:.2f}x in process) | {cpu1:.1f} | "
                f"{summary['frames']['kept']} | {summary['frames']['shifts']} | "
                f"{len(summary['sets'])} ({fell}) | {timing['peak_rss_mb']:.0f} |"
            )
        med = sorted(r[0] for r in runs)[len(runs) // 2]
        med_in = sorted(r[2]["wall_s"] for r in runs)[len(runs) // 2]
        print(
            f"| median of {len(runs)} | {med:.2f} | {med_in:.2f} | {fl / med:.2f}x "
            f"({fl / med_in:.2f}x in process) | | | | | |"
        )
        timing = sorted(runs, key=lambda r: r[0])[len(runs) // 2][2]  # the median run's stages
        st = timing.get("stages", {})
        print("\n| stage | calls | median (ms) | p99 (ms) | total (s) |\n|---|---|---|---|---|")
        for name, s in sorted(st.items()):
            print(
                f"| {name} | {s['calls']} | {s['median_ms']:.1f} | {s['p99_ms']:.1f} | "
                f"{s['total_s']:.1f} |"
            )
        fm = timing["frame_ms"]
        print(f"| whole frame | {timing['frames']} | {fm['median']:.1f} | {fm['p99']:.1f} | |")
        if args.bags > 1:
            load1 = os.getloadavg()[0]
            seq, cpu_seq = run_process(bags, work / "seq", 1)
            par, cpu_par = run_process(bags, work / "par", 2)
            load2 = os.getloadavg()[0]
            print(
                f"\n{args.bags} flights ({args.seconds:g} s each), "
                f"load average {load1:.1f} -> {load2:.1f}"
            )
            print("| run | wall (s) | ratio to sequential | CPU (s) |\n|---|---|---|---|")
            print(f"| --jobs 1 (one after another) | {seq:.1f} | 1.00 | {cpu_seq:.1f} |")
            print(f"| --jobs 2 | {par:.1f} | {par / seq:.2f} | {cpu_par:.1f} |")
            print(
                f"(--jobs 2 cannot beat {cpu_par / 2:.1f} s, its CPU over the 2 cores: a ratio of "
                f"{cpu_par / 2 / seq:.2f} at best on a 2-core machine)"
                if (os.cpu_count() or 1) == 2
                else ""
            )
    finally:
        if args.keep is None:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
