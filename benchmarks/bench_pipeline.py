#!/usr/bin/env python3
"""End-to-end throughput and latency of the nodes at 1920x1080 (issue 6).

A camera stand-in in this process publishes 1920x1080 bgr8 frames (raw CDR,
stamped at publication) at ``--rate`` Hz: a real Seneca frame drifting by
(0.41, 0.27) px per frame (48 frames, played forwards then backwards), from a
participant with the package's Fast DDS profile as the README asks of a camera
driver (``--camera-default-dds``: Fast DDS's defaults, whose 512 KiB segment
delivers reliable 6 MB frames late, in bursts). The nodes run as

* ``separate``: registration, shift, reconstruction and mosaic nodes, each its
  own process, talking over DDS (the mosaic fed with the registration node's
  reference frames, ``image:=/aligned/reference``);
* ``single``: the ``pipeline`` executable (one process, stages in memory).

Printed per layout: frames in, shifts out, super-resolved images out, frames
dropped by each node's queue (from /diagnostics), latency frame-in ->
shift-out (p50, p99) and frames-in -> super-resolved-out (from the last frame
of a set), and the CPU time of the node processes.

Usage: python benchmarks/bench_pipeline.py [--rate 10] [--seconds 20] [--set 16] [--layouts separate single]
"""

from __future__ import annotations

import argparse
import os
import random
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
from machine_speed import machine_line  # noqa: E402

from subpix_ros.runtime import (  # noqa: E402
    add_malloc_argument,
    allocator_line,
    configure_ros_environment,
    proc_status_mb,
)

STEP = (0.41, 0.27)
SET = 16  # frames per super-resolved image (the reference and 15 aligned frames), --set


def make_frames(n: int, w: int = 1920, h: int = 1080) -> list[np.ndarray]:
    """N frames of a real scene drifting by STEP px per frame (bilinear warp of an upscaled Seneca frame)."""
    scene = cv2.imread(str(ROOT / "data" / "seneca" / "IMG_0463.jpg"), cv2.IMREAD_COLOR)
    size = (max(2400, w + 300), max(1800, h + 300))  # 2400x1800 up to 1080p, larger for 4K
    scene = cv2.resize(scene, size, interpolation=cv2.INTER_CUBIC)
    out = []
    for k in range(n):
        m = np.float32([[1, 0, -100 + k * STEP[1]], [0, 1, -100 + k * STEP[0]]])
        out.append(cv2.warpAffine(scene, m, (w, h), flags=cv2.INTER_LINEAR))
    return out


def add_params_argument(ap: argparse.ArgumentParser) -> None:
    """Add ``--params FILE`` (repeatable): node parameter files applied after bench.yaml."""
    ap.add_argument(
        "--params",
        action="append",
        default=[],
        metavar="FILE",
        help="a parameter file applied after config/bench.yaml (e.g. config/onboard.yaml)",
    )


def use_params(files: list[str]) -> None:
    """Hand ``--params`` files to :func:`start_layout` (through the environment) and say so."""
    if files:
        os.environ["SUBPIX_BENCH_PARAMS"] = os.pathsep.join(str(Path(f).resolve()) for f in files)
        print(f"parameters: config/bench.yaml, then {', '.join(files)}")


#: Set by use_camera_dds for the stand-in alone: not handed on to the node processes.
_STAND_IN_ONLY: dict[str, str] = {}


def add_camera_dds_argument(ap: argparse.ArgumentParser) -> None:
    """Add ``--camera-default-dds``: the camera stand-in without the package's Fast DDS profile."""
    ap.add_argument(
        "--camera-default-dds",
        action="store_true",
        help="run the camera stand-in on Fast DDS's defaults (a 512 KiB shared-memory segment), as "
        "a camera driver started without the package's profile (README: Camera frames between "
        "processes); the nodes keep the profile",
    )


def use_camera_dds(default_dds: bool) -> None:
    """Give the camera stand-in (this process) the package's Fast DDS profile, or not; say which.

    The segment that carries a frame is the publisher's: the README asks for a camera driver
    started with the package's profile, so the stand-in is too unless ``default_dds``
    (docs/design-notes.md, "Frame -> shift p99: the camera's Fast DDS segment").
    """
    if default_dds:
        _STAND_IN_ONLY["SKIP_DEFAULT_XML"] = "1"
        os.environ.update(_STAND_IN_ONLY)
        print(
            "camera stand-in: Fast DDS defaults (512 KiB shared-memory segment); nodes: the package's profile"
        )
    else:
        configure_ros_environment()
        print(
            "camera stand-in and nodes: the package's Fast DDS profile (64 MiB shared-memory segment)"
        )


def pingpong(k: int, n: int) -> int:
    """0, 1, ..., n-1, n-2, ..., 1, 0, 1, ...: the drift reverses instead of jumping back to the start."""
    i = k % (2 * n - 2)
    return i if i < n else 2 * n - 2 - i


def start_layout(layout: str, env: dict) -> list[subprocess.Popen]:
    env = {k: v for k, v in env.items() if _STAND_IN_ONLY.get(k) != v}
    override = Path(tempfile.gettempdir()) / f"bench_pipeline_set{SET}_{os.getpid()}.yaml"
    override.write_text(
        # the shipped files' section names (/**/node): merged into their entries, so that a
        # --params file after this one still wins (rcl orders entries by first appearance)
        f"/**/registration_node:\n  ros__parameters:\n    max_frames_per_reference: {SET - 1}\n"
        f"/**/reconstruction_node:\n  ros__parameters:\n    n_frames: {SET}\n"
        f"    min_frames: {min(SET, 4)}\n"  # at most n_frames (4: the default)
        f"    max_memory_mb: {float(env.get('SUBPIX_BENCH_MAX_MEMORY_MB') or 0.0)}\n"
    )
    params = ["--params-file", str(ROOT / "config" / "bench.yaml"), "--params-file", str(override)]
    for extra in filter(None, env.get("SUBPIX_BENCH_PARAMS", "").split(os.pathsep)):
        params += ["--params-file", str(Path(extra).resolve())]  # --params: applied last
    if layout == "single":
        cmds = [
            [
                sys.executable,
                "-m",
                "subpix_ros.nodes.pipeline",
                "--no-telemetry",
                "--ros-args",
                "-r",
                "image:=/camera/image_raw",
                *params,
            ]
        ]
    else:
        # the mosaic takes the registration node's reference frames (keyframes, 1 in max_frames_per_reference+1)
        # instead of a second 10 Hz camera subscription: the README's wiring for high camera rates
        remap = {
            "registration_node": ["-r", "image:=/camera/image_raw"],
            "mosaic_node": ["-r", "image:=/aligned/reference"],
        }
        cmds = [
            [sys.executable, "-m", f"subpix_ros.nodes.{n}", "--ros-args", *params]
            + remap.get(n, [])
            for n in ("registration_node", "shift_node", "reconstruction_node", "mosaic_node")
        ]
    return [
        subprocess.Popen(c, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        for c in cmds
    ]


def cpu_seconds(pid: int) -> float:
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except OSError:
        return float("nan")


def rss_parts_mb(pid: int) -> dict[str, float]:
    """VmRSS, its parts (RssAnon, RssFile, RssShmem: Fast DDS's segments) and VmHWM, MB.

    VmHWM is the kernel's high-water mark of VmRSS since the process started: the peak that
    samples taken now and then miss (the kernel counts resident pages per thread in batches,
    so a sample may read a few MB above it). Empty once the process is gone.
    """
    return proc_status_mb(("VmRSS", "VmHWM", "RssAnon", "RssFile", "RssShmem"), pid)


def run_layout(layout: str, frames: list[np.ndarray], rate: float, seconds: float) -> dict:
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import Vector3Stamped
    from sensor_msgs.msg import Image

    from subpix_ros.cli._ros import stop_processes
    from subpix_ros.io import cdr
    from subpix_ros.nodes.qos import FollowingSubscription, reliable_qos

    env = dict(os.environ)
    procs = start_layout(layout, env)
    rclpy.init()
    node = rclpy.create_node("bench_camera")
    pub = node.create_publisher(Image, "/camera/image_raw", reliable_qos(30))
    sent: dict[int, float] = {}
    shifts: dict[int, float] = {}
    srs: dict[int, float] = {}
    diag: dict[str, dict[str, str]] = {}
    node.create_subscription(
        Vector3Stamped,
        "/shift",
        lambda r: shifts.setdefault(
            cdr.header_to_ns(cdr.cdr_to_vector3_stamped(r)[1]), time.monotonic()
        ),
        reliable_qos(100),
        raw=True,
    )
    sr_sub = FollowingSubscription(  # noqa: F841 (kept alive)
        node,
        Image,
        "/super_resolved",
        lambda r: srs.setdefault(
            cdr.header_to_ns(cdr.cdr_to_image_msg(r).header), time.monotonic()
        ),
        raw=True,
    )
    node.create_subscription(
        DiagnosticArray,
        "/diagnostics",
        lambda m: diag.update({s.name: {kv.key: kv.value for kv in s.values} for s in m.status}),
        50,
    )
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not (
            pub.get_subscription_count() >= (1 if layout == "single" else 2)
            and node.count_publishers("/shift")
            and node.count_publishers("/super_resolved")
        ):
            rclpy.spin_once(node, timeout_sec=0.1)
        for _ in range(20):
            rclpy.spin_once(node, timeout_sec=0.05)
        cpu0 = [cpu_seconds(p.pid) for p in procs]
        self_cpu0 = time.process_time()
        n = int(rate * seconds)
        t0 = time.monotonic()
        base = time.time_ns()
        for k in range(n):
            target = t0 + k / rate
            while time.monotonic() < target:
                rclpy.spin_once(node, timeout_sec=max(0.0, min(0.005, target - time.monotonic())))
            stamp = base + int(k * 1e9 / rate)
            raw = cdr.image_to_cdr(frames[pingpong(k, len(frames))], "bgr8", stamp, "camera")
            sent[stamp] = time.monotonic()
            pub.publish(raw)
        wall = time.monotonic() - t0
        end = time.monotonic() + 30
        while time.monotonic() < end and len(shifts) < n - n // SET - 2:
            rclpy.spin_once(node, timeout_sec=0.05)
        end = time.monotonic() + 10
        while time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.05)
        cpu_each = [cpu_seconds(p.pid) - c0 for p, c0 in zip(procs, cpu0)]
        cpu = sum(cpu_each)
        hwm = [rss_parts_mb(p.pid).get("VmHWM", float("nan")) for p in procs]
        camera_cpu = time.process_time() - self_cpu0
    finally:
        node.destroy_node()
        rclpy.shutdown()
        stop_processes(procs)
    order = sorted(sent)
    lat_shift = np.array([shifts[s] - sent[s] for s in shifts if s in sent]) * 1000
    lat_sr = []
    for ref, t in srs.items():  # the set's last frame is SET-1 frames after its reference
        if ref in sent:
            i = order.index(ref)
            last = order[min(i + SET - 1, len(order) - 1)]
            lat_sr.append((t - sent[last]) * 1000)
    drops = {
        name.replace("_node", ""): d.get("dropped_frames", "?") for name, d in sorted(diag.items())
    }
    # frames that never reached a node (its subscription's history replaced: no DDS event)
    drops.update(
        {
            f"{n.replace('_node', '')} {k}": v
            for n, d in sorted(diag.items())
            for k, v in d.items()
            if k.startswith("messages_missed_")
        }
    )
    stage_keys = (
        "frames_tracked",
        "tracking_fallbacks",
        "images_fell_back",
        "worker_cpu_ms_per_item",
        "latency_p50_ms",
    )
    stages = {
        name.replace("_node", ""): {k: v for k, v in d.items() if k in stage_keys}
        for name, d in sorted(diag.items())
    }
    return {
        "layout": layout,
        "frames": len(sent),
        "rate": len(sent) / wall,
        "shifts": len(shifts),
        "sr": len(srs),
        "sr_fell_back": next(
            (d.get("images_fell_back", "?") for n, d in diag.items() if "reconstruction" in n),
            "?",
        ),
        "lat_shift": lat_shift,
        "lat_sr": np.array(lat_sr),
        "drops": drops,
        "stages": stages,
        "cpu_s_per_frame": cpu / len(sent),
        "cpu_each": [round(c / len(sent), 3) for c in cpu_each],
        "camera_cpu": camera_cpu / len(sent),
        "rss_peak_each": [round(m) for m in hwm],
    }


def pct(a: np.ndarray, q: float) -> str:
    return f"{np.percentile(a, q):8.0f}" if a.size else "       -"


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--rate", type=float, default=10.0)
    ap.add_argument("--seconds", type=float, default=20.0)
    global SET
    ap.add_argument(
        "--set", type=int, default=SET, help="frames per super-resolved image (default %(default)s)"
    )
    ap.add_argument(
        "--layouts", nargs="+", default=["separate", "single"], choices=["separate", "single"]
    )
    add_malloc_argument(ap, " in this process and the nodes")
    ap.add_argument(
        "--max-memory-mb",
        type=float,
        default=None,
        help="the reconstruction's max_memory_mb (default: unbounded)",
    )
    add_params_argument(ap)
    add_camera_dds_argument(ap)
    args = ap.parse_args()
    print(machine_line(), flush=True)
    if args.max_memory_mb:
        os.environ["SUBPIX_BENCH_MAX_MEMORY_MB"] = str(args.max_memory_mb)
    use_params(args.params)
    use_camera_dds(args.camera_default_dds)
    print(allocator_line(args.default_malloc))
    SET = max(2, args.set)
    os.environ.setdefault("ROS_DOMAIN_ID", str(random.randint(101, 199)))
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    frames = make_frames(48)
    rows = [run_layout(layout, frames, args.rate, args.seconds) for layout in args.layouts]
    print(
        f"\n1920x1080 bgr8 at {args.rate:g} Hz for {args.seconds:g} s, sets of {SET} frames, x2 super-resolution"
        f"{'' if not args.max_memory_mb else f', max_memory_mb {args.max_memory_mb:g}'} "
        f"(load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs)"
    )
    print(
        "| layout   | frames in | in Hz | shifts out | SR out (bicubic fallbacks) "
        "| frame->shift p50/p99 ms | set->SR p50/p99 ms "
        "| CPU s/frame | RSS peak MB (VmHWM; sum over processes) | dropped (per node) |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['layout']:8s} | {r['frames']:9d} | {r['rate']:5.1f} | {r['shifts']:10d} | "
            f"{r['sr']:6d} ({r['sr_fell_back']}) | "
            f"{pct(r['lat_shift'], 50)} / {pct(r['lat_shift'], 99)} | {pct(r['lat_sr'], 50)} / {pct(r['lat_sr'], 99)} | "
            f"{r['cpu_s_per_frame']:.3f} | {sum(r['rss_peak_each']):.0f} | {r['drops']} |"
        )
    for r in rows:
        print(
            f"  {r['layout']}: CPU s/frame per process {r['cpu_each']} (camera stand-in {r['camera_cpu']:.3f}); "
            f"RSS peak MB per process {r['rss_peak_each']} (each counts the shared libraries and "
            "its Fast DDS segment: the sum overstates what the processes hold together); "
            f"last stage figures from /diagnostics: {r['stages']}"
        )


if __name__ == "__main__":
    main()
