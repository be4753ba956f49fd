"""Reading a bag's messages in time order, verifying what is read."""

from __future__ import annotations

import heapq
from pathlib import Path
from typing import Iterator, Sequence

from .records import BagCorrupt, BagError, BagMessage, ReadReport, _one_line, open_reader
from .sqlite import _sqlite_messages
from .topics import _bag_files, bag_topics


def read_messages(
    path: str | Path,
    topics: Sequence[str] | None = None,
    *,
    skip_corrupt: bool = False,
    report: ReadReport | None = None,
) -> Iterator[BagMessage]:
    """Yield a bag's messages in time order, optionally only ``topics``.

    Every reader of bags in the package goes through here.

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
        file: Path,
        offset: int | None,
        detail: str,
        lost: int | None,
        count: int | None,
        more: bool = False,
    ) -> None:
        """Count a damaged record (``more``: readable messages lie past it); raise unless skipping."""
        where = "" if offset is None else f" at byte offset {offset}"
        rep.skipped_records += 1
        rep.skipped_messages += lost or 0
        rep.problems.append(f"{file.name}{where}: {detail}")
        rep.readable_after = rep.readable_after or more
        if rep.first_bad is None:
            rep.first_bad = (file, offset)
        if not skip_corrupt:
            raise BagCorrupt(
                file, offset, detail, rep.messages if count is None else count, more=more
            )

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
        later_files = k < len(files) - 1
        try:
            f, buf = _mcap.open_mcap(file)
        except _mcap.Damaged as exc:
            on_bad(file, exc.offset, exc.detail, None, None, later_files)
            continue

        def bad(offset, detail, lost, _file=file, _f=f, _later=later_files):
            more = _later or _mcap.readable_after(_f, offset)
            on_bad(_file, offset, detail, lost, None, more)

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
