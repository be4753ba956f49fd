"""Writing rosbag2 bags (mcap or sqlite3) from raw CDR messages."""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path
from typing import Iterable, Sequence

from rosbags.rosbag2 import StoragePlugin, Writer

from .records import BagError, BagMessage, _one_line


class BagWriter:
    """Write raw CDR messages to a rosbag2 bag.

    ``path`` ending in ``.mcap`` writes one self-describing MCAP file (what
    ``ros2 bag play file.mcap`` and ``rosbags`` read); any other path is a
    rosbag2 bag directory (metadata.yaml + storage) with ``storage`` "mcap" or
    "sqlite3". Connections are created on first use of a topic.
    """

    def __init__(self, path: str | Path, storage: str = "mcap", typestore=None) -> None:
        from subpix_ros.io.cdr import TYPESTORE  # shared Jazzy typestore

        self.path = Path(path)
        self._single_file = self.path.suffix == ".mcap"
        if self._single_file:
            storage = "mcap"
        if storage not in ("mcap", "sqlite3"):
            raise BagError(f"unknown storage {storage!r} (mcap or sqlite3)")
        if self.path.exists():
            raise BagError(f"output exists: {self.path}")
        if not self.path.parent.is_dir():
            raise BagError(f"output folder does not exist: {self.path.parent}")
        self._tmp: Path | None = None
        target = self.path
        if self._single_file:
            self._tmp = Path(tempfile.mkdtemp(prefix="subpix_bag_", dir=self.path.parent))
            target = self._tmp / "bag"
        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        self._typestore = typestore or TYPESTORE
        self._writer = Writer(target, version=9, storage_plugin=plugin)
        self._writer.open()
        self._connections: dict[str, object] = {}
        self.count = 0

    def add_topic(self, topic: str, msgtype: str, qos: Sequence = ()) -> None:
        """Declare ``topic`` with the QoS profiles its publishers offered.

        The profiles (rosbags ``Qos``) are stored as rosbag2's ``offered_qos_profiles``;
        :meth:`write` declares unknown topics without them.
        """
        if topic in self._connections:
            raise BagError(f"topic {topic} already in the bag")
        try:
            self._connections[topic] = self._writer.add_connection(
                topic, msgtype, typestore=self._typestore, offered_qos_profiles=list(qos)
            )
        except Exception as exc:  # noqa: BLE001
            raise BagError(
                f"cannot add topic {topic} of type {msgtype}: {_one_line(exc)}"
            ) from None

    def write(self, topic: str, msgtype: str, timestamp_ns: int, raw: bytes | memoryview) -> None:
        """Write one message (raw CDR bytes) on ``topic``, adding the topic on first use."""
        if topic not in self._connections:
            self.add_topic(topic, msgtype)
        self._writer.write(self._connections[topic], int(timestamp_ns), raw)
        self.count += 1

    def write_all(self, messages: Iterable[BagMessage]) -> None:
        """Write every message of ``messages`` in the order given."""
        for m in messages:
            self.write(m.topic, m.msgtype, m.timestamp_ns, m.raw)

    def close(self) -> None:
        """Finish the bag: metadata, chunk CRCs, the file moved into place."""
        from subpix_ros.io import _mcap

        self._writer.close()
        folder = self._tmp / "bag" if self._tmp is not None else self.path
        for f in folder.glob("*.mcap"):  # chunk CRCs, so that damage is found on reading
            _mcap.write_chunk_crcs(f)
        if self._tmp is not None:
            files = list((self._tmp / "bag").glob("*.mcap"))
            shutil.move(str(files[0]), str(self.path))
            shutil.rmtree(self._tmp, ignore_errors=True)
            self._tmp = None

    def __enter__(self) -> "BagWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
