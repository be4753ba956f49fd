"""rosbag2 reading and writing (mcap and sqlite3) through ``rosbags``.

Messages stay as raw CDR bytes end to end: replay publishes them unchanged and
record writes what it received, so nothing is re-serialised. Every failure
(missing path, corrupt or truncated storage, unknown topic) raises
:class:`BagError` with a one-line message that names the bag and the problem.
"""
from __future__ import annotations

import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Iterator, Sequence

from rosbags.rosbag2 import Reader, StoragePlugin, Writer

__all__ = ["BagError", "BagMessage", "TopicInfo", "open_reader", "bag_topics", "read_messages", "BagWriter"]


class BagError(Exception):
    """A bag cannot be read or written; the message is one user-facing line."""


@dataclass(frozen=True)
class TopicInfo:
    name: str
    msgtype: str
    count: int


@dataclass(frozen=True)
class BagMessage:
    topic: str
    msgtype: str
    timestamp_ns: int  # the bag's receive time stamp
    raw: bytes  # CDR bytes, exactly as recorded


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text[:300]


def open_reader(path: str | Path) -> Reader:
    """Open a rosbag2 bag (directory with metadata.yaml, or one .mcap/.db3 file)."""
    p = Path(path)
    if not p.exists():
        raise BagError(f"bag not found: {p}")
    try:
        reader = Reader(p)
        reader.open()
    except Exception as exc:  # noqa: BLE001 - rosbags raises many types for corrupt input
        raise BagError(f"cannot open bag {p}: {_one_line(exc)}") from None
    return reader


def bag_topics(path: str | Path) -> list[TopicInfo]:
    reader = open_reader(path)
    try:
        counts: dict[str, int] = {}
        types: dict[str, str] = {}
        for conn in reader.connections:
            counts[conn.topic] = counts.get(conn.topic, 0) + conn.msgcount
            types[conn.topic] = conn.msgtype
        return [TopicInfo(t, types[t], counts[t]) for t in sorted(counts)]
    finally:
        reader.close()


def read_messages(path: str | Path, topics: Sequence[str] | None = None) -> Iterator[BagMessage]:
    """Yield the bag's messages in time order, optionally only ``topics``.

    Raises BagError for a requested topic that is not in the bag, and for
    storage that turns out corrupt or truncated while reading.
    """
    reader = open_reader(path)
    try:
        conns = list(reader.connections)
        if topics:
            present = {c.topic for c in conns}
            missing = [t for t in topics if t not in present]
            if missing:
                raise BagError(
                    f"topic(s) not in bag {path}: {', '.join(missing)} (bag has: {', '.join(sorted(present))})"
                )
            conns = [c for c in conns if c.topic in topics]
        try:
            for conn, ts, raw in reader.messages(connections=conns):
                yield BagMessage(conn.topic, conn.msgtype, int(ts), raw)
        except BagError:
            raise
        except Exception as exc:  # noqa: BLE001
            raise BagError(f"bag {path} is corrupt or truncated: {_one_line(exc)}") from None
    finally:
        reader.close()


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

    def write(self, topic: str, msgtype: str, timestamp_ns: int, raw: bytes | memoryview) -> None:
        conn = self._connections.get(topic)
        if conn is None:
            try:
                conn = self._writer.add_connection(topic, msgtype, typestore=self._typestore)
            except Exception as exc:  # noqa: BLE001
                raise BagError(f"cannot add topic {topic} of type {msgtype}: {_one_line(exc)}") from None
            self._connections[topic] = conn
        self._writer.write(conn, int(timestamp_ns), raw)
        self.count += 1

    def write_all(self, messages: Iterable[BagMessage]) -> None:
        for m in messages:
            self.write(m.topic, m.msgtype, m.timestamp_ns, m.raw)

    def close(self) -> None:
        self._writer.close()
        if self._tmp is not None:
            files = list((self._tmp / "bag").glob("*.mcap"))
            shutil.move(str(files[0]), str(self.path))
            shutil.rmtree(self._tmp, ignore_errors=True)
            self._tmp = None

    def __enter__(self) -> "BagWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
