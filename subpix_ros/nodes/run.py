"""The ``main`` of every node console entry point."""

from __future__ import annotations

import os
import signal
import sys
import traceback
from dataclasses import dataclass, field
from typing import Callable, Sequence

import rclpy
from rclpy.executors import (
    Executor,
    ExternalShutdownException,
    MultiThreadedExecutor,
    SingleThreadedExecutor,
)
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from ..io.participant import detach_discovery_listener
from ..runtime import (
    RuntimeSetupError,
    clean_stale_shm_segments,
    configure_allocator,
    configure_opencv_threads,
    configure_ros_environment,
    die_with_parent_if_asked,
    dump_stacks_on_sigusr1,
)

__all__ = ["run_nodes", "shutdown_nodes", "Shutdown", "executor_kind", "EXECUTOR_ENV", "EXECUTORS"]

#: Environment variable choosing the executor of the node processes (see :func:`executor_kind`).
EXECUTOR_ENV = "SUBPIX_EXECUTOR"
#: ``single``: rclpy's SingleThreadedExecutor (the default); ``multi``: its MultiThreadedExecutor.
EXECUTORS = ("single", "multi")


def executor_kind(environ=None) -> str:
    """Return the executor the node processes spin on: ``SUBPIX_EXECUTOR``, default ``single``.

    The nodes' callbacks only decode, hand work to their own worker threads and publish, so
    one executor thread serves them. rclpy's MultiThreadedExecutor (``multi``) spins while a
    callback it handed to its pool has not started (ros2/rclpy#1452, fixed upstream after
    Jazzy's 7.1); figures in docs/design-notes.md ("One executor thread per node process").

    Raises
    ------
    ValueError
        If the variable holds anything else than ``single`` or ``multi``.
    """
    env = os.environ if environ is None else environ
    kind = env.get(EXECUTOR_ENV, "").strip().lower() or "single"
    if kind not in EXECUTORS:
        raise ValueError(
            f"{EXECUTOR_ENV}={env.get(EXECUTOR_ENV)!r}: use one of {', '.join(EXECUTORS)}"
        )
    return kind


def _make_executor(kind: str, threads: int | None) -> Executor:
    """Return the executor of :func:`executor_kind`'s choice (``threads``: the multi one's)."""
    if kind == "multi":
        return MultiThreadedExecutor(num_threads=threads)
    return SingleThreadedExecutor()


#: Seconds between the executor's checks of a stop request whose KeyboardInterrupt was lost.
STOP_CHECK_S = 0.5


class _StopRequest:
    """SIGINT / SIGTERM handler: raise KeyboardInterrupt, and remember that it was asked.

    Python runs a signal handler in the main thread between bytecodes. When that is inside a
    ``__del__`` or a weakref callback (importlib's module-lock callback, when a thread imports),
    the KeyboardInterrupt is printed as "Exception ignored in ..." and swallowed, and the
    executor would spin on as if the signal had not come. The flag survives that.
    """

    def __init__(self) -> None:
        self.asked = False

    def __call__(self, signum, frame) -> None:
        self.asked = True
        raise KeyboardInterrupt


def run_nodes(
    factories: Sequence[Callable[[], Node]],
    args: Sequence[str] | None = None,
    threads: int | None = None,
    large_messages: bool = True,
) -> int:
    """Init rclpy, build the nodes, spin them on one executor, shut down cleanly.

    Parameters
    ----------
    factories : sequence of callable
        Each returns one node.
    args : sequence of str, optional
        Command-line arguments for ``rclpy.init`` (``--ros-args ...``).
    threads : int, optional
        Executor threads of ``SUBPIX_EXECUTOR=multi`` (default: rclpy's).
    large_messages : bool, optional
        False for nodes that publish no image: the package's Fast DDS profile with a 1 MiB
        shared-memory segment instead of 64 MiB
        (:func:`subpix_ros.runtime.configure_ros_environment`).

    Returns
    -------
    int
        Exit status: 0; 1 when a node's ``close()`` failed (said on stderr, the other nodes
        still closed) or a second signal cut the closing short; 2 when the ROS / DDS
        environment cannot be configured or ``SUBPIX_EXECUTOR`` names no executor.

    Notes
    -----
    Freed frame buffers stay in the process's heap for reuse
    (:func:`subpix_ros.runtime.keep_freed_memory`), or with ``SUBPIX_MALLOC=memory`` every
    thread allocates from one arena (:func:`subpix_ros.runtime.favour_memory`); the ROS / DDS defaults of
    :func:`subpix_ros.runtime.configure_ros_environment` are applied before the participant is
    created, or the process refuses to start with one line on stderr. OpenCV runs its loops
    in the calling thread unless ``OPENCV_FOR_THREADS_NUM`` says otherwise
    (:func:`subpix_ros.runtime.configure_opencv_threads`). The nodes spin on a
    SingleThreadedExecutor unless ``SUBPIX_EXECUTOR=multi`` (:func:`executor_kind`); each node
    shows which as ``executor`` in /diagnostics.
    """
    die_with_parent_if_asked()  # SUBPIX_DIE_WITH_PARENT=1: started by subpix demo
    configure_allocator()
    configure_opencv_threads()
    dump_stacks_on_sigusr1()  # kill -USR1 <pid>: every thread's stack on stderr
    clean_stale_shm_segments()  # segments of killed processes (64 MiB each with our profile)
    try:
        kind = executor_kind()
        configure_ros_environment(large_messages=large_messages)
    except (RuntimeSetupError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    # SIGINT and SIGTERM stop the executor with KeyboardInterrupt while the context is still up,
    # so that each node's close() can publish (the reconstruction's open set, as documented);
    # rclpy's own handlers shut the context down first ("publisher's context is invalid"). A
    # second signal cuts the closing short (shutdown_nodes).
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    stop = _StopRequest()
    signal.signal(signal.SIGINT, stop)
    signal.signal(signal.SIGTERM, stop)
    nodes: list[Node] = []
    executor = _make_executor(kind, threads)
    try:
        for make in factories:
            nodes.append(make())
            executor.add_node(nodes[-1])
        # Executor.spin() with a look at the stop request every STOP_CHECK_S: a signal whose
        # KeyboardInterrupt Python swallowed (see _StopRequest) still stops the process
        while not stop.asked and executor.context.ok():
            executor.spin_once(timeout_sec=STOP_CHECK_S)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        done = shutdown_nodes(nodes, executor)
    return 1 if done.close_errors or done.cut_short else 0


@dataclass
class Shutdown:
    """What :func:`shutdown_nodes` did."""

    #: The Fast DDS discovery listener was taken off before the participant went.
    listener_detached: bool = False
    #: One line per node whose ``close()`` raised (the others were still closed).
    close_errors: list[str] = field(default_factory=list)
    #: A second Ctrl-C / SIGTERM came while closing: the nodes not closed yet were not.
    cut_short: bool = False


def shutdown_nodes(nodes: Sequence[Node], executor: Executor) -> Shutdown:
    """Close every node, take the DDS discovery listener off, destroy the nodes, shut rclpy down.

    Parameters
    ----------
    nodes : sequence of Node
        The process's nodes, all in rclpy's default context; each one's ``close()`` (if it has
        one) runs first, in order, while every publisher is still up (the reconstruction
        publishes its open set there). A ``close()`` that raises is reported on stderr with its
        traceback and the others still run; a second Ctrl-C / SIGTERM (KeyboardInterrupt) during
        one ends the closing there, said on stderr, and the nodes are still destroyed.
    executor : Executor
        The executor they spun on.

    Returns
    -------
    Shutdown
        ``listener_detached`` True when the Fast DDS discovery listener was taken off before
        the participant went (:func:`subpix_ros.io.participant.detach_discovery_listener`):
        without it a node process stopped with Ctrl-C while a peer left could hang for good in
        ``destroy_node``; ``close_errors`` one line per failed ``close()``.
    """
    done = Shutdown()
    for n in nodes:
        close = getattr(n, "close", None)
        if close is None:
            continue
        try:
            close()
        except KeyboardInterrupt:  # a second signal: the user wants out now
            done.cut_short = True
            print(
                f"interrupted again while {n.get_name()} closed: closing cut short (queued "
                "frames and open sets not handled)",
                file=sys.stderr,
            )
            break
        except Exception as exc:  # noqa: BLE001 - the other nodes' close() must still run
            name = n.get_name()
            done.close_errors.append(f"{name}: {type(exc).__name__}: {exc}")
            print(f"error: {name} failed to close:\n{traceback.format_exc()}", file=sys.stderr)
    # one participant per context: taking its listener off through any node is enough
    done.listener_detached = detach_discovery_listener(nodes[0]) if nodes else False
    for n in nodes:
        n.destroy_node()
    executor.shutdown()
    if rclpy.ok():
        rclpy.shutdown()
    return done
