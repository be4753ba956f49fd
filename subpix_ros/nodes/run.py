"""The ``main`` of every node console entry point."""

from __future__ import annotations

import sys
from typing import Callable, Sequence

import rclpy
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node

from ..runtime import (
    RuntimeSetupError,
    clean_stale_shm_segments,
    configure_allocator,
    configure_opencv_threads,
    configure_ros_environment,
)

__all__ = ["run_nodes"]


def run_nodes(
    factories: Sequence[Callable[[], Node]],
    args: Sequence[str] | None = None,
    threads: int | None = None,
) -> int:
    """Init rclpy, build the nodes, spin them on a MultiThreadedExecutor, shut down cleanly.

    Parameters
    ----------
    factories : sequence of callable
        Each returns one node.
    args : sequence of str, optional
        Command-line arguments for ``rclpy.init`` (``--ros-args ...``).
    threads : int, optional
        Executor threads (default: rclpy's).

    Returns
    -------
    int
        Exit status: 0, or 2 when the ROS / DDS environment cannot be configured.

    Notes
    -----
    Freed frame buffers stay in the process's heap for reuse
    (:func:`subpix_ros.runtime.keep_freed_memory`), or with ``SUBPIX_MALLOC=memory`` every
    thread allocates from one arena (:func:`subpix_ros.runtime.favour_memory`); the ROS / DDS defaults of
    :func:`subpix_ros.runtime.configure_ros_environment` are applied before the participant is
    created, or the process refuses to start with one line on stderr. OpenCV runs its loops
    in the calling thread unless ``OPENCV_FOR_THREADS_NUM`` says otherwise
    (:func:`subpix_ros.runtime.configure_opencv_threads`).
    """
    configure_allocator()
    configure_opencv_threads()
    clean_stale_shm_segments()  # segments of killed processes (64 MiB each with our profile)
    try:
        configure_ros_environment()
    except RuntimeSetupError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    rclpy.init(args=args)
    nodes: list[Node] = []
    executor = MultiThreadedExecutor(num_threads=threads)
    try:
        for make in factories:
            nodes.append(make())
            executor.add_node(nodes[-1])
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        for n in nodes:
            close = getattr(n, "close", None)
            if close is not None:
                close()
            n.destroy_node()
        executor.shutdown()
        if rclpy.ok():
            rclpy.shutdown()
    return 0
