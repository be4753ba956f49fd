"""The node processes' console entry points.

Each entry point imports its node module (rclpy, OpenCV and numpy: about a second) inside a
guard, so that a Ctrl-C while a node is still starting ends it with one line on stderr and
exit status 130 instead of Python's traceback from deep inside an import. Once
:func:`subpix_ros.nodes.run.run_nodes` has installed its signal handlers, a Ctrl-C is the
node's ordinary stop.
"""

from __future__ import annotations

import importlib
import sys
from functools import partial

__all__ = ["start", "NODE_MODULES"]

#: The node modules that have a console entry point of the same name.
NODE_MODULES = (
    "telemetry_node",
    "registration_node",
    "shift_node",
    "reconstruction_node",
    "mosaic_node",
    "pipeline",
    "monitor_node",
)

#: Exit status of a process stopped by Ctrl-C while starting (128 + SIGINT, as a shell reports).
INTERRUPTED = 130


def start(module: str, args: list[str] | None = None) -> int:
    """Import ``subpix_ros.nodes.<module>`` and run its ``main``.

    Parameters
    ----------
    module : str
        One of :data:`NODE_MODULES`.
    args : list of str, optional
        Passed to the node's ``main`` (``None``: ``sys.argv``).

    Returns
    -------
    int
        The node's exit status, or :data:`INTERRUPTED` when a Ctrl-C came while the node
        module was importing ("interrupted while starting"), or outside the node's own
        handling of its signals ("interrupted"): one line on stderr.
    """
    if module not in NODE_MODULES:
        raise ValueError(f"no node module {module!r}; one of {', '.join(NODE_MODULES)}")
    try:
        main = importlib.import_module(f"subpix_ros.nodes.{module}").main
    except KeyboardInterrupt:
        print(f"{module}: interrupted while starting", file=sys.stderr, flush=True)
        return INTERRUPTED
    try:
        return main(args)
    except KeyboardInterrupt:  # before the node took its signals over, or after it gave them back
        print(f"{module}: interrupted", file=sys.stderr, flush=True)
        return INTERRUPTED


# The console entry points (setup.py): each the guarded start of its module, no argument.
telemetry_node = partial(start, "telemetry_node")
registration_node = partial(start, "registration_node")
shift_node = partial(start, "shift_node")
reconstruction_node = partial(start, "reconstruction_node")
mosaic_node = partial(start, "mosaic_node")
pipeline = partial(start, "pipeline")
monitor_node = partial(start, "monitor_node")
