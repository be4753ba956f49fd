#!/usr/bin/env python3
"""CPU cost of 1080p frames between node processes, per Fast DDS profile (issue 22).

One publisher process sends ``--frames`` 1920x1080 bgr8 images (6.2 MB each, as the
registration node sends its aligned frames) at ``--rate`` Hz to two subscriber processes (as
the shift and reconstruction nodes take them), all with real rclpy and Fast DDS on this
machine, serialized as the nodes do it (``publish`` of CDR bytes, ``raw=True``
subscriptions, pixels viewed in place). Each process reports its own CPU time (``time.process_time``, every thread) over the
stream and what it received; the processes set the allocator as the nodes do
(``subpix_ros.runtime.configure_allocator``: freed frame buffers kept for reuse), and once
with glibc's defaults for comparison. Run once per profile: the package's
``config/fastdds_profile.xml`` (64 MiB shared-memory segment), the same with the shared-memory
transport's ``maxMessageSize`` at 16 MiB (a frame in one piece instead of 64 KB fragments) and
Fast DDS's built-in defaults (``SKIP_DEFAULT_XML=1``: a 512 KiB segment).

Printed: one line per profile and QoS (reliable depth 10, best effort depth 10): frames
received by each subscriber, CPU ms per frame of the publisher and of each subscriber, and the
total. The two cores are shared: the load average is printed beside.

Usage: python benchmarks/bench_large_messages.py [--frames 100] [--rate 10] [--size 1920x1080]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PROFILE = ROOT / "config" / "fastdds_profile.xml"

NODE = r"""
import json, sys, time
import numpy as np
import rclpy
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image

role, n, rate, w, h, reliable, wait_s = sys.argv[1], int(sys.argv[2]), float(sys.argv[3]), \
    int(sys.argv[4]), int(sys.argv[5]), sys.argv[6] == "1", float(sys.argv[7])
if sys.argv[8] == "1":  # the nodes' allocator setting (nodes/run.py)
    from subpix_ros.runtime import configure_allocator
    configure_allocator()
rclpy.init()
node = rclpy.create_node(f"large_{role}")
qos = QoSProfile(depth=10, history=HistoryPolicy.KEEP_LAST, reliability=(
    ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT))
if role == "pub":
    from rclpy.serialization import serialize_message
    pub = node.create_publisher(Image, "large_frames", qos)
    msg = Image(height=h, width=w, encoding="bgr8", step=3 * w)
    msg.data = np.random.default_rng(0).integers(0, 256, h * w * 3, dtype=np.uint8).tobytes()
    raw = serialize_message(msg)  # the nodes publish serialized CDR (nodes/payloads.py)
    t_end = time.monotonic() + wait_s
    while pub.get_subscription_count() < 2 and time.monotonic() < t_end:
        rclpy.spin_once(node, timeout_sec=0.05)
    time.sleep(0.5)
    c0, t0 = time.process_time(), time.monotonic()
    for k in range(n):
        pub.publish(raw)
        rclpy.spin_once(node, timeout_sec=max(0.0, t0 + (k + 1) / rate - time.monotonic()))
    cpu = time.process_time() - c0
    time.sleep(1.0)
    print(json.dumps({"role": role, "cpu_s": cpu, "n": n}), flush=True)
else:
    got = [0]
    c = [None]
    def on_msg(m):  # raw CDR bytes, viewed as pixels as the nodes do (no message object)
        if c[0] is None:
            c[0] = time.process_time()
        np.frombuffer(m, np.uint8, count=h * w * 3, offset=len(m) - h * w * 3)
        got[0] += 1
    node.create_subscription(Image, "large_frames", on_msg, qos, raw=True)
    t_end = time.monotonic() + wait_s + n / rate + 3.0
    last = time.monotonic()
    while time.monotonic() < t_end:
        before = got[0]
        rclpy.spin_once(node, timeout_sec=0.1)
        if got[0] != before:
            last = time.monotonic()
        elif got[0] and time.monotonic() - last > 2.0:
            break
    cpu = time.process_time() - (c[0] if c[0] is not None else time.process_time())
    print(json.dumps({"role": role, "cpu_s": cpu, "n": got[0]}), flush=True)
"""


def profiles(tmp: Path) -> dict[str, dict[str, str]]:
    """Environment additions per profile: the package's, a variant, Fast DDS's built-ins.

    The variant gives the shared-memory transport a 16 MiB message size (tried: whole frames
    instead of 64 KB fragments).
    """
    big = PROFILE.read_text().replace(
        "<segment_size>67108864</segment_size>",
        "<segment_size>67108864</segment_size><maxMessageSize>16777216</maxMessageSize>",
    )
    path = tmp / "fastdds_max_message_16mib.xml"
    path.write_text(big)
    return {
        "package profile": {"FASTRTPS_DEFAULT_PROFILES_FILE": str(PROFILE)},
        "+ SHM maxMessageSize 16 MiB": {"FASTRTPS_DEFAULT_PROFILES_FILE": str(path)},
        "Fast DDS defaults": {"SKIP_DEFAULT_XML": "1"},
    }


def run(env_extra: dict, args, reliable: bool, domain: str, nodes_malloc: bool = True) -> dict:
    """Start two subscribers and a publisher; return their reports."""
    env = {
        k: v
        for k, v in os.environ.items()
        if not k.startswith(("FASTRTPS_", "FASTDDS_", "ROS_")) and k != "SKIP_DEFAULT_XML"
    }
    env.update(env_extra, ROS_DOMAIN_ID=domain, RMW_IMPLEMENTATION="rmw_fastrtps_cpp")
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    w, h = (int(v) for v in args.size.lower().split("x"))
    common = [str(args.frames), str(args.rate), str(w), str(h), "1" if reliable else "0", "10"]
    common.append("1" if nodes_malloc else "0")
    subs = [
        subprocess.Popen(
            [sys.executable, "-c", NODE, f"sub{i}", *common],
            env=env,
            stdout=subprocess.PIPE,
            text=True,
        )
        for i in range(2)
    ]
    time.sleep(1.0)
    pub = subprocess.run(
        [sys.executable, "-c", NODE, "pub", *common],
        env=env,
        capture_output=True,
        text=True,
        timeout=60 + args.frames / args.rate,
    )
    outs = [json.loads(pub.stdout.strip().splitlines()[-1])]
    for s in subs:
        out, _ = s.communicate(timeout=30 + args.frames / args.rate)
        outs.append(json.loads(out.strip().splitlines()[-1]))
    return {o["role"]: o for o in outs}


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--rate", type=float, default=10.0)
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--domain", default=os.environ.get("SUBPIX_TEST_DOMAIN_ID", "47"))
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        table = profiles(Path(tmp))
        print(
            f"{args.size} bgr8 at {args.rate:g} Hz, {args.frames} frames, 1 publisher -> 2 "
            f"subscribers (separate processes), load average {os.getloadavg()[0]:.1f}"
        )
        print(
            "| profile | QoS | allocator | received (sub 1, sub 2) | CPU ms/frame: publisher | "
            "sub 1 | sub 2 | total |\n|---|---|---|---|---|---|---|---|"
        )
        cases = [(True, name, True) for name in table]
        cases += [(False, name, True) for name in table]
        cases += [(True, "package profile", False)]
        for reliable, name, nodes_malloc in cases:
            r = run(table[name], args, reliable, args.domain, nodes_malloc)
            per = {k: 1000.0 * v["cpu_s"] / args.frames for k, v in r.items()}
            print(
                f"| {name} | {'reliable' if reliable else 'best effort'} | "
                f"{'nodes' if nodes_malloc else 'glibc default'} | "
                f"{r['sub0']['n']}, {r['sub1']['n']} of {args.frames} | {per['pub']:.1f} | "
                f"{per['sub0']:.1f} | {per['sub1']:.1f} | {sum(per.values()):.1f} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
