"""subpix_ros: sub-pixel processing of drone imagery for ROS 2."""

__version__ = "0.1.0"
