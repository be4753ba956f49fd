"""``subpix record -o OUT.mcap TOPIC...``: write live topics to a rosbag2 file."""
from __future__ import annotations

import argparse
import signal
import threading
import time

from subpix_ros.cli import CliError
from subpix_ros.io.bags import BagError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "record",
        help="record topics (raw CDR) into a rosbag2 mcap file",
        description="Subscribe to TOPICs without deserialising and write a rosbag2 bag that `subpix replay` "
        "and the standard ROS 2 tools read. OUT ending in .mcap is one MCAP file; anything else a bag folder.",
    )
    p.add_argument("-o", "--output", required=True, help="OUT.mcap file, or a bag folder name")
    p.add_argument("topics", nargs="+", metavar="TOPIC")
    p.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap", help="bag folder storage (default mcap)")
    p.add_argument("--duration", type=float, default=0.0, help="stop after this many seconds (0: until Ctrl-C)")
    p.add_argument("--count", type=int, default=0, help="stop after this many messages (0: no limit)")
    p.add_argument("--discover-timeout", type=float, default=10.0, help="seconds to wait for the topics to appear")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

    from subpix_ros.cli._ros import ros_node
    from subpix_ros.io.player import Recorder

    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    try:
        with ros_node("subpix_record") as node:
            rec = Recorder(node, args.output, args.topics, discover_timeout_s=args.discover_timeout,
                           storage=args.storage)
            print(f"recording {', '.join(args.topics)} -> {args.output}", flush=True)
            ex = SingleThreadedExecutor()
            ex.add_node(node)
            t0 = time.monotonic()
            try:
                while not stop.is_set():
                    ex.spin_once(timeout_sec=0.1)
                    if args.duration and time.monotonic() - t0 >= args.duration:
                        break
                    if args.count and rec.count >= args.count:
                        break
            except (KeyboardInterrupt, ExternalShutdownException):
                pass  # Ctrl-C / SIGINT: rclpy's handler shut the context down; close the bag cleanly
            finally:
                rec.close()
                ex.shutdown()
    except BagError as exc:
        raise CliError(str(exc)) from None
    print(f"recorded {rec.count} messages to {args.output}")
    return 0
