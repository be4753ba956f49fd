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
    die_with_parent_if_asked,
    dump_stacks_on_sigusr1,
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
    "blur",
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
    dump_stacks_on_sigusr1()  # kill -USR1 <pid>: where a hung command is (subpix_ros.runtime)
    keep_freed_memory()  # frame buffers reused, not re-faulted per frame (subpix_ros.runtime)
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    if extra:  # said with the subcommand's usage, not the top-level one
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        sub.choices[args.command].error(f"unrecognized arguments: {' '.join(extra)}")
    die_with_parent_if_asked()  # SUBPIX_DIE_WITH_PARENT=1: a replay started by subpix demo
    if args.command in ("replay", "record", "demo"):
        clean_stale_shm_segments()  # the DDS commands: segments of killed processes (runtime)
    try:
        # before a subcommand creates a DDS participant (runtime); the recorder writes nothing
        # over DDS: the 1 MiB shared-memory segment, not 64 MiB
        configure_ros_environment(large_messages=args.command != "record")
    except RuntimeSetupError as exc:
        print(f"subpix {args.command}: error: {exc}", file=sys.stderr)
        return 2
    try:
        return int(args.func(args) or 0)
    except CliError as exc:
        print(f"subpix {args.command}: error: {exc}", file=sys.stderr)
        return exc.code
    except KeyboardInterrupt:
        print(f"subpix {args.command}: interrupted", file=sys.stderr)
        return 130


#: Subcommands that end with their products written and closed: the ``subpix`` command leaves
#: them without the interpreter's teardown (see :func:`console`).
_QUICK_EXIT = ("process", "report")


def console() -> None:
    """Run the ``subpix`` command (the console script) and exit with its status.

    After ``subpix process`` or ``subpix report`` has returned, every product is written,
    closed and moved into place: the exit handlers run (``atexit``: logging, multiprocessing),
    stdout and stderr are flushed, and the process ends with ``os._exit``, skipping the
    interpreter's teardown of its modules and objects (0.1-0.15 s after a 1080p flight; it
    frees nothing the kernel does not free at exit). Other subcommands (ROS participants,
    sockets) exit normally.
    """
    import atexit
    import os

    argv = sys.argv[1:]
    status = main(argv)
    if argv and argv[0] in _QUICK_EXIT:
        atexit._run_exitfuncs()
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError):  # a closed pipe: nothing more can be said
                pass
        os._exit(status)
    sys.exit(status)


if __name__ == "__main__":  # pragma: no cover
    console()
