"""The node processes' executor (nodes/run.py): one thread by default, chosen by SUBPIX_EXECUTOR."""

import os
import subprocess
import sys

import pytest
from rclpy.executors import MultiThreadedExecutor, SingleThreadedExecutor

from subpix_ros.nodes.run import EXECUTOR_ENV, _make_executor, executor_kind


@pytest.mark.parametrize(
    "value, want", [(None, "single"), ("", "single"), ("multi", "multi"), (" Single ", "single")]
)
def test_executor_kind_defaults_to_one_thread(value, want):
    env = {} if value is None else {EXECUTOR_ENV: value}
    assert executor_kind(env) == want


def test_an_unknown_executor_is_an_error_naming_the_choices():
    with pytest.raises(ValueError, match="single, multi"):
        executor_kind({EXECUTOR_ENV: "threads"})


def test_each_kind_makes_its_rclpy_executor(ctx):
    single, multi = _make_executor("single", None), _make_executor("multi", 2)
    try:
        assert isinstance(single, SingleThreadedExecutor)
        assert isinstance(multi, MultiThreadedExecutor)
    finally:
        single.shutdown()
        multi.shutdown()


@pytest.mark.parametrize("value, want", [(None, "single"), ("multi", "multi")])
def test_a_node_shows_its_processs_executor_in_diagnostics(ctx, monkeypatch, value, want):
    from subpix_ros.nodes.shift_node import ShiftNode

    if value is None:
        monkeypatch.delenv(EXECUTOR_ENV, raising=False)
    else:
        monkeypatch.setenv(EXECUTOR_ENV, value)
    node = ShiftNode()
    try:
        values = {kv.key: kv.value for kv in node.diag.snapshot().values}
        assert values["executor"] == want
    finally:
        node.close()
        node.destroy_node()


def test_a_node_process_with_an_unknown_executor_refuses_to_start_with_one_line():
    env = {**os.environ, EXECUTOR_ENV: "fast"}
    out = subprocess.run(
        [sys.executable, "-m", "subpix_ros.nodes.shift_node"],
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 2, (out.returncode, out.stderr)
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and "SUBPIX_EXECUTOR='fast'" in lines[0], out.stderr


@pytest.fixture
def shift_and_mosaic():
    """Yield a shift node and a mosaic node in a fresh rclpy context, as ``pipeline`` holds them.

    The test hands them to ``shutdown_nodes`` (which shuts rclpy down); whatever is left is
    shut down here.
    """
    import rclpy

    from subpix_ros.nodes.mosaic_node import MosaicNode
    from subpix_ros.nodes.shift_node import ShiftNode

    rclpy.init()
    try:
        yield ShiftNode(), MosaicNode()
    finally:
        if rclpy.ok():
            rclpy.shutdown()


def test_shutting_the_nodes_down_takes_the_discovery_listener_off_first(shift_and_mosaic):
    """Every node process's teardown applies the Fast DDS work-around before destroying nodes.

    (Was: only ``subpix record`` / ``replay`` / ``demo`` did; a node process stopped with
    Ctrl-C just as a peer left could hang for good in ``destroy_node``, see
    :func:`subpix_ros.io.participant.detach_discovery_listener`.) Two real nodes in one context,
    as the ``pipeline`` entry point runs them; each one's ``close()`` still runs first.
    """
    import rclpy

    from subpix_ros.nodes.run import shutdown_nodes

    nodes = list(shift_and_mosaic)
    names = [n.get_name() for n in nodes]
    closed = []
    for n in nodes:
        close = n.close
        n.close = lambda close=close, n=n: (closed.append(n.get_name()), close())
    executor = SingleThreadedExecutor()
    for n in nodes:
        executor.add_node(n)
    done = shutdown_nodes(nodes, executor)
    assert done.listener_detached is True and done.close_errors == []
    assert closed == names
    assert not rclpy.ok()


def test_node_processes_stopped_together_by_ctrl_c_all_exit(tmp_path):
    """A terminal's Ctrl-C reaches every node of a flight at once: each exits 0, no traceback.

    Two node processes in one domain, started long enough to have discovered each other, are
    interrupted together, three times, so that each one's teardown runs while its peer is
    leaving: the case where a node could hang in ``destroy_node``.
    """
    import signal
    import time

    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    for _ in range(3):
        procs = [
            subprocess.Popen(
                [sys.executable, "-m", f"subpix_ros.nodes.{name}"],
                env=env,
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                text=True,
            )
            for name in ("shift_node", "mosaic_node")
        ]
        time.sleep(3.0)  # started, and discovered each other
        for p in procs:
            p.send_signal(signal.SIGINT)
        for p in procs:
            try:
                out, err = p.communicate(timeout=20)
            except subprocess.TimeoutExpired:
                for q in procs:
                    q.kill()
                pytest.fail(f"a node process did not exit within 20 s of Ctrl-C: {p.args}")
            assert p.returncode == 0, (p.args, err)
            assert "Traceback" not in err, err


_LOST_SIGNAL_NODE = """
import os, signal, sys
from rclpy.node import Node
from subpix_ros.nodes.run import run_nodes

class Swallows:
    def __del__(self):
        os.kill(os.getpid(), signal.SIGINT)
        for _ in range(10000):  # the handler runs in here, inside __del__
            pass

class LostSignal(Node):
    def __init__(self):
        super().__init__("subpix_test_lost_signal")
        self.timer = self.create_timer(0.2, self.tick)

    def tick(self):
        self.timer.cancel()
        Swallows()  # dropped at once: its __del__ runs now
        print("signalled", flush=True)

sys.exit(run_nodes([LostSignal]))
"""


def test_a_ctrl_c_whose_keyboardinterrupt_python_swallows_still_stops_the_node():
    """A signal handled inside a ``__del__`` or weakref callback: the node process still stops.

    (Was: the handler's KeyboardInterrupt was printed as "Exception ignored in ..." and the
    executor spun on, so a Ctrl-C that came while a thread imported a module (importlib's
    module-lock callback) was lost: seen as a node that did not stop in 1 of 240 harness runs
    under load.) Here the signal is sent from a ``__del__``, deterministically.
    """
    proc = subprocess.Popen(
        [sys.executable, "-c", _LOST_SIGNAL_NODE],
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        out, err = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
        pytest.fail(f"the node did not stop within 30 s of its SIGINT:\n{out}\n{err}")
    assert "signalled" in out, err
    assert "Exception ignored" in err and "KeyboardInterrupt" in err, err
    assert proc.returncode == 0, err


def test_a_node_whose_close_fails_does_not_keep_the_others_from_closing(shift_and_mosaic, capsys):
    """One node's ``close()`` raising: said on stderr, the next node still closes (publishes)."""
    import rclpy

    from subpix_ros.nodes.run import shutdown_nodes

    bad, good = shift_and_mosaic
    closed = []

    def fails():
        raise RuntimeError("disk full")

    bad.close = fails
    good_close = good.close
    good.close = lambda: (closed.append("mosaic"), good_close())
    done = shutdown_nodes([bad, good], SingleThreadedExecutor())
    assert closed == ["mosaic"] and not rclpy.ok()
    assert done.close_errors == ["shift_node: RuntimeError: disk full"]
    err = capsys.readouterr().err
    assert "shift_node failed to close" in err and "RuntimeError: disk full" in err


def test_a_second_ctrl_c_while_closing_cuts_the_closing_short(shift_and_mosaic, capsys):
    """Ctrl-C again while a node drains: the rest is not closed, every node is still destroyed."""
    import rclpy

    from subpix_ros.nodes.run import shutdown_nodes

    first, second = shift_and_mosaic
    closed = []

    def interrupted():
        raise KeyboardInterrupt  # as the handler raises it on the second signal

    first.close = interrupted
    second.close = lambda: closed.append("mosaic")
    done = shutdown_nodes([first, second], SingleThreadedExecutor())
    assert done.cut_short and closed == [] and not rclpy.ok()
    assert "interrupted again while shift_node closed" in capsys.readouterr().err
