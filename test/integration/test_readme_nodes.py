"""The README's "Running the nodes" example, run as written, in a plainly activated venv (issue 19).

The commands are read from the README's bash block: `source .venv/bin/activate` is emulated by the
environment of a plain activation (this environment without any ROS / DDS variable, plus PATH and
VIRTUAL_ENV of .venv, plus ROS_DOMAIN_ID for isolation): no RMW_IMPLEMENTATION, no
ROS_AUTOMATIC_DISCOVERY_RANGE, no AMENT_PREFIX_PATH, no Fast DDS profile. The replay and the
registration, shift and reconstruction nodes run as written, each its own process (mosaic_node and
telemetry_node are left out: the mosaic is tested elsewhere, and the telemetry node needs an
autopilot on UDP 14550). A listener process in the same environment counts what comes out.

Checked: shifts and a super-resolved image come out; the registration node receives at least 70 %
of the camera frames the looping replay sends (best effort, SensorDataQoS); after a SIGKILL of
the registration node and a restart with the same command, frames flow again.
"""

import json
import os
import re
import shlex
import signal
import subprocess
import threading
import time

import pytest
from conftest import ROOT

from subpix_ros.runtime import plain_venv_environ

VENV = ROOT / ".venv"
RUN = ("subpix replay", "registration_node", "shift_node", "reconstruction_node")

LISTENER = r"""
import json, threading, time
import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.qos import QoSProfile, ReliabilityPolicy, DurabilityPolicy, HistoryPolicy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Vector3Stamped
from sensor_msgs.msg import Image
rclpy.init()
node = rclpy.create_node("readme_listener")
out = {"shifts": 0, "super_resolved": 0, "reg_input": None, "reg_level": None, "reg_message": ""}
def on_diag(m):
    for s in m.status:
        if s.name == "registration_node":
            v = {kv.key: kv.value for kv in s.values}
            out["reg_input"] = int(v.get("input_total", 0))
            out["reg_level"], out["reg_message"] = s.level[0], s.message
def count(key):
    return lambda raw: out.__setitem__(key, out[key] + 1)
rel = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE)
lat = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE,
                 durability=DurabilityPolicy.TRANSIENT_LOCAL)
node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 100)
node.create_subscription(Vector3Stamped, "/shift", count("shifts"), rel, raw=True)
node.create_subscription(Image, "/super_resolved", count("super_resolved"), lat, raw=True)
def report():
    while rclpy.ok():
        print(json.dumps(dict(out, t=time.monotonic())), flush=True)
        time.sleep(0.5)
threading.Thread(target=report, daemon=True).start()
try:
    rclpy.spin(node)
except (KeyboardInterrupt, ExternalShutdownException):
    pass
"""


def readme_commands():
    """Return the command lines of the README's "Running the nodes" bash block, in order."""
    text = (ROOT / "README.md").read_text()
    section = text.split("## Running the nodes", 1)[1]
    block = re.search(r"```bash\n(.*?)```", section, re.S).group(1)
    return [
        line.split("#", 1)[0].strip().rstrip("&").strip()
        for line in block.splitlines()
        if line.split("#", 1)[0].strip()
    ]


def plain_env():
    # this test run's domain (conftest), for isolation
    return plain_venv_environ(VENV, os.environ["ROS_DOMAIN_ID"])


class Listener:
    def __init__(self, env):
        self.proc = subprocess.Popen(
            [str(VENV / "bin" / "python"), "-c", LISTENER],
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            cwd=ROOT,
        )
        self.latest, self.lines = {}, []
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self):
        for line in self.proc.stdout:
            self.lines.append(line)
            if line.startswith("{"):
                self.latest = json.loads(line)

    def wait(self, cond, timeout):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.latest and cond(self.latest):
                return True
            time.sleep(0.2)
        return False


def _stop(procs):
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGINT)
    for p in procs:
        try:
            p.wait(15)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


@pytest.mark.usefixtures("sample_bags")
def test_readme_running_the_nodes_in_a_plain_venv(tmp_path):
    cmds = readme_commands()
    assert cmds[0] == "source .venv/bin/activate", f"the README's example starts with {cmds[0]!r}"
    if not (ROOT / "data" / "bags" / "subpixel" / "metadata.yaml").is_file():
        pytest.fail("data/bags/subpixel missing: run `make sample`")
    run = [c for c in cmds if c.startswith(RUN)]
    assert [c.split()[0] for c in run] == [
        "subpix",
        "registration_node",
        "shift_node",
        "reconstruction_node",
    ]
    env = plain_env()
    logs = {}
    listener = Listener(env)
    procs = {}

    def start(cmd):
        name = shlex.split(cmd)[0] if not cmd.startswith("subpix") else "replay"
        logs[name] = open(tmp_path / f"{name}.log", "a")
        procs[name] = subprocess.Popen(
            shlex.split(cmd), env=env, cwd=ROOT, stdout=logs[name], stderr=subprocess.STDOUT
        )

    def report():
        return f"listener {listener.latest}; logs:\n" + "\n".join(
            f"--- {n}\n{(tmp_path / f'{n}.log').read_text()[-1500:]}" for n in logs
        )

    try:
        for cmd in run:  # in the README's order: the looping replay first, then the nodes
            start(cmd)
        out = lambda s: s["shifts"] >= 1 and s["super_resolved"] >= 1  # noqa: E731
        assert listener.wait(out, 180), report()
        # and the registration node's count of camera frames (its /diagnostics) is here
        assert listener.wait(lambda s: s["reg_input"] is not None, 30), report()
        for name, p in procs.items():
            assert p.poll() is None, f"{name} exited with {p.returncode}: {report()}"

        # The camera is best effort: nearly every frame must still arrive (24 frames / 2.8 s loop).
        s0 = dict(listener.latest)
        time.sleep(14.0)
        s1 = dict(listener.latest)
        expected = 24 * (s1["t"] - s0["t"]) / 2.8
        got = s1["reg_input"] - s0["reg_input"]
        print(f"camera frames at the registration node: {got} of ~{expected:.0f} sent")
        assert got >= 0.7 * expected, (
            f"{got} camera frames reached the registration node of "
            f"~{expected:.0f} sent; " + report()
        )

        # SIGKILL (stale shared-memory files stay), restart with the same command: frames again.
        procs["registration_node"].send_signal(signal.SIGKILL)
        procs["registration_node"].wait(10)
        shifts_before = listener.latest["shifts"]
        start(next(c for c in run if c.startswith("registration_node")))
        # the new process counts from 0: a count below the old one is the new node's
        old_total = listener.latest["reg_input"]
        restarted = lambda s: 0 < s["reg_input"] < old_total  # noqa: E731
        assert listener.wait(restarted, 120), "no frames after the restart: " + report()
        more = lambda s: s["shifts"] >= shifts_before + 5  # noqa: E731
        assert listener.wait(more, 120), "no shifts after the restart: " + report()
    finally:
        _stop(list(procs.values()))
        listener.proc.send_signal(signal.SIGINT)
        try:
            listener.proc.wait(15)
        except subprocess.TimeoutExpired:
            listener.proc.kill()
        for fh in logs.values():
            fh.close()
