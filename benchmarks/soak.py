#!/usr/bin/env python3
"""Soak: the single-process pipeline fed 1920x1080 frames at 30 Hz for 18,000 frames (issue 7).

Not a CI test (10 minutes at 30 Hz). A camera stand-in publishes a loop of
64 real-scene frames (see bench_pipeline.make_frames) with fresh, increasing
stamps, played forwards then backwards (``--loop pingpong``, the default: a
continuous flight whose drift reverses) or jumping back to the first frame
(``--loop jump``: a scene cut of 26 x 17 px every 64 frames, which restarts the
registration's reference; the soaks before wave 2 session 6 ran this way); the stand-in
loads the package's Fast DDS profile (``--camera-default-dds``: not, as the soaks before wave 2
session 7); the pipeline's resident memory is sampled every 5 s. Printed: frames
in, shifts out, super-resolved images out, frames dropped per stage (the
bounded drop-oldest queues: at 30 Hz the pipeline is expected to drop, and
must count it), latency frame -> shift (p50, p99), and memory: RSS after
warm-up (first 60 s), at the end, growth, and the maximum, and the floor
(the lowest RSS of each minute: a leak lifts it, images in flight do not).

Usage: python benchmarks/soak.py [--frames 18000] [--rate 30] [--loop pingpong|jump]
"""

from __future__ import annotations

import argparse
import os
import random
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
from bench_pipeline import (  # noqa: E402
    add_camera_dds_argument,
    add_params_argument,
    cpu_seconds,
    make_frames,
    pingpong,
    rss_parts_mb,
    start_layout,
    use_camera_dds,
    use_params,
)
from machine_speed import machine_line  # noqa: E402

from subpix_ros.runtime import add_malloc_argument, allocator_line  # noqa: E402


def rss_mb(pid: int) -> float:
    return rss_parts_mb(pid).get("VmRSS", float("nan"))


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--frames", type=int, default=18000)
    ap.add_argument("--rate", type=float, default=30.0)
    ap.add_argument("--warmup-s", type=float, default=60.0)
    ap.add_argument(
        "--loop",
        choices=("pingpong", "jump"),
        default="pingpong",
        help="after the last frame: play backwards (default) or jump back to the first",
    )
    add_malloc_argument(ap, " in the pipeline process")
    ap.add_argument(
        "--max-memory-mb",
        type=float,
        default=None,
        help="the reconstruction's max_memory_mb (default: unbounded)",
    )
    ap.add_argument(
        "--mem-every-s",
        type=float,
        default=1.0,
        help="RSS sampled every this many s (default %(default)s); the peak is VmHWM's",
    )
    ap.add_argument("--size", default="1920x1080", help="WxH of the frames (default %(default)s)")
    add_params_argument(ap)
    add_camera_dds_argument(ap)
    args = ap.parse_args()
    print(machine_line(), flush=True)
    width, height = (int(v) for v in args.size.lower().split("x"))
    if args.max_memory_mb:
        os.environ["SUBPIX_BENCH_MAX_MEMORY_MB"] = str(args.max_memory_mb)
    use_params(args.params)
    use_camera_dds(args.camera_default_dds)
    print(allocator_line(args.default_malloc))
    os.environ.setdefault("ROS_DOMAIN_ID", str(random.randint(101, 199)))
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")

    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import Vector3Stamped
    from sensor_msgs.msg import Image

    from subpix_ros.io import cdr
    from subpix_ros.nodes.qos import FollowingSubscription, reliable_qos

    frames = make_frames(64, width, height)
    (proc,) = start_layout("single", dict(os.environ))
    rclpy.init()
    node = rclpy.create_node("soak_camera")
    pub = node.create_publisher(Image, "/camera/image_raw", reliable_qos(30))
    sent: dict[int, float] = {}
    lat: list[float] = []
    lat_at: list[float] = []  # when each frame of ``lat`` was sent, s after the first
    late: list[
        tuple[float, float]
    ] = []  # (s after the first frame, ms) the camera sent a frame late
    srs = [0]
    diag: dict[str, dict[str, str]] = {}
    t0s = [time.monotonic()]  # the first frame's send time, set when the camera starts

    def on_shift(raw):
        s = cdr.header_to_ns(cdr.cdr_to_vector3_stamped(raw)[1])
        t = sent.pop(s, None)
        if t is not None:
            lat.append(time.monotonic() - t)
            lat_at.append(t - t0s[0])

    node.create_subscription(Vector3Stamped, "/shift", on_shift, reliable_qos(100), raw=True)
    sr_sub = FollowingSubscription(  # noqa: F841 (kept alive)
        node, Image, "/super_resolved", lambda r: srs.__setitem__(0, srs[0] + 1), raw=True
    )
    loads: list[tuple[float, float]] = []  # (when, the pipeline's own process_cpu_cores)

    def on_diagnostics(m):
        diag.update({s.name: {kv.key: kv.value for kv in s.values} for s in m.status})
        for s in m.status:
            if s.name.endswith("registration_node"):
                loads.extend(
                    (time.monotonic(), float(kv.value))
                    for kv in s.values
                    if kv.key == "process_cpu_cores"
                )

    node.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, 50)
    mem: list[tuple[float, float]] = []
    peak: dict[str, float] = {}  # the RSS parts at the largest sample
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not (
            pub.get_subscription_count() and node.count_publishers("/shift")
        ):
            rclpy.spin_once(node, timeout_sec=0.1)
        t0 = time.monotonic()
        t0s[0] = t0
        cpu0 = cpu_seconds(proc.pid)
        next_mem = t0
        base = time.time_ns()
        for k in range(args.frames):
            target = t0 + k / args.rate
            while time.monotonic() < target:
                rclpy.spin_once(node, timeout_sec=max(0.0, min(0.005, target - time.monotonic())))
            stamp = base + int(k * 1e9 / args.rate)
            behind = time.monotonic() - target
            if behind > 0.05:  # this process (not the pipeline) was held up
                late.append((target - t0, behind * 1000))
            i = pingpong(k, len(frames)) if args.loop == "pingpong" else k % len(frames)
            pub.publish(cdr.image_to_cdr(frames[i], "bgr8", stamp, "camera"))
            sent[stamp] = time.monotonic()
            if len(sent) > 2000:  # frames never answered (dropped) leave the latency table
                for s in sorted(sent)[:1000]:
                    del sent[s]
            if time.monotonic() >= next_mem:
                parts = rss_parts_mb(proc.pid)
                mem.append((time.monotonic() - t0, parts.get("VmRSS", float("nan"))))
                if parts.get("VmRSS", 0) > peak.get("VmRSS", 0):
                    peak = parts
                next_mem += args.mem_every_s
                if proc.poll() is not None:
                    raise SystemExit(f"pipeline died with status {proc.returncode}")
        wall = time.monotonic() - t0
        end = time.monotonic() + 15
        while time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.05)
        mem.append((time.monotonic() - t0, rss_mb(proc.pid)))
        hwm = rss_parts_mb(proc.pid).get("VmHWM", float("nan"))
        cpu = cpu_seconds(proc.pid) - cpu0
        alive = proc.poll() is None
    finally:
        node.destroy_node()
        rclpy.shutdown()
        proc.send_signal(2)
        proc.wait(15)
    m = np.array(mem)
    after = m[m[:, 0] >= args.warmup_s]
    # RSS swings by hundreds of MB with the frames and 4K images in flight: compare the median of the
    # first and last fifth of the run after warm-up (a leak is a trend), and fit the trend itself
    k = max(1, len(after) // 5)
    base_mb = float(np.median(after[:k, 1]))
    end_mb = float(np.median(after[-k:, 1]))
    slope = (
        float(np.polyfit(after[:, 0], after[:, 1], 1)[0] * 60) if len(after) > 2 else float("nan")
    )
    # The floor: the lowest RSS of each minute after warm-up (what stays when no image is in flight). A leak
    # lifts the floor; frames and 4K images in flight only lift the peaks, which the medians above still see.
    win = np.floor((after[:, 0] - args.warmup_s) / 60.0)
    floors = np.array(
        [[w, after[win == w, 1].min()] for w in np.unique(win) if (win == w).sum() >= 6]
    )
    floor_slope = (
        float(np.polyfit(floors[:, 0], floors[:, 1], 1)[0]) if len(floors) > 2 else float("nan")
    )
    lat_ms = np.array(lat) * 1000
    drops = {n.replace("_node", ""): d.get("dropped_frames", "?") for n, d in sorted(diag.items())}
    # frames that never reached a node (its subscription's history replaced: no DDS event)
    drops.update(
        {
            f"{n.replace('_node', '')} {k}": v
            for n, d in sorted(diag.items())
            for k, v in d.items()
            if k.startswith("messages_missed_")
        }
    )
    print(
        f"\nsoak: single-process pipeline, {width}x{height} bgr8 at {args.rate:g} Hz, {args.frames} frames in {wall:.0f} s"
        f"{'' if not args.max_memory_mb else f', max_memory_mb {args.max_memory_mb:g}'} "
        f"(frames looped: {args.loop}; load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs)"
    )
    print(
        "| frames in | shifts out | SR out | frame->shift p50 / p99 ms | RSS after warm-up MB (median, first 1/5) | "
        "RSS end MB (median, last 1/5) | growth MB | trend MB/min | RSS max MB (sampled) | RSS peak MB (VmHWM) | "
        "crashed | dropped (per stage) |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    print(
        f"| {args.frames} | {len(lat)} | {srs[0]} | {np.percentile(lat_ms, 50):.0f} / {np.percentile(lat_ms, 99):.0f} | "
        f"{base_mb:.0f} | {end_mb:.0f} | {end_mb - base_mb:+.0f} | {slope:+.1f} | {m[:, 1].max():.0f} | {hwm:.0f} | {not alive} | "
        f"{drops} |"
    )
    if len(floors):
        print(
            f"RSS floor (lowest of each minute after warm-up), MB: first {floors[0, 1]:.0f}, last {floors[-1, 1]:.0f}, "
            f"trend {floor_slope:+.1f} MB/min over {len(floors)} minutes: "
            + ", ".join(f"{v:.0f}" for v in floors[:, 1])
        )
    print(f"pipeline process CPU {cpu / args.frames:.3f} s per frame in")
    reg_diag = next((d for n, d in diag.items() if n.endswith("registration_node")), {})
    during = [v for t, v in loads if t0 + 1.0 <= t <= t0 + wall]  # statuses of the run itself
    print(
        f"the pipeline's own /diagnostics: process_cpu_cores mean "
        f"{np.mean(during) if during else float('nan'):.3f} over the {len(during)} statuses of "
        f"the run (here: {cpu / wall:.3f} cores, its CPU with the 15 s tail over the run's "
        f"wall time), process_rss_peak_mb "
        f"{reg_diag.get('process_rss_peak_mb', '?')} (VmHWM read here: {hwm:.0f})"
    )
    rec = next((d for n, d in diag.items() if n.endswith("reconstruction_node")), {})
    print(
        f"super-resolved images: {rec.get('images_made', '?')} made, "
        f"{rec.get('images_published', '?')} published, of which "
        f"{rec.get('images_fell_back', '?')} fell back to bicubic (last: method "
        f"{rec.get('method', '?')}, {rec.get('fallback_reason', '') or 'no reason'}; memory "
        f"{rec.get('memory_reduction', '') or 'not reduced'}; sets skipped for max_cpu_cores "
        f"{rec.get('sets_skipped_budget', '?')}, last set {rec.get('set_cpu_time_s', '?')} s of CPU)"
    )
    if rec.get("images_fell_back", "0") not in ("0", "?"):
        print(
            "WARNING: bicubic fallbacks are not super-resolution: the figures above are not those of SR"
        )
    print(
        "RSS at its largest sample, MB: "
        + ", ".join(f"{k} {v:.0f}" for k, v in peak.items() if k != "VmHWM")
    )
    reg = next((d for n, d in diag.items() if n.endswith("registration_node")), {})
    print(
        "registration node, last /diagnostics: camera frames received after their stamps p50 / max "
        f"{reg.get('camera_delay_ms_p50', '?')} / {reg.get('camera_delay_ms_max', '?')} ms (last 200); "
        f"warnings {reg.get('warnings_total', '?')}, recent: {reg.get('recent_problems', '?')[:300]}"
    )
    print(
        "memory samples (s, MB): "
        + ", ".join(f"{t:.0f}:{v:.0f}" for t, v in m[:: max(1, len(m) // 20)])
    )
    worst = np.argsort(lat_ms)[::-1][:12]
    print(
        "slowest frames -> shift (sent at s: ms): "
        + ", ".join(
            f"{lat_at[i]:.1f}:{lat_ms[i]:.0f}" for i in sorted(worst, key=lambda i: lat_at[i])
        )
    )
    print(
        f"camera stand-in late by > 50 ms: {len(late)} frames"
        + (
            ": "
            + ", ".join(f"{t:.1f}:{ms:.0f}" for t, ms in sorted(late, key=lambda x: -x[1])[:12])
            if late
            else ""
        )
    )


if __name__ == "__main__":
    main()
