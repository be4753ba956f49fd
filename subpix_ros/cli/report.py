"""``subpix report OUTDIR``: (re)write report.html of processed flights.

OUTDIR is either one flight's product folder (with summary.json) or the
output folder of `subpix process` (each flight folder in it). A flight that
cannot be reported (its summary.json unreadable), or whose folder lacks
products the run wrote (the report says which), is said on stderr, one line
each, and the exit status is 1.
The report is one self-contained HTML file (pictures inline, no network).
"""

from __future__ import annotations

import argparse
import sys
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


def _flight_folders(root: Path) -> list[Path]:
    """Return ``root`` if it is a flight's folder, else its flight folders (by name).

    A flight's folder is one with a ``summary.json``, readable or not: one that cannot be
    read is a flight that cannot be reported, said, not a folder passed over.
    """
    if (root / "summary.json").exists():
        return [root]
    return sorted(
        d
        for d in root.iterdir()
        if d.is_dir() and not d.name.startswith(".") and (d / "summary.json").exists()
    )


def run(args: argparse.Namespace) -> int:
    """Write report.html of one processed flight, or of every flight in a batch folder.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed ``subpix report`` arguments.

    Returns
    -------
    int
        0; 1 when a flight could not be reported (its ``summary.json`` unreadable, say) or
        lacks products the run wrote (its report, which says so, still written): one line on
        stderr for each; the others' reports still written.

    Raises
    ------
    CliError
        When OUTDIR is not a folder or holds no processed flight.
    """
    from subpix_ros.process.report import (
        ReportInputError,
        missing_products,
        read_summary,
        write_report,
    )

    root = Path(args.outdir)
    if not root.is_dir():
        raise CliError(f"not a folder: {root}")
    folders = _flight_folders(root)
    if not folders:
        raise CliError(
            f"no processed flight in {root} (no summary.json): run `subpix process` first"
        )
    failed = 0
    for d in folders:
        try:
            print(write_report(d), flush=True)
            missing = missing_products(d, read_summary(d))
        except ReportInputError as exc:
            why = f"cannot report {d}: {exc}"
        except (OSError, ValueError, KeyError) as exc:
            why = f"cannot write the report of {d}: {exc}"
        else:
            if not missing:
                continue
            why = (
                f"{d}: products missing (the report says so): {', '.join(missing)}; "
                "`subpix process --force` writes them again"
            )
        failed += 1
        print(f"subpix report: error: {why}", file=sys.stderr, flush=True)
    return 1 if failed else 0
