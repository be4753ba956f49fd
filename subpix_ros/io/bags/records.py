"""What the bag readers return and raise: messages, topics, read reports, errors."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from rosbags.rosbag2 import Reader


class BagError(Exception):
    """A bag cannot be read or written; the message is one user-facing line."""


@dataclass(frozen=True)
class TopicInfo:
    """One topic of a bag: name, message type, message count and recorded QoS."""

    name: str
    msgtype: str
    count: int
    #: the publishers' QoS as recorded (rosbags ``Qos``: reliability, durability, depth, ...);
    #: empty if the bag does not say
    qos: tuple = ()


def _parse_qos(text, where: str) -> tuple:
    """offered_qos_profiles of any rosbag2 metadata version (4-8: integer enums, 9: names)."""
    from rosbags.rosbag2.metadata import parse_qos

    if not text:
        return ()
    try:
        return tuple(parse_qos(text))
    except Exception as exc:  # noqa: BLE001
        raise BagError(f"{where}: unreadable offered_qos_profiles ({_one_line(exc)})") from None


@dataclass(frozen=True)
class BagMessage:
    """One recorded message: topic, type, receive time stamp and its raw CDR bytes."""

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


class BagCorrupt(BagError):
    """A bag's storage failed a check while reading.

    ``path``: the storage file; ``offset``: byte offset of the first bad record in it (None if
    the storage cannot say, e.g. rows missing from a sqlite3 table); ``count``: messages that
    could be read (mcap: delivered before the bad record; sqlite3: readable rows, checked
    before anything is delivered); ``detail``: what failed; ``more``: whether reading past the
    damage (``skip_corrupt``) would deliver more than was delivered (False for a file that
    ends at its damage, a truncated copy): only then does the message suggest it.
    """

    def __init__(
        self, path: Path, offset: int | None, detail: str, count: int, more: bool = False
    ) -> None:
        self.path, self.offset, self.detail, self.count = Path(path), offset, detail, count
        self.more = more
        where = "" if offset is None else f" at byte offset {offset}"
        hint = " (--skip-corrupt reads on past the damage)" if more else ""
        super().__init__(
            f"bag {path} is corrupt{where}: {detail}; {count} message(s) could be read{hint}"
        )


@dataclass
class ReadReport:
    """What :func:`read_messages` delivered and what it skipped (filled while reading)."""

    messages: int = 0
    skipped_records: int = 0  # damaged chunks / records / rows skipped
    skipped_messages: int = 0  # messages the bag's indexes say were in them (where known)
    first_bad: tuple[Path, int | None] | None = None
    problems: list[str] = field(default_factory=list)
    #: some damaged record had readable messages after it (False: the storage ends at its
    #: damage, e.g. a truncated mcap: reading past it gains nothing)
    readable_after: bool = False

    def summary(self) -> str:
        """Describe what was skipped and why, in one line."""
        lost = (
            f" holding {self.skipped_messages} message(s) by the bag's index"
            if self.skipped_messages
            else ""
        )
        return (
            f"skipped {self.skipped_records} corrupt record(s){lost}; first: {self.problems[0]}"
            if self.problems
            else "no corrupt records"
        )
