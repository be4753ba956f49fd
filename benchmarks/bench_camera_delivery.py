#!/usr/bin/env python3
"""How often camera frames reach the registration node in separate processes (issue 19, item 1).

Each run starts ``registration_node``, ``shift_node`` and ``reconstruction_node`` as the README's
"Running the nodes" shows (camera remapped to /camera/image_raw, ``use_sim_time``), each its own
process, in a *plainly activated venv*: the environment is this one's minus every ROS / DDS
variable (``RMW_IMPLEMENTATION``, ``ROS_*``, ``AMENT_PREFIX_PATH``, ``FASTRTPS_*``, ``FASTDDS_*``)
plus what ``.venv/bin/activate`` sets (``PATH``, ``VIRTUAL_ENV``) and ``ROS_DOMAIN_ID`` for
isolation. Then ``subpix replay BAG --clock`` (no ``--wait-for``), then a few seconds for the
nodes to finish. A listener process (same environment) counts what came out: the registration
node's ``input_total`` from /diagnostics, shifts, super-resolved images.

``--extra VAR=VALUE`` adds a variable to the environment of every process (e.g. the settings of
``scripts/env.sh``: ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``), ``--replay-extra`` to the
replay's only (the camera process), ``--kill-first`` SIGKILLs a first set of the nodes before
each run (stale ``/dev/shm/fastrtps_*`` files), ``--settle`` is the time between starting the
nodes and the replay. ``--bag mono512`` replays an 8-frame 512x512 mono8 bag (written to a
temporary folder) instead of the README's ``data/bags/subpixel``. Results:
docs/design-notes.md, "Camera frames between processes".

Printed: one line per run, then runs with frames delivered / runs.

Usage: python benchmarks/bench_camera_delivery.py [--runs 7] [--bag subpixel|mono512] [--settle 3]
       [--extra VAR=VALUE ...] [--kill-first] [--reliable]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from subpix_ros.runtime import plain_venv_environ  # noqa: E402

VENV = ROOT / ".venv"

LISTENER = r"""
import json, signal, sys
import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.qos import QoSProfile, ReliabilityPolicy, DurabilityPolicy, HistoryPolicy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Vector3Stamped
from sensor_msgs.msg import Image
rclpy.init()
node = rclpy.create_node("delivery_listener")
out = {"input_total": 0, "shifts": 0, "super_resolved": 0, "registered": 0, "diag": {}}
def on_diag(m):
    for s in m.status:
        v = {kv.key: kv.value for kv in s.values}
        out["diag"][s.name] = {"level": s.level[0] if isinstance(s.level, bytes) else int(s.level),
                               "message": s.message}
        if s.name == "registration_node":
            out["input_total"] = max(out["input_total"], int(v.get("input_total", 0)))
rel = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE)
lat = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE,
                 durability=DurabilityPolicy.TRANSIENT_LOCAL)
node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 100)
from sensor_msgs.msg import TimeReference
def count(key):
    return lambda r: out.__setitem__(key, out[key] + 1)
node.create_subscription(Vector3Stamped, "/shift", count("shifts"), rel, raw=True)
node.create_subscription(Image, "/super_resolved", count("super_resolved"), lat, raw=True)
node.create_subscription(TimeReference, "/aligned/reference_stamp", count("registered"), rel,
                         raw=True)
node.create_subscription(Image, "/aligned/reference", count("registered"), lat, raw=True)
print("listening", flush=True)
try:
    rclpy.spin(node)
except (KeyboardInterrupt, ExternalShutdownException):
    pass
print(json.dumps(out), flush=True)
"""


def plain_env(extra: dict[str, str], domain: str) -> dict[str, str]:
    """Return the environment as `source .venv/bin/activate` leaves it, without ROS / DDS vars."""
    env = plain_venv_environ(VENV, domain)
    env["PYTHONUNBUFFERED"] = "1"
    env.update(extra)
    return env


def write_mono512(folder: Path) -> Path:
    """8 frames 512x512 mono8 on /camera/image_raw at 10 Hz (a real crop drifting 0.4 px/frame)."""
    import cv2
    import numpy as np

    from subpix_ros.data import CROP_NAMES, load_crop
    from subpix_ros.io.bags import BagWriter
    from subpix_ros.io.cdr import image_to_cdr

    crop = load_crop(CROP_NAMES[0]).astype(np.float32)
    bag = folder / "mono512"
    with BagWriter(bag) as w:
        for k in range(8):
            m = np.float32([[1, 0, -100 + 0.27 * k], [0, 1, -100 + 0.41 * k]])
            frame = cv2.warpAffine(crop, m, (512, 512), flags=cv2.INTER_LINEAR)
            ns = 1_700_000_000_000_000_000 + k * 100_000_000
            w.write(
                "/camera/image_raw",
                "sensor_msgs/msg/Image",
                ns,
                image_to_cdr(np.clip(frame, 0, 255).astype(np.uint8), "mono8", ns, "camera"),
            )
    return bag


def start_nodes(env: dict, reliable: bool, log: Path) -> list[subprocess.Popen]:
    extra = ["-p", "camera_reliable:=true"] if reliable else []
    cmds = [
        [
            "registration_node",
            "--ros-args",
            "-r",
            "image:=/camera/image_raw",
            "-p",
            "use_sim_time:=true",
            *extra,
        ],
        ["shift_node", "--ros-args", "-p", "use_sim_time:=true"],
        ["reconstruction_node", "--ros-args", "-p", "use_sim_time:=true"],
    ]
    fh = open(log, "a")
    return [subprocess.Popen(c, env=env, stdout=fh, stderr=subprocess.STDOUT) for c in cmds]


def stop(procs, sig=signal.SIGINT, timeout=10.0) -> None:
    for p in procs:
        if p.poll() is None:
            p.send_signal(sig)
    for p in procs:
        try:
            p.wait(timeout)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def shm_files() -> int:
    prefixes = ("fastrtps_", "fast_datasharing", "sem.fastrtps")
    return sum(1 for n in os.listdir("/dev/shm") if n.startswith(prefixes))


def one_run(args, env: dict, bag: Path, log: Path) -> dict:
    if args.kill_first:
        first = start_nodes(env, args.reliable, log)
        time.sleep(args.settle)
        stop(first, signal.SIGKILL)
    shm_before = shm_files()
    listener = subprocess.Popen(
        [str(VENV / "bin" / "python"), "-c", LISTENER],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    assert listener.stdout.readline().strip() == "listening"
    nodes = start_nodes(env, args.reliable, log)
    time.sleep(args.settle)
    t0 = time.monotonic()
    renv = dict(env, **dict(e.split("=", 1) for e in args.replay_extra))
    r = subprocess.run(
        ["subpix", "replay", str(bag), "--clock", *args.replay_args],
        env=renv,
        capture_output=True,
        text=True,
        timeout=120,
    )
    replay_s = time.monotonic() - t0
    time.sleep(args.after)
    stop(nodes)
    listener.send_signal(signal.SIGINT)
    out, _ = listener.communicate(timeout=20)
    res = json.loads(out.strip().splitlines()[-1])
    res.update(
        replay_rc=r.returncode,
        replay=(r.stdout + r.stderr).strip().splitlines()[-1:],
        replay_s=replay_s,
        shm_before=shm_before,
    )
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=7)
    ap.add_argument(
        "--bag", default="subpixel", help="subpixel (README) or mono512 (8 frames 512x512 mono8)"
    )
    ap.add_argument(
        "--settle",
        type=float,
        default=3.0,
        help="seconds between starting the nodes and the replay",
    )
    ap.add_argument(
        "--after", type=float, default=6.0, help="seconds after the replay before stopping"
    )
    ap.add_argument("--extra", nargs="*", default=[], metavar="VAR=VALUE")
    ap.add_argument(
        "--replay-extra",
        nargs="*",
        default=[],
        metavar="VAR=VALUE",
        help="variables for the replay (the camera) only, e.g. SKIP_DEFAULT_XML=1",
    )
    ap.add_argument(
        "--kill-first", action="store_true", help="SIGKILL a first set of nodes before each run"
    )
    ap.add_argument("--reliable", action="store_true", help="camera_reliable:=true")
    ap.add_argument("--domain", default=os.environ.get("SUBPIX_TEST_DOMAIN_ID", "44"))
    ap.add_argument("--replay-args", nargs="*", default=[], help="more arguments for subpix replay")
    args = ap.parse_args()
    extra = dict(e.split("=", 1) for e in args.extra)
    env = plain_env(extra, args.domain)
    tmp = Path(tempfile.mkdtemp(prefix="bench_delivery_"))
    bag = ROOT / "data" / "bags" / "subpixel" if args.bag == "subpixel" else write_mono512(tmp)
    log = tmp / "nodes.log"
    print(
        f"bag {args.bag}, settle {args.settle} s, extra {extra or '-'}, "
        f"kill-first {args.kill_first}, "
        f"reliable {args.reliable}; node logs in {log}"
    )
    delivered = 0
    for k in range(args.runs):
        res = one_run(args, env, bag, log)
        ok = res["input_total"] > 0 or res["registered"] > 0
        delivered += ok
        diag = res["diag"].get("registration_node", {})
        print(
            f"run {k + 1}: registration input {res['input_total']:3d} (diag), frames registered "
            f"{res['registered']:3d}, shifts {res['shifts']:3d}, super-resolved "
            f"{res['super_resolved']}, diag {diag.get('level')} "
            f"{diag.get('message', '')[:100]!r}, shm files before {res['shm_before']}, "
            f"replay {res['replay_s']:.1f} s {res['replay']}",
            flush=True,
        )
    print(f"runs with frames delivered: {delivered}/{args.runs}")


if __name__ == "__main__":
    main()
