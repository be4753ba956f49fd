"""rclpy start-up shared by the CLI subcommands that talk ROS."""

from __future__ import annotations

import contextlib
import signal
import subprocess
from typing import Iterable, Iterator

from subpix_ros.io.participant import detach_discovery_listener

__all__ = ["ros_node", "stop_processes"]


@contextlib.contextmanager
def ros_node(name: str, use_sim_time: bool = False, rclpy_signals: bool = True) -> Iterator[object]:
    """Yield one node in an initialised rclpy context, torn down on exit.

    ``rclpy_signals`` False leaves SIGINT and SIGTERM to the command: rclpy's own handler shuts
    the context down at once, so a command that publishes could not finish cleanly (its next
    publish raised "publisher's context is invalid").
    """
    import rclpy
    from rclpy.parameter import Parameter
    from rclpy.signals import SignalHandlerOptions

    # Not sys.argv: rcl would read the command's own FROM:=TO arguments (subpix replay --remap)
    # as ROS 1 style remap rules for every name of the node, its /rosout logger included.
    rclpy.init(
        args=[],
        signal_handler_options=SignalHandlerOptions.ALL
        if rclpy_signals
        else SignalHandlerOptions.NO,
    )
    node = rclpy.create_node(
        name, parameter_overrides=[Parameter("use_sim_time", value=use_sim_time)]
    )
    try:
        yield node
    finally:
        detach_discovery_listener(node)  # before the participant goes: see its docstring
        node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()


def stop_processes(procs: Iterable[subprocess.Popen], timeout: float = 10.0) -> None:
    """SIGINT every process still running (a node's clean shutdown), wait, and kill what hangs."""
    procs = list(procs)
    for proc in procs:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
    for proc in procs:
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
