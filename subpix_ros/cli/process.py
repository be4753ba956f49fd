"""``subpix process``: flight bags -> products and a flight report, without DDS.

Reads each bag directly (rosbag2, mcap or sqlite3; sensor_msgs/Image or
CompressedImage; telemetry from the bag's /telemetry/* topics or a .tlog
beside it), runs the stage pipeline in this process (or one worker process
per bag with --jobs), and writes OUTDIR/<bag name>/: results.mcap (shift,
homography, super_resolved/compressed and mosaic/compressed (the PNGs),
telemetry/frame_interval, diagnostics, stamped with their source frames;
`subpix replay` plays it), superres/*.png
beside bicubic/*.png of each set's reference, mosaic.png, shifts.csv,
frames.csv, telemetry.csv, summary.json, timing.json and report.html.

The same bag and parameters give byte-identical products (timing.json and
report.html carry the processing times). A folder is renamed into place only
when complete; a re-run skips complete bags (--force redoes them). A bag that
cannot be processed (or only in part: no images, a corrupt chunk, frames of
another size) gets one line and the exit status is 1 at the end; a bag
without telemetry is processed (every frame kept) and the report says so.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from subpix_ros.cli import CliError


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``subpix process`` subcommand to the CLI's subparsers ``sub``."""
    parser = sub.add_parser(
        "process",
        help="flight bags -> products and a flight report (no DDS)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("bags", nargs="+", metavar="BAG", help="rosbag2 bag folder, .mcap or .db3")
    parser.add_argument("-o", "--out", required=True, metavar="OUTDIR", help="output folder")
    parser.add_argument(
        "--params",
        action="append",
        default=[],
        metavar="FILE.yaml",
        help="stage parameters (config/*.yaml layout: node: ros__parameters: ...; /** for "
        "every node that declares the key); repeatable, a later file's values over an earlier "
        "one's (e.g. --params config/bench.yaml --params blur.yaml); a key no node declares, "
        "or a misspelt node name, is an error (status 2); default: the nodes' defaults",
    )
    parser.add_argument(
        "--jobs", type=int, default=1, metavar="N", help="bags processed in parallel (default 1)"
    )
    parser.add_argument(
        "--camera-topic",
        default=None,
        metavar="T",
        help="image topic (default /camera/image_raw, else the bag's image topic)",
    )
    parser.add_argument(
        "--telemetry",
        choices=("tlog", "topics"),
        default=None,
        help="telemetry source (default: the bag's /telemetry/* topics, else a .tlog beside it)",
    )
    parser.add_argument(
        "--force", action="store_true", help="redo bags whose products are complete"
    )
    parser.add_argument(
        "--skip-corrupt",
        action="store_true",
        help="go on past damaged chunks/records of a bag (default: stop the bag at the first "
        "one); what was skipped is in the summary and the report, and the bag counts as partial",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress output")
    parser.add_argument(
        "--serve",
        type=_port,
        nargs="?",
        const=8765,
        default=None,
        metavar="PORT",
        help="serve the processing live to Foxglove on ws://127.0.0.1:PORT (default 8765; "
        "the monitor_node's view: mosaic, SR vs bicubic, camera, shifts, GPS); --jobs 1 only",
    )
    parser.set_defaults(func=run)


def _port(text: str) -> int:
    """Return a TCP port number 1..65535 from the command line (argparse type)."""
    try:
        port = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a port number: {text!r}") from None
    if not 1 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"port {port} is not in 1..65535")
    return port


def run(args: argparse.Namespace) -> int:
    """Process the given bags (or folders of bags) into products and reports."""
    from subpix_ros.process.batch import Progress, interrupt_on_signals, run_batch
    from subpix_ros.process.inputs import InputError, bag_name
    from subpix_ros.process.params import (
        ParamsError,
        check_params,
        live_only_notes,
        load_params_files,
    )
    from subpix_ros.process.products import BATCH_SUMMARY
    from subpix_ros.runtime import favour_throughput

    favour_throughput()  # a batch job: page faults cost more than resident memory here

    if args.jobs < 1:
        raise CliError(f"--jobs must be >= 1, got {args.jobs}")
    try:
        # a key or node that cannot apply is said before any bag (exit status 2); another
        # program's node is ignored with a warning line
        params = load_params_files(args.params, say=lambda line: print(line, file=sys.stderr))
        check_params(params)
    except ParamsError as exc:
        raise CliError(str(exc), code=2) from None
    except InputError as exc:
        raise CliError(str(exc)) from None
    for line in live_only_notes(params):
        print(f"note: {line}", file=sys.stderr)
    names: dict[str, str] = {}
    for b in args.bags:
        n = bag_name(b)
        if n in names:
            raise CliError(f"bags {names[n]} and {b} would both write {Path(args.out) / n}")
        names[n] = b
    if not args.out.strip():
        raise CliError("-o/--out is empty: give the output folder")
    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CliError(f"cannot create {out}: {exc.strerror}") from None
    lock = _lock_out(out)  # held until the process ends  # noqa: F841
    monitor = None
    if args.serve is not None:
        if args.jobs != 1:
            raise CliError("--serve shows one bag at a time: use it with --jobs 1")
        from subpix_ros.monitor import Monitor, MonitorConfig, MonitorError

        try:
            monitor = Monitor(MonitorConfig(port=args.serve))  # started: bound, serving
        except (MonitorError, OSError) as exc:
            raise CliError(f"--serve: {exc}") from None
        print(f"serving the processing on {monitor.url}", file=sys.stderr, flush=True)
    interrupt_on_signals()  # Ctrl-C or a kill: unfinished folders removed, exit status 130
    progress = Progress(stream=sys.stderr, quiet=args.quiet)
    try:
        results = run_batch(
            args.bags,
            out,
            params,
            jobs=args.jobs,
            camera_topic=args.camera_topic,
            telemetry=args.telemetry,
            force=args.force,
            skip_corrupt=args.skip_corrupt,
            monitor=monitor,
            progress=progress,
        )
    finally:
        if monitor is not None:
            monitor.close()
    # a bag skipped as up to date keeps the status of the run that made its products
    failed = [
        r
        for r in results
        if r.status in ("failed", "partial") or r.previous_status in ("failed", "partial")
    ]
    lines = [r.line for r in results]
    try:
        _write_batch_summary(out, results)
    except OSError as exc:  # a full or read-only disk: the flights' own lines still say the rest
        print(
            f"subpix process: cannot write {out / BATCH_SUMMARY}: {exc.strerror or exc}",
            file=sys.stderr,
        )
        failed = failed or list(results)
    if not args.quiet:
        print("\n".join(["summary:"] + [f"  {ln}" for ln in lines]))
        for r in results:
            if r.out and r.status != "failed" and (Path(r.out) / "report.html").is_file():
                print(f"  report: {Path(r.out) / 'report.html'}")
    if failed:
        if args.quiet:  # no progress, but never a failure without its reason
            for r in failed:
                print(r.line, file=sys.stderr)
        print(
            f"subpix process: {len(failed)} of {len(results)} bag(s) failed or only partly usable: "
            f"{', '.join(r.name for r in failed)}",
            file=sys.stderr,
        )
        return 1
    return 0


def _write_batch_summary(out: Path, results) -> None:
    """Write ``OUTDIR/batch_summary.json``: one entry per bag of this run (atomically)."""
    from subpix_ros.process.products import BATCH_SUMMARY

    entries = [
        {
            "bag": r.bag,
            "name": r.name,
            "status": r.status,
            "previous_status": r.previous_status,
            "line": r.line,
            "out": r.out,
        }
        for r in results
    ]
    tmp = out / f".{BATCH_SUMMARY}.tmp"
    try:
        tmp.write_text(json.dumps(entries, indent=1) + "\n")
        tmp.replace(out / BATCH_SUMMARY)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _lock_out(out: Path) -> int:
    """Take OUTDIR for this run: an advisory lock on the folder itself (no file left in it).

    Returns the folder's open descriptor (the lock lasts while it is open: to the process's
    end, a kill included). Raises :class:`CliError` when another ``subpix process`` holds it,
    or OUTDIR cannot be written (a read-only file system): said before any bag is read.
    """
    import fcntl
    import os

    if not os.access(out, os.W_OK):
        raise CliError(
            f"cannot write in {out}: not writable (read-only file system or permissions)"
        )
    fd = os.open(out, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        raise CliError(
            f"another subpix process is writing {out}: wait for it to end, or choose another "
            "output folder (-o)"
        ) from None
    return fd
