"""Live operator monitoring over Foxglove (ROS-free): see :mod:`subpix_ros.monitor.monitor`."""

from .budget import LEVELS, ByteMeter, TokenBucket, wire_bytes
from .geo import feature_collection, footprint_lonlat
from .monitor import LOOPBACK, TOPICS, Monitor, MonitorConfig, MonitorError, check_exposure

__all__ = [
    "Monitor",
    "MonitorConfig",
    "MonitorError",
    "TOPICS",
    "LOOPBACK",
    "check_exposure",
    "LEVELS",
    "ByteMeter",
    "TokenBucket",
    "wire_bytes",
    "footprint_lonlat",
    "feature_collection",
]
