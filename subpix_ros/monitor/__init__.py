"""Live operator monitoring over Foxglove (ROS-free): see :mod:`subpix_ros.monitor.monitor`."""

from .budget import LEVELS, ByteMeter, TokenBucket, wire_bytes
from .config import LOOPBACK, MonitorConfig, MonitorError, check_exposure
from .geo import feature_collection, footprint_lonlat
from .monitor import Monitor
from .schemas import TOPICS

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
