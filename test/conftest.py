import os
import sys
from pathlib import Path

from dataclasses import dataclass

import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from subpix_ros.data import CROP_NAMES, load_crop  # noqa: E402


@pytest.fixture(scope="session")
def crops():
    """The four real full-resolution Seneca luminance crops (uint8, 768x768)."""
    return {name: load_crop(name) for name in CROP_NAMES}


@pytest.fixture(scope="session", autouse=True)
def ros_isolation():
    """Keep this test run's DDS traffic to itself: a domain id of its own, localhost only.

    Set in os.environ so subprocesses (nodes, `subpix replay`) inherit it.
    """
    import random

    os.environ["ROS_DOMAIN_ID"] = os.environ.get("SUBPIX_TEST_DOMAIN_ID", str(random.Random().randint(1, 100)))
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
    os.environ["PYTHONUNBUFFERED"] = "1"
    # the package's Fast DDS profile, as every entry point loads it (camera frames published from this process)
    from subpix_ros.runtime import configure_ros_environment

    configure_ros_environment()
    yield


@pytest.fixture(scope="session")
def sample_bags(tmp_path_factory):
    """The bundled sample flights (data/bags, built by `make sample`; built here if missing)."""
    import subprocess

    bags = ROOT / "data" / "bags"
    if not (bags / "subpixel" / "truth.json").is_file() or not (bags / "seneca" / "metadata.yaml").is_file():
        bags = tmp_path_factory.mktemp("bags")
        subprocess.run([sys.executable, str(ROOT / "scripts" / "build_sample_flight.py"), "--out", str(bags)], check=True)
    return bags


@pytest.fixture
def rclpy_node():
    """An initialised rclpy context with one node in this (the test) process."""
    import rclpy

    rclpy.init()
    node = rclpy.create_node("subpix_test")
    yield node
    node.destroy_node()
    rclpy.shutdown()


def subpix_cmd(*args: str) -> list[str]:
    """The `subpix` command line (run as a module so the checkout's code is used)."""
    return [sys.executable, "-m", "subpix_ros.cli", *args]


@dataclass
class ImageMsg:
    """A plain stand-in for sensor_msgs/Image (subpix_ros.io.images is duck-typed)."""

    height: int
    width: int
    encoding: str
    is_bigendian: int
    step: int
    data: object
    header: object = None
