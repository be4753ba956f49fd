"""The package builds with colcon as an ament_python package (the route of a normal Jazzy install)."""

import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EXECUTABLES = [
    "telemetry_node",
    "registration_node",
    "shift_node",
    "reconstruction_node",
    "mosaic_node",
    "pipeline",
    "subpix",
]


def test_colcon_build_installs_executables_index_and_share(tmp_path):
    colcon = Path(sys.executable).parent / "colcon"
    src = tmp_path / "ws" / "src" / "subpix_ros"
    shutil.copytree(
        ROOT,
        src,
        ignore=shutil.ignore_patterns(
            ".venv",
            "bags",
            "out",
            ".git",
            "__pycache__",
            "build",
            "install",
            "log",
            "*.egg-info",
            ".pytest_cache",
        ),
    )
    r = subprocess.run(
        [str(colcon), "build", "--packages-select", "subpix_ros"],
        cwd=tmp_path / "ws",
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    prefix = tmp_path / "ws" / "install" / "subpix_ros"
    for exe in EXECUTABLES:  # where `ros2 run subpix_ros <exe>` looks
        assert (prefix / "lib" / "subpix_ros" / exe).is_file(), exe
    assert (
        prefix / "share" / "ament_index" / "resource_index" / "packages" / "subpix_ros"
    ).is_file()
    share = prefix / "share" / "subpix_ros"
    assert (share / "package.xml").is_file()
    assert {p.name for p in (share / "config").glob("*.yaml")} >= {
        f"{n}.yaml" for n in EXECUTABLES[:5]
    }
    assert len(list((share / "data" / "seneca").glob("*.jpg"))) == 9


def test_every_ros_package_the_code_imports_is_a_dependency():
    """Each ROS package imported by subpix_ros is an exec_depend (rosdep installs it).

    (Was: rcl_interfaces imported by every node, not declared.)
    """
    import re
    import xml.etree.ElementTree as ET

    deps = {e.text for e in ET.parse(ROOT / "package.xml").getroot().iter("exec_depend")}
    imported = set()
    for f in (ROOT / "subpix_ros").rglob("*.py"):
        imported |= set(
            re.findall(
                r"^\s*(?:from|import) (rclpy|ament_index_python|rcl_interfaces|\w+_msgs)\b",
                f.read_text(),
                re.M,
            )
        )
    assert imported >= {"rclpy", "rcl_interfaces", "sensor_msgs"}, imported
    assert imported <= deps, imported - deps
