"""The single-process pipeline's command line: a node-name remap for every node is refused."""

import subprocess
import sys

import pytest


@pytest.mark.parametrize("rule", ["__node:=cam_pipe", "__name:=cam_pipe"])
def test_a_node_name_remap_for_every_node_is_refused_with_one_line_and_status_2(rule):
    """A global ``__node`` remap: exit status 2 and one line naming the per-node form.

    (Was: the five nodes all took the name cam_pipe: rcl's "Publisher already registered
    for node name" four times, colliding parameter services, five statuses named cam_pipe.)
    """
    cmd = [sys.executable, "-m", "subpix_ros.nodes.pipeline", "--ros-args", "-r", rule]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        out, err = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
        pytest.fail(f"the pipeline started with -r {rule}:\n{err[-2000:]}")
    assert proc.returncode == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "cam_pipe" in lines[0], err
    assert "-r registration_node:__node:=cam_pipe" in lines[0]
    assert out == ""


@pytest.mark.parametrize(
    "argv, found",
    [
        (["pipeline", "--ros-args", "-r", "__node:=a"], "__node:=a"),
        (["pipeline", "--ros-args", "--remap", "__name:=a"], "__name:=a"),
        (["pipeline", "--monitor", "--ros-args", "-p", "x:=1", "-r", "__node:=a"], "__node:=a"),
        (["pipeline", "--ros-args", "-r", "registration_node:__node:=reg_a"], None),
        (["pipeline", "--ros-args", "-r", "__ns:=/drone1", "-r", "image:=/cam"], None),
        (["pipeline", "-r", "__node:=a"], None),  # not a ROS argument
        (["pipeline", "--ros-args", "--", "-r", "__node:=a"], None),
    ],
)
def test_only_an_unprefixed_node_name_remap_among_the_ros_arguments_is_found(argv, found):
    from subpix_ros.nodes.pipeline import global_name_remap

    assert global_name_remap(argv) == found
