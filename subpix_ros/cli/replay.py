"""``subpix replay BAG``: publish a rosbag2 bag with its original timing."""

from __future__ import annotations

import argparse
import signal
import sys

from subpix_ros.cli import CliError
from subpix_ros.io.bags import BagCorrupt, BagError


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``subpix replay`` subcommand to the CLI's subparsers ``sub``."""
    parser = sub.add_parser(
        "replay",
        help="publish a bag's messages with their original timing (raw CDR pass-through)",
        description="Publish a rosbag2 bag (mcap or sqlite3; a bag folder or one .mcap file) "
        "with its original timing. "
        "Messages are published as the recorded bytes, never re-serialised.",
    )
    parser.add_argument("bag", help="bag folder (with metadata.yaml) or .mcap/.db3 file")
    parser.add_argument(
        "--rate", type=float, default=1.0, help="playback speed factor (default 1.0)"
    )
    parser.add_argument(
        "--loop", action="store_true", help="replay again and again until interrupted"
    )
    parser.add_argument(
        "--topics", nargs="+", metavar="TOPIC", help="only these topics (default: all)"
    )
    parser.add_argument(
        "--clock", action="store_true", help="also publish /clock (bag time) for use_sim_time nodes"
    )
    parser.add_argument(
        "--remap", nargs="+", default=[], metavar="FROM:=TO", help="publish topic FROM under TO"
    )
    parser.add_argument(
        "--wait-for",
        nargs="+",
        default=[],
        metavar="TOPIC",
        help="before starting, wait until these topics (the bag's names or their --remap "
        "names) have a subscriber (error if "
        "not within --wait-timeout); without it, wait until any replayed topic has "
        "one (replay anyway after --wait-timeout), since a subscriber still being "
        "discovered would miss the first messages",
    )
    parser.add_argument(
        "--wait-count",
        type=int,
        default=1,
        metavar="N",
        help="with --wait-for: wait until each of those topics has N subscribers (e.g. the "
        "camera read by the registration, mosaic and monitor nodes: 3), so that none misses "
        "the first messages while still being discovered (default 1)",
    )
    parser.add_argument(
        "--no-wait", action="store_true", help="start at once, matched subscribers or not"
    )
    parser.add_argument(
        "--wait-timeout",
        type=float,
        default=15.0,
        help="seconds to wait for subscribers (default 15)",
    )
    parser.add_argument(
        "--delay",
        type=float,
        default=0.5,
        help="seconds to wait before the first message (discovery)",
    )
    parser.add_argument(
        "--ack-timeout",
        type=float,
        default=10.0,
        help="after the last message, wait up to this many seconds until every reliable "
        "subscriber has acknowledged everything "
        "(a slow subscriber still gets the end of the bag); default 10",
    )
    parser.add_argument(
        "--skip-corrupt",
        action="store_true",
        help="replay what can be read from a damaged bag and report the skipped "
        "records at the end (the exit status is still non-zero); default: stop at the "
        "first damaged record",
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Publish the bag's messages with their original timing (at ``--rate``)."""
    import time

    from subpix_ros.cli._ros import ros_node
    from subpix_ros.io.player import Player

    if not args.ack_timeout >= 0:
        raise CliError(f"--ack-timeout must be >= 0, got {args.ack_timeout}")
    if args.wait_count < 1 or (args.wait_count > 1 and not args.wait_for):
        raise CliError(f"--wait-count {args.wait_count}: needs --wait-for and N >= 1")
    remap = {}
    for r in args.remap:
        if ":=" not in r:
            raise CliError(f"bad --remap {r!r}: use FROM:=TO")
        src, dst = r.split(":=", 1)
        remap[src] = dst
    try:
        with ros_node("subpix_replay", rclpy_signals=False) as node:
            player = Player(
                node,
                args.bag,
                topics=args.topics,
                rate=args.rate,
                loop=args.loop,
                clock=args.clock,
                remap=remap,
                skip_corrupt=args.skip_corrupt,
            )
            # Ctrl-C or a kill: the player stops between messages and the end is acknowledged
            # (SIGINT too: a job started with `&` inherits it ignored, and rclpy's own handler,
            # left out here, shut the context down under the player: a traceback, exit 1)
            signal.signal(signal.SIGTERM, lambda *_: player.stop())
            signal.signal(signal.SIGINT, lambda *_: player.stop())
            published_as = {dst: src for src, dst in remap.items()}  # a remapped name is fine too
            wait_for = [published_as.get(t, t) for t in args.wait_for]
            unknown = [
                t
                for t, b in zip(args.wait_for, wait_for)
                if b not in player.publishers and not (b == "/clock" and args.clock)
            ]
            if unknown:
                raise CliError(f"--wait-for topic(s) not replayed: {', '.join(unknown)}")
            if (
                wait_for
                and not player.wait_for_subscribers(wait_for, args.wait_timeout, args.wait_count)
                and not player.stopped  # stopped while waiting: nothing replayed, no error
            ):
                few = "no" if args.wait_count == 1 else f"fewer than {args.wait_count}"
                raise CliError(
                    f"{few} subscribers on {', '.join(args.wait_for)} within "
                    f"{args.wait_timeout:.0f} s"
                )
            waits = not args.wait_for and not args.no_wait
            if waits and not player.wait_for_any_subscriber(args.wait_timeout):
                print(
                    f"subpix replay: no subscriber on any replayed topic within "
                    f"{args.wait_timeout:g} s: replaying anyway",
                    file=sys.stderr,
                )
            time.sleep(max(0.0, args.delay))
            interrupted = False
            corrupt = None
            try:
                stats = player.play()
            except KeyboardInterrupt:
                stats, interrupted = player.stats, True
            except BagCorrupt as exc:  # the messages before it went out: let subscribers have them
                stats, corrupt = player.stats, exc
            interrupted = interrupted or player.stopped
            # Tearing the writers down with samples in flight would lose the end of the bag for a
            # subscriber that is behind; on Ctrl-C only a short grace.
            timeout = min(args.ack_timeout, 1.0) if interrupted else args.ack_timeout
            acked = player.wait_for_acks(timeout)
    except BagError as exc:
        raise CliError(str(exc)) from None
    if corrupt is not None:
        raise CliError(f"{corrupt} (replayed {stats.published} messages before it)", code=3)
    if not acked and not interrupted:
        print(
            "subpix replay: warning: not every reliable subscriber acknowledged every message "
            f"within {args.ack_timeout:g} s (a subscriber is slow, stalled or gone)",
            file=sys.stderr,
        )
    print(f"replayed {stats.published} messages from {args.bag} ({stats.loops} pass(es))")
    rep = player.read_report
    if rep.skipped_records:
        print(f"subpix replay: error: bag {args.bag} is corrupt: {rep.summary()}", file=sys.stderr)
        return 3
    return 0
