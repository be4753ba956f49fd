"""rosbag2 reading and writing (mcap and sqlite3) through ``rosbags``.

Messages stay as raw CDR bytes end to end: replay publishes them unchanged and
record writes what it received, so nothing is re-serialised. Every failure
(missing path, corrupt or truncated storage, unknown topic) raises
:class:`BagError` with a one-line message that names the bag and the problem.
"""

from .reader import read_messages
from .records import BagCorrupt, BagError, BagMessage, ReadReport, TopicInfo, open_reader
from .topics import bag_topics
from .writer import BagWriter

__all__ = [
    "BagError",
    "BagCorrupt",
    "BagMessage",
    "ReadReport",
    "TopicInfo",
    "open_reader",
    "bag_topics",
    "read_messages",
    "BagWriter",
]
