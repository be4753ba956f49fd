from glob import glob

from setuptools import find_packages, setup

package_name = "subpix_ros"

# Each node's console entry point imports its module under a Ctrl-C guard (nodes/entry.py).
NODES = {
    "telemetry_node": "subpix_ros.nodes.entry:telemetry_node",
    "registration_node": "subpix_ros.nodes.entry:registration_node",
    "shift_node": "subpix_ros.nodes.entry:shift_node",
    "reconstruction_node": "subpix_ros.nodes.entry:reconstruction_node",
    "mosaic_node": "subpix_ros.nodes.entry:mosaic_node",
    "pipeline": "subpix_ros.nodes.entry:pipeline",
    "monitor_node": "subpix_ros.nodes.entry:monitor_node",
}

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*", "benchmarks"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", glob("config/*.yaml") + glob("config/*.xml")
         + ["config/foxglove_layout.json"]),
        # the bundled real sample data (CC0), so an installed package finds it (subpix_ros.data)
        ("share/" + package_name + "/data/seneca", glob("data/seneca/*.*")),
        ("share/" + package_name + "/data/crops", glob("data/crops/*.*")),
    ],
    # ROS 2 itself (rclpy, message packages) comes from the ROS install or, in
    # a venv, from requirements.txt: never from install_requires.
    install_requires=["setuptools", "numpy", "opencv-python-headless", "pymavlink", "pyserial", "rosbags", "PyYAML",
                      "foxglove-sdk", "matplotlib", "tqdm"],
    zip_safe=True,
    maintainer="subpix_ros developers",
    maintainer_email="dev@subpix-ros.org",
    description="Sub-pixel processing of drone imagery as ROS 2 nodes",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [f"{name} = {target}" for name, target in NODES.items()]
        + ["subpix = subpix_ros.cli:console"],
    },
)
