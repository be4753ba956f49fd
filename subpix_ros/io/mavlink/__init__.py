"""MAVLink telemetry in and out (pymavlink, MAVLink 2, 'ardupilotmega' dialect).

* :func:`encode_samples` (:mod:`.encode`) and :func:`write_tlog` (:mod:`.tlog`) turn
  :class:`~subpix_ros.core.telemetry.TelemetrySample` sequences into real MAVLink packets
  (HEARTBEAT, ATTITUDE, VFR_HUD, GLOBAL_POSITION_INT) and ``.tlog`` files that MAVProxy,
  QGroundControl and ``mavutil.mavlink_connection`` read.
* :class:`MavlinkReader` (:mod:`.reader`) reads a live link (UDP, TCP, serial) or replays a
  ``.tlog`` on its own thread and turns the message stream back into samples, with
  heartbeat/link-loss detection and statistics about everything it had to ignore.
* :func:`parse_url`, :class:`MavlinkSender` (:mod:`.link`): endpoints and a UDP sender.

MAVLink 2 is chosen inside each connection (the reader installs its own v2 parser); importing
this package changes no environment variable.

Notes
-----
``relative_alt`` (height above home) is used as height above ground: the flat-terrain
assumption of METHODS.md B. The reader's and the sender's network endpoints default to
127.0.0.1 when the URL omits the host (``udpin:14550`` binds 127.0.0.1:14550); give an explicit
host such as ``udpin:0.0.0.0:14550`` to listen on all interfaces.
"""

from .encode import DIALECT, encode_samples
from .link import ConnectionSpec, LinkEvent, LinkLoss, MavlinkSender, ReaderStats, parse_url
from .reader import MavlinkReader
from .tlog import read_tlog_packets, write_tlog

__all__ = [
    "DIALECT",
    "encode_samples",
    "write_tlog",
    "read_tlog_packets",
    "parse_url",
    "ConnectionSpec",
    "LinkEvent",
    "ReaderStats",
    "LinkLoss",
    "MavlinkReader",
    "MavlinkSender",
]
