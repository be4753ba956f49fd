"""``subpix report OUTDIR``: (re)write report.html of processed flights.

OUTDIR is either one flight's product folder (with summary.json) or the
output folder of `subpix process` (each complete flight folder in it).
The report is one self-contained HTML file (pictures inline, no network).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from subpix_ros.cli import CliError


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``subpix report`` subcommand to the CLI's subparsers ``sub``."""
    parser = sub.add_parser(
        "report",
        help="write report.html of processed flights",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "outdir", metavar="OUTDIR", help="a flight's product folder or `subpix process` -o folder"
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Write report.html of one processed flight, or of every flight in a batch folder."""
    from subpix_ros.process.products import is_complete
    from subpix_ros.process.report import write_report

    root = Path(args.outdir)
    if not root.is_dir():
        raise CliError(f"not a folder: {root}")
    folders = (
        [root]
        if is_complete(root)
        else sorted(
            d
            for d in root.iterdir()
            if d.is_dir() and not d.name.startswith(".") and is_complete(d)
        )
    )
    if not folders:
        raise CliError(
            f"no processed flight in {root} (no summary.json): run `subpix process` first"
        )
    for d in folders:
        try:
            print(write_report(d))
        except (OSError, ValueError, KeyError) as exc:
            raise CliError(f"cannot write the report of {d}: {exc}") from None
    return 0
