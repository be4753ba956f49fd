"""The ``subpix`` command-line tool.

Each subcommand lives in its own module under ``subpix_ros.cli`` and exposes
``register(subparsers)``, which adds its parser(s) and sets ``func`` to a
callable ``func(args) -> int``. A subcommand reports a user error by raising
:class:`CliError`; ``main`` prints it as one line and exits non-zero (no
traceback wall).
"""

from __future__ import annotations

import argparse
import importlib
import sys
from typing import Sequence

from ..runtime import (
    RuntimeSetupError,
    clean_stale_shm_segments,
    configure_ros_environment,
    keep_freed_memory,
)

# Subcommand modules, in the order ``subpix --help`` lists them.
MODULES = (
    "demo",
    "process",
    "report",
    "replay",
    "record",
    "shift",
    "interval",
    "register",
    "mosaic",
    "superres",
    "mtf",
)


class CliError(Exception):
    """A user-facing error: printed as one line, exit status ``code``."""

    def __init__(self, message: str, code: int = 1) -> None:
        super().__init__(message)
        self.code = code


def build_parser() -> argparse.ArgumentParser:
    """Return the ``subpix`` parser with every installed subcommand registered."""
    parser = argparse.ArgumentParser(
        prog="subpix", description="Sub-pixel processing of drone imagery (subpix_ros)."
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in MODULES:
        module = f"{__name__}.{name}"
        try:
            importlib.import_module(module).register(sub)
        except ModuleNotFoundError as exc:
            if exc.name != module:  # a missing dependency is a real error
                raise
            # not installed in this build: test/test_cli.py checks all are present
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``subpix`` command line.

    Parameters
    ----------
    argv : sequence of str or None
        Arguments (default: ``sys.argv[1:]``).

    Returns
    -------
    int
        Exit status: the subcommand's, 2 when the ROS environment cannot be
        set up, a :class:`CliError`'s code, 130 on Ctrl-C.
    """
    keep_freed_memory()  # frame buffers reused, not re-faulted per frame (subpix_ros.runtime)
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command in ("replay", "record", "demo"):
        clean_stale_shm_segments()  # the DDS commands: segments of killed processes (runtime)
    try:
        configure_ros_environment()  # before a subcommand creates a DDS participant (runtime)
    except RuntimeSetupError as exc:
        print(f"subpix {args.command}: error: {exc}", file=sys.stderr)
        return 2
    try:
        return int(args.func(args) or 0)
    except CliError as exc:
        print(f"subpix {args.command}: error: {exc}", file=sys.stderr)
        return exc.code
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
