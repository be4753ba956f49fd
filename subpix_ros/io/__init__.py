"""Bytes in and out, shared by all nodes and tools.

:mod:`.cdr` (ROS 2 messages as CDR bytes), :mod:`.images` (Image / CompressedImage <-> numpy),
:mod:`.bags` (rosbag2 reading, verified, and writing), :mod:`.mavlink` (MAVLink telemetry in and
out), :mod:`.telemetry_msgs` (telemetry samples <-> the telemetry node's messages),
:mod:`.frame_metadata` (frames.csv / EXIF), :mod:`.player` (replay and record through rclpy),
:mod:`.participant` (the DDS participant's teardown).
"""
