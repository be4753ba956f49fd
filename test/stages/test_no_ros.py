"""The stages run without ROS: importing them (and running the whole Pipeline) loads no rclpy."""

import ast
import subprocess
import sys
from pathlib import Path

from conftest import ROOT

STAGES = ROOT / "subpix_ros" / "stages"


def test_importing_and_running_the_stages_loads_no_rclpy(sample_bags):
    code = f"""
import sys
import subpix_ros.stages as S
assert 'rclpy' not in sys.modules, 'import'
from subpix_ros.io import cdr
from subpix_ros.io.bags import read_messages
pipe = S.Pipeline({{"reconstruction_node": {{"n_frames": 4, "method": "bicubic"}}}})
got = []
pipe.on("super_resolved", got.append)
for m in list(read_messages({str(sample_bags / "subpixel")!r}, ["/camera/image_raw"]))[:5]:
    img, h = cdr.cdr_to_image(m.raw)
    pipe.add(S.Frame(cdr.header_to_ns(h), img))
assert len(got) == 1, got
ros = ('rclpy', 'rcl_interfaces', 'sensor_msgs')
bad = sorted(m for m in sys.modules if m.split('.')[0] in ros)
assert not bad, bad
print('ok')
"""
    r = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120
    )
    assert r.returncode == 0 and r.stdout.strip() == "ok", r.stdout + r.stderr


def test_no_stage_module_imports_ros():
    for path in STAGES.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = (
                [a.name for a in node.names]
                if isinstance(node, ast.Import)
                else [node.module or ""]
                if isinstance(node, ast.ImportFrom)
                else []
            )
            for n in names:
                assert not n.startswith(("rclpy", "subpix_ros.nodes", "sensor_msgs")), (
                    f"{path.name}: {n}"
                )


def test_the_rclpy_check_itself_can_fail():
    """The subprocess check above would see rclpy if a stage imported it."""
    r = subprocess.run(
        [
            sys.executable,
            "-c",
            "import sys, subpix_ros.nodes.qos; print('rclpy' in sys.modules)",
        ],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=60,
    )
    assert r.stdout.strip() == "True", r.stderr
    assert Path(STAGES / "__init__.py").is_file()
