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
