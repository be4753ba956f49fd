"""``subpix record -o OUT.mcap TOPIC...``: write live topics to a rosbag2 file."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time

from subpix_ros.cli import CliError
from subpix_ros.io.bags import BagError


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``subpix record`` subcommand to the CLI's subparsers ``sub``."""
    parser = sub.add_parser(
        "record",
        help="record topics (raw CDR) into a rosbag2 mcap file",
        description="Subscribe to TOPICs without deserialising and write a rosbag2 bag that "
        "`subpix replay` and the standard ROS 2 tools read. OUT ending in .mcap is one MCAP file; "
        "anything else a bag folder. As `ros2 bag record`, it may be started before the "
        "publishers: each topic is subscribed when its first publisher appears (with that "
        "publisher's QoS) and recorded from then on. Ctrl-C or SIGTERM "
        "stops it with a complete bag.",
    )
    parser.add_argument("-o", "--output", required=True, help="OUT.mcap file, or a bag folder name")
    parser.add_argument("topics", nargs="+", metavar="TOPIC")
    parser.add_argument(
        "--storage",
        choices=("mcap", "sqlite3"),
        default="mcap",
        help="bag folder storage (default mcap)",
    )
    parser.add_argument(
        "--duration",
        type=float,
        default=0.0,
        help="stop this many seconds after the first topic was subscribed (0: until Ctrl-C)",
    )
    parser.add_argument(
        "--count", type=int, default=0, help="stop after this many messages (0: no limit)"
    )
    parser.add_argument(
        "--discover-timeout",
        type=float,
        default=None,
        metavar="S",
        help="give up (non-zero exit) if not every TOPIC has a publisher within S seconds; the bag "
        "keeps what was recorded (default: wait for the topics indefinitely)",
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Record the given topics into a bag until interrupted (or ``--duration``/``--count`` ends)."""
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

    from subpix_ros.cli._ros import ros_node
    from subpix_ros.io.player import Recorder

    if args.discover_timeout is not None and not args.discover_timeout > 0:
        raise CliError(f"--discover-timeout must be > 0, got {args.discover_timeout}")
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    timed_out = False
    try:
        with ros_node("subpix_record") as node:
            rec = Recorder(node, args.output, args.topics, storage=args.storage)
            print(
                f"waiting for publishers of {', '.join(args.topics)} -> {args.output}", flush=True
            )
            ex = SingleThreadedExecutor()
            ex.add_node(node)
            t0 = time.monotonic()
            t_first = None
            next_poll = 0.0
            try:
                while not stop.is_set():
                    now = time.monotonic()
                    if rec.pending and now >= next_poll:
                        for topic in rec.poll():
                            print(f"recording {topic} ({rec.subscribed[topic]})", flush=True)
                        t_first = t_first if t_first is not None or not rec.subscribed else now
                        next_poll = now + 0.1
                        if (
                            rec.pending
                            and args.discover_timeout is not None
                            and now - t0 >= args.discover_timeout
                        ):
                            timed_out = True
                            break
                    ex.spin_once(timeout_sec=0.05)
                    if (
                        args.duration
                        and t_first is not None
                        and time.monotonic() - t_first >= args.duration
                    ):
                        break
                    if args.count and rec.count >= args.count:
                        break
            except (KeyboardInterrupt, ExternalShutdownException):
                pass  # Ctrl-C / SIGINT: rclpy's handler shut the context down; close the bag
            finally:
                rec.close()
                ex.shutdown()
    except BagError as exc:
        raise CliError(str(exc)) from None
    missing = ", ".join(rec.pending)
    if timed_out:
        kept = (
            f"; {rec.count} messages of the others kept in {args.output}" if rec.subscribed else ""
        )
        raise CliError(
            f"no publisher found for topic(s) {missing} within {args.discover_timeout:g} s{kept}"
        )
    if not rec.subscribed:
        raise CliError(f"no publisher appeared for {missing}; nothing recorded")
    if rec.pending:
        print(
            f"subpix record: warning: no publisher appeared for {missing}; not in the bag",
            file=sys.stderr,
        )
    if rec.lost:
        lost = ", ".join(f"{t} {n}" for t, n in sorted(rec.lost.items()))
        print(
            f"subpix record: warning: messages lost in transport before the recorder took them, "
            f"not in the bag: {lost} (best-effort publishers of large messages without the "
            "package's Fast DDS profile, or a network that drops)",
            file=sys.stderr,
        )
    per_topic = ", ".join(f"{t} {n}" for t, n in rec.counts.items() if t in rec.subscribed)
    print(f"recorded {rec.count} messages to {args.output} ({per_topic})")
    return 0
