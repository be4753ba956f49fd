"""rclpy start-up shared by the CLI subcommands that talk ROS."""
from __future__ import annotations

import contextlib
from typing import Iterator


@contextlib.contextmanager
def ros_node(name: str, use_sim_time: bool = False) -> Iterator[object]:
    """An initialised rclpy context and one node, torn down on exit."""
    import rclpy
    from rclpy.parameter import Parameter

    rclpy.init()
    node = rclpy.create_node(name, parameter_overrides=[Parameter("use_sim_time", value=use_sim_time)])
    try:
        yield node
    finally:
        node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
