"""rosbag2 reading and writing (mcap and sqlite3) through ``rosbags``.

Messages stay as raw CDR bytes end to end: replay publishes them unchanged and
record writes what it received, so nothing is re-serialised. Every failure
(missing path, corrupt or truncated storage, unknown topic) raises
:class:`BagError` with a one-line message that names the bag and the problem.
"""

from __future__ import annotations

import contextlib
import heapq
import re
import shutil
import sqlite3
import tempfile
from dataclasses import dataclass, field
from pathlib import Path, PurePath
from typing import Iterable, Iterator, Sequence

import yaml
from rosbags.rosbag2 import Reader, StoragePlugin, Writer

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


class BagError(Exception):
    """A bag cannot be read or written; the message is one user-facing line."""


@dataclass(frozen=True)
class TopicInfo:
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
    before anything is delivered); ``detail``: what failed.
    """

    def __init__(self, path: Path, offset: int | None, detail: str, count: int) -> None:
        self.path, self.offset, self.detail, self.count = Path(path), offset, detail, count
        where = "" if offset is None else f" at byte offset {offset}"
        super().__init__(
            f"bag {path} is corrupt{where}: {detail}; {count} message(s) could be read "
            f"(--skip-corrupt reads what can be read)"
        )


@dataclass
class ReadReport:
    """What :func:`read_messages` delivered and what it skipped (filled while reading)."""

    messages: int = 0
    skipped_records: int = 0  # damaged chunks / records / rows skipped
    skipped_messages: int = 0  # messages the bag's indexes say were in them (where known)
    first_bad: tuple[Path, int | None] | None = None
    problems: list[str] = field(default_factory=list)

    def summary(self) -> str:
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


def _bag_files(path: Path) -> tuple[str, list[Path], dict | None]:
    """(storage, storage files, parsed metadata.yaml or None) of a bag folder or single file."""
    if path.is_dir():
        meta_path = path / "metadata.yaml"
        if not meta_path.is_file():
            raise BagError(f"not a rosbag2 bag (no metadata.yaml): {path}")
        try:
            meta = yaml.safe_load(meta_path.read_text())["rosbag2_bagfile_information"]
            storage = meta["storage_identifier"]
            files = [path / PurePath(x).name for x in meta["relative_file_paths"]]
        except Exception as exc:  # noqa: BLE001 - any malformed YAML
            raise BagError(f"cannot read {meta_path}: {_one_line(exc)}") from None
        if (meta.get("compression_mode") or "").lower() == "file":
            return "rosbags", [path], meta
        missing = [str(f) for f in files if not f.is_file()]
        if missing:
            raise BagError(f"bag {path}: storage file(s) missing: {', '.join(missing)}")
        if storage not in ("mcap", "sqlite3"):
            raise BagError(f"bag {path}: storage {storage!r} not supported (mcap or sqlite3)")
        return storage, files, meta
    if path.suffix == ".mcap":
        return "mcap", [path], None
    if path.suffix == ".db3":
        return "sqlite3", [path], None
    raise BagError(
        f"not a rosbag2 bag (a folder with metadata.yaml, a .mcap or a .db3 file): {path}"
    )


def bag_topics(path: str | Path) -> list[TopicInfo]:
    """Topics, types and message counts (from metadata.yaml, else the storage's own index)."""
    p = Path(path)
    if not p.exists():
        raise BagError(f"bag not found: {p}")
    storage, files, meta = _bag_files(p)
    if meta is not None:
        try:
            odd = [
                (
                    t["topic_metadata"]["name"],
                    t["topic_metadata"].get("serialization_format", "cdr"),
                )
                for t in meta["topics_with_message_count"]
            ]
        except Exception as exc:  # noqa: BLE001
            raise BagError(f"bag {p}: bad metadata.yaml ({_one_line(exc)})") from None
        odd = [(n, f) for n, f in odd if f != "cdr"]
        if odd:
            raise BagError(f"bag {p}: topic {odd[0][0]} is serialised as {odd[0][1]!r}, not CDR")
        try:
            return sorted(
                (
                    TopicInfo(
                        t["topic_metadata"]["name"],
                        t["topic_metadata"]["type"],
                        int(t["message_count"]),
                        _parse_qos(
                            t["topic_metadata"].get("offered_qos_profiles"),
                            f"bag {p} topic {t['topic_metadata']['name']}",
                        ),
                    )
                    for t in meta["topics_with_message_count"]
                ),
                key=lambda t: t.name,
            )
        except Exception as exc:  # noqa: BLE001
            raise BagError(f"bag {p}: bad metadata.yaml ({_one_line(exc)})") from None
    counts: dict[str, int] = {}
    types: dict[str, str] = {}
    qos: dict[str, tuple] = {}
    if storage == "mcap":
        from subpix_ros.io import _mcap

        try:
            f, buf = _mcap.open_mcap(p)
        except _mcap.Damaged as exc:
            raise BagCorrupt(p, exc.offset, exc.detail, 0) from None
        # no summary: channels and counts come from the chunks themselves
        for cid, n in (f.topic_counts() if f.indexed else _scan_unindexed(f, buf)).items():
            ch = f.channels.get(cid)
            if ch is not None:
                counts[ch.topic] = counts.get(ch.topic, 0) + n
                types[ch.topic] = ch.msgtype
        for ch in f.channels.values():
            if ch.encoding != "cdr":
                raise BagError(
                    f"bag {p}: topic {ch.topic} is serialised as {ch.encoding!r}, not CDR"
                )
            counts.setdefault(ch.topic, 0)
            types.setdefault(ch.topic, ch.msgtype)
            qos.setdefault(ch.topic, _parse_qos(ch.qos, f"bag {p} topic {ch.topic}"))
    else:
        with _sqlite(p) as con:
            try:
                cols = {r[1] for r in con.execute("PRAGMA table_info(topics)")}
                q = "offered_qos_profiles" if "offered_qos_profiles" in cols else "''"
                for name, typ, n, fmt, qtext in con.execute(
                    "SELECT name, type, "
                    "(SELECT count(*) FROM messages WHERE topic_id = topics.id), "
                    f"serialization_format, {q} FROM topics"
                ):
                    if fmt != "cdr":
                        raise BagError(f"bag {p}: topic {name} is serialised as {fmt!r}, not CDR")
                    counts[name], types[name] = int(n), typ
                    qos[name] = _parse_qos(qtext, f"bag {p} topic {name}")
            except sqlite3.DatabaseError as exc:
                raise BagCorrupt(p, None, f"sqlite3: {_one_line(exc)}", 0) from None
    return [TopicInfo(t, types[t], counts[t], qos.get(t, ())) for t in sorted(counts)]


def _scan_unindexed(f, buf) -> dict[int, int]:
    """Messages per channel of an MCAP file without a summary, from its readable chunks (this
    also collects the channel records inside them)."""
    from subpix_ros.io import _mcap

    schemas: dict[int, str] = {}
    counts: dict[int, int] = {}
    for c in f.chunks:
        try:
            msgs = _mcap.chunk_messages(buf, c, None, schemas, f.channels)
        except _mcap.Damaged:
            continue
        for _, _, cid, _ in msgs:
            counts[cid] = counts.get(cid, 0) + 1
    for _, _, cid, _ in f.loose:
        counts[cid] = counts.get(cid, 0) + 1
    return counts


@contextlib.contextmanager
def _sqlite(db: Path):
    try:
        con = sqlite3.connect(f"file:{db}?mode=ro&immutable=1", uri=True)
    except sqlite3.Error as exc:
        raise BagError(f"cannot open bag {db}: {_one_line(exc)}") from None
    try:
        yield con
    finally:
        con.close()


def _sqlite_bad_pages(con) -> tuple[int | None, str] | None:
    """First damaged page (byte offset) and sqlite's words for it, or None if quick_check passes."""
    try:
        rows = [r[0] for r in con.execute("PRAGMA quick_check(20)")]
        page_size = con.execute("PRAGMA page_size").fetchone()[0]
    except sqlite3.DatabaseError as exc:
        return None, f"sqlite3: {_one_line(exc)}"
    if rows == ["ok"]:
        return None
    pages = [int(m) for r in rows for m in re.findall(r"[Pp]age (\d+)", r)]
    offset = (min(pages) - 1) * page_size if pages else None
    return offset, f"sqlite3 quick_check: {_one_line(rows[0])}"


def _sqlite_messages(
    db: Path, topics: set[str] | None, expected: dict[str, int] | None, on_bad
) -> Iterator[BagMessage]:
    """Messages of one sqlite3 storage file in time order; damaged pages are found with
    ``PRAGMA quick_check`` before anything is delivered, and then every row is read by its id."""
    with _sqlite(db) as con:
        try:
            tmap = {i: (n, t) for i, n, t in con.execute("SELECT id, name, type FROM topics")}
        except sqlite3.DatabaseError as exc:
            on_bad(db, 0, f"topics table unreadable (sqlite3: {_one_line(exc)})", None, 0)
            return
        ids = [i for i, (n, _) in tmap.items() if topics is None or n in topics]
        if not ids:
            return
        where = f"topic_id IN ({','.join(str(i) for i in ids)})"
        bad = _sqlite_bad_pages(con)
        if bad is None:
            got: dict[str, int] = {}
            try:
                for tid, ts, data in con.execute(
                    f"SELECT topic_id, timestamp, data FROM messages WHERE {where} "
                    "ORDER BY timestamp, id"
                ):
                    name, typ = tmap[tid]
                    got[name] = got.get(name, 0) + 1
                    yield BagMessage(name, typ, int(ts), bytes(data))
            except sqlite3.DatabaseError as exc:
                on_bad(db, None, f"sqlite3: {_one_line(exc)}", None, None)
                return
            for name, n in (expected or {}).items():
                if name in got or (topics is None or name in topics):
                    if got.get(name, 0) < n and (topics is None or name in topics):
                        on_bad(
                            db,
                            None,
                            f"{name}: metadata.yaml says {n} messages, the storage holds "
                            f"{got.get(name, 0)}",
                            n - got.get(name, 0),
                            None,
                        )
            return
        offset, detail = bad
        # Damaged: read row by row (a lookup by id stops only at the pages it needs).
        try:
            top = con.execute("SELECT max(id) FROM messages").fetchone()[0] or 0
        except sqlite3.DatabaseError:
            top = 0
        top = max(top, sum((expected or {}).values()))
        good, failed = [], 0
        for rid in range(1, top + 1):
            try:
                row = con.execute(
                    f"SELECT topic_id, timestamp FROM messages WHERE id = ? AND {where}", (rid,)
                ).fetchone()
                if row is not None:
                    con.execute(
                        "SELECT data FROM messages WHERE id = ?", (rid,)
                    ).fetchone()  # overflow pages too
                    good.append((int(row[1]), rid, row[0]))
            except sqlite3.DatabaseError:
                failed += 1
        lost = failed
        if expected:
            want = sum(n for name, n in expected.items() if topics is None or name in topics)
            lost = max(failed, want - len(good))
        on_bad(
            db,
            offset,
            f"{detail} ({len(good)} readable row(s), {lost} unreadable or missing)",
            lost,
            len(good),
        )
        for ts, rid, tid in sorted(good):
            try:
                (data,) = con.execute("SELECT data FROM messages WHERE id = ?", (rid,)).fetchone()
            except sqlite3.DatabaseError:
                continue
            name, typ = tmap[tid]
            yield BagMessage(name, typ, ts, bytes(data))


def read_messages(
    path: str | Path,
    topics: Sequence[str] | None = None,
    *,
    skip_corrupt: bool = False,
    report: ReadReport | None = None,
) -> Iterator[BagMessage]:
    """Yield a bag's messages in time order, optionally only ``topics``; every reader of bags
    in the package goes through here.

    Parameters
    ----------
    path : bag folder (metadata.yaml + storage files), or one ``.mcap`` / ``.db3`` file.
    topics : only these topics (BagError if one is not in the bag).
    skip_corrupt : False: the first damaged record raises :class:`BagCorrupt` (offset, messages
        read). True: damaged records are skipped and counted in ``report``.
    report : filled while reading: messages delivered, records skipped, problems.

    Yields
    ------
    BagMessage
        topic, type, receive time stamp (ns) and the CDR bytes as recorded (decompressed if the
        bag compresses per message).

    Raises
    ------
    BagError
        bag missing or unreadable, topic not in it, a topic not serialised as CDR.
    BagCorrupt
        (``skip_corrupt`` False) the first damaged record: ``offset``, ``count``.

    Notes
    -----
    MCAP: record lengths, chunk CRCs (``uncompressed_crc``, when the writer set one) and each
    chunk's message count against its index are checked before a chunk's messages are
    delivered, so a damaged chunk delivers nothing; messages before it in time are delivered
    first. sqlite3 (no checksums in the format): ``PRAGMA quick_check`` before reading, and the
    row counts against metadata.yaml after.
    """
    p = Path(path)
    if not p.exists():
        raise BagError(f"bag not found: {p}")
    rep = report if report is not None else ReadReport()
    storage, files, meta = _bag_files(p)
    present = {t.name for t in bag_topics(p)}  # also refuses a bag that is not CDR
    if topics:
        missing = [t for t in topics if t not in present]
        if missing:
            raise BagError(
                f"topic(s) not in bag {path}: {', '.join(missing)} "
                f"(bag has: {', '.join(sorted(present))})"
            )
    wanted = set(topics) if topics else None

    def on_bad(
        file: Path, offset: int | None, detail: str, lost: int | None, count: int | None
    ) -> None:
        where = "" if offset is None else f" at byte offset {offset}"
        rep.skipped_records += 1
        rep.skipped_messages += lost or 0
        rep.problems.append(f"{file.name}{where}: {detail}")
        if rep.first_bad is None:
            rep.first_bad = (file, offset)
        if not skip_corrupt:
            raise BagCorrupt(file, offset, detail, rep.messages if count is None else count)

    if storage == "rosbags":
        yield from _rosbags_messages(p, wanted, rep)
        return
    if meta is not None and (meta.get("compression_mode") or "").lower() == "message":
        yield from _decompressed(
            p, _read_storage(p, storage, files, meta, wanted, rep, on_bad), rep
        )
        return
    yield from _read_storage(p, storage, files, meta, wanted, rep, on_bad)


def _decompressed(path: Path, msgs: Iterator[BagMessage], rep: ReadReport) -> Iterator[BagMessage]:
    """Per-message zstd compression (rosbag2 ``compression_mode: message``)."""
    from subpix_ros.io._mcap import _decompress

    for m in msgs:
        try:
            raw = _decompress(m.raw, "zstd", 0)
        except Exception as exc:  # noqa: BLE001 - the decompressor's own types
            raise BagCorrupt(
                path,
                None,
                f"a {m.topic} message does not decompress ({_one_line(exc)})",
                rep.messages,
            ) from None
        yield BagMessage(m.topic, m.msgtype, m.timestamp_ns, raw)


def _read_storage(p, storage, files, meta, wanted, rep, on_bad) -> Iterator[BagMessage]:
    if storage == "sqlite3":
        expected = None
        if meta is not None and len(files) == 1:
            expected = {
                t["topic_metadata"]["name"]: int(t["message_count"])
                for t in meta.get("topics_with_message_count", [])
            }
        for db in files:
            for m in _sqlite_messages(db, wanted, expected, on_bad):
                rep.messages += 1
                yield m
        return
    from subpix_ros.io import _mcap

    srcs = []
    for k, file in enumerate(files):
        try:
            f, buf = _mcap.open_mcap(file)
        except _mcap.Damaged as exc:
            on_bad(file, exc.offset, exc.detail, None, None)
            continue

        def bad(offset, detail, lost, _file=file):
            on_bad(_file, offset, detail, lost, None)

        srcs.extend(_keyed(s, k) for s in _mcap.sources(f, buf, wanted, bad))
    for t, _, payload in heapq.merge(*srcs, key=lambda x: (x[0], x[1])):
        if payload is None:
            continue
        ch, data = payload
        rep.messages += 1
        yield BagMessage(ch.topic, ch.msgtype, int(t), bytes(data))


def _keyed(src, k: int):
    """Order key (file index, position in file) for the merge across storage files."""
    for t, order, payload in src:
        yield t, (k, *order), payload


def _rosbags_messages(path: Path, wanted: set[str] | None, rep: ReadReport) -> Iterator[BagMessage]:
    """File-compressed bags (compression_mode: file): read through rosbags (its checks only)."""
    reader = open_reader(path)
    try:
        conns = [c for c in reader.connections if wanted is None or c.topic in wanted]
        try:
            for conn, ts, raw in reader.messages(connections=conns):
                rep.messages += 1
                yield BagMessage(conn.topic, conn.msgtype, int(ts), raw)
        except Exception as exc:  # noqa: BLE001
            raise BagCorrupt(path, None, _one_line(exc), rep.messages) from None
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

    def add_topic(self, topic: str, msgtype: str, qos: Sequence = ()) -> None:
        """Declare ``topic`` with the QoS profiles its publishers offered (rosbags ``Qos``),
        stored as rosbag2's ``offered_qos_profiles``; :meth:`write` declares unknown topics
        without them."""
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
        if topic not in self._connections:
            self.add_topic(topic, msgtype)
        self._writer.write(self._connections[topic], int(timestamp_ns), raw)
        self.count += 1

    def write_all(self, messages: Iterable[BagMessage]) -> None:
        for m in messages:
            self.write(m.topic, m.msgtype, m.timestamp_ns, m.raw)

    def close(self) -> None:
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
