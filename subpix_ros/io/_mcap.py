"""A verifying MCAP reader for rosbag2 storage files (used by :mod:`subpix_ros.io.bags`).

Every record's length is checked against its container, every chunk's ``uncompressed_crc``
(when the writer set one) against its decompressed bytes, and every chunk's message count
against its chunk index in the summary section; a file whose footer or summary is missing or
damaged (a recording that was killed, a truncated copy) is read by walking the data section.
Nothing is yielded from a chunk that failed a check. Problems go to a callback ``on_bad(offset,
detail, lost)`` (``lost``: messages the index says were in the bad part, None if unknown) that
either raises or records and lets reading go on.

Notes
-----
Record layout (MCAP specification, https://mcap.dev/spec): ``opcode u8 | length u64 | body``.
Chunk body: ``start u64 | end u64 | uncompressed_size u64 | uncompressed_crc u32 |
compression str | records_length u64 | records``; ``uncompressed_crc`` = CRC-32 (zlib) of the
decompressed records, 0 = not set. Footer (last 37 bytes): ``0x02 | 20 u64 | summary_start u64
| summary_offset_start u64 | summary_crc u32 | magic``; ``summary_crc`` covers the bytes from
``summary_start`` to the end of ``summary_offset_start``.
"""

from __future__ import annotations

import mmap
import struct
from binascii import crc32
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

MAGIC = b"\x89MCAP0\r\n"
OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK = (
    0x01,
    0x02,
    0x03,
    0x04,
    0x05,
    0x06,
)
OP_MESSAGE_INDEX, OP_CHUNK_INDEX, OP_STATISTICS, OP_DATA_END = 0x07, 0x08, 0x0B, 0x0F
_U16, _U32, _U64 = struct.Struct("<H"), struct.Struct("<I"), struct.Struct("<Q")
_CHUNK_HEAD = struct.Struct("<QQQI")
_MSG_HEAD = struct.Struct("<HIQQ")
_MAX_CHUNK = 1 << 32  # no sane writer makes a 4 GiB chunk; a bigger size is damage


class Damaged(Exception):
    """A record failed a check: ``offset`` (byte offset in the file) and a short ``detail``."""

    def __init__(self, offset: int, detail: str) -> None:
        super().__init__(f"{detail} at byte offset {offset}")
        self.offset = offset
        self.detail = detail


@dataclass
class Channel:
    topic: str
    msgtype: str
    qos: str  # offered_qos_profiles metadata (YAML text), '' if none
    encoding: str = "cdr"  # message encoding


@dataclass
class _Chunk:
    offset: int  # file offset of the chunk record (its opcode byte)
    length: int  # whole record length incl. opcode and length field (0 = unknown)
    start: int
    end: int
    counts: dict[int, int] | None = None  # per channel, from the chunk index (None: no index)


@dataclass
class _Bad:
    offset: int
    detail: str
    time_hint: int
    lost: int | None = None


@dataclass
class McapFile:
    path: Path
    channels: dict[int, Channel] = field(default_factory=dict)
    chunks: list[_Chunk] = field(default_factory=list)
    loose: list[tuple[int, int, int, int]] = field(
        default_factory=list
    )  # unchunked (time, off, cid, len)
    bad: list[_Bad] = field(default_factory=list)
    message_count: int | None = None  # from the summary statistics
    indexed: bool = False

    def topic_counts(self) -> dict[int, int]:
        counts: dict[int, int] = {}
        for c in self.chunks:
            for cid, n in (c.counts or {}).items():
                counts[cid] = counts.get(cid, 0) + n
        for _, _, cid, _ in self.loose:
            counts[cid] = counts.get(cid, 0) + 1
        return counts


def _string(buf, pos: int, end: int) -> tuple[str, int]:
    if pos + 4 > end:
        raise ValueError("string length past its record")
    (n,) = _U32.unpack_from(buf, pos)
    if pos + 4 + n > end:
        raise ValueError("string past its record")
    return bytes(buf[pos + 4 : pos + 4 + n]).decode("utf-8", "replace"), pos + 4 + n


def _schema(buf, pos: int, end: int) -> tuple[int, str]:
    (sid,) = _U16.unpack_from(buf, pos)
    name, _ = _string(buf, pos + 2, end)
    return sid, name


def _channel(buf, pos: int, end: int, schemas: dict[int, str]) -> tuple[int, Channel]:
    cid, sid = struct.unpack_from("<HH", buf, pos)
    topic, p = _string(buf, pos + 4, end)
    encoding, p = _string(buf, p, end)
    (mlen,) = _U32.unpack_from(buf, p)
    p, mend, qos = p + 4, p + 4 + mlen, ""
    if mend > end:
        raise ValueError("channel metadata past its record")
    while p < mend:
        k, p = _string(buf, p, mend)
        v, p = _string(buf, p, mend)
        if k == "offered_qos_profiles":
            qos = v
    return cid, Channel(topic, schemas.get(sid, ""), qos, encoding)


def _decompress(data, compression: str, size: int) -> bytes:
    if compression == "":
        return bytes(data)
    if compression == "zstd":
        try:
            from compression import zstd  # Python >= 3.14
        except ImportError:
            from backports import zstd  # rosbags' dependency
        return zstd.decompress(bytes(data))
    if compression == "lz4":
        from lz4.frame import decompress

        return decompress(bytes(data))
    raise ValueError(f"unknown chunk compression {compression!r}")


def open_mcap(path: Path) -> tuple[McapFile, mmap.mmap | bytes]:
    """Parse the file's structure (header, footer, summary; or walk the data section).

    Raises Damaged only when nothing at all can be read (no MCAP header); every other problem
    is listed in ``McapFile.bad`` with the message time before which it lies.
    """
    f = McapFile(path)
    with open(path, "rb") as fh:
        size = fh.seek(0, 2)
        buf = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) if size else b""
    if size < 8 or buf[:8] != MAGIC:
        raise Damaged(0, "not an MCAP file (bad magic)" if size else "empty file")
    if size < 17 or buf[8] != OP_HEADER:
        raise Damaged(8, "no MCAP header record")
    (hlen,) = _U64.unpack_from(buf, 9)
    data_start = 17 + hlen
    if data_start > size:
        raise Damaged(8, "header record past the end of the file")
    summary = _read_summary(f, buf, size, data_start)
    if summary is None:
        _walk(f, buf, data_start, size)
    return f, buf


def _read_summary(f: McapFile, buf, size: int, data_start: int) -> int | None:
    """Read the summary section and return its offset.

    None (with the reason in ``f.bad``) if the file has no usable summary.
    """
    foot = size - 37
    if size < data_start + 37 or buf[size - 8 :] != MAGIC or buf[foot] != OP_FOOTER:
        return None  # no footer (a recording cut short, a truncated copy): walk the data section
    summary_start, _ = struct.unpack_from("<QQ", buf, foot + 9)
    (summary_crc,) = _U32.unpack_from(buf, foot + 25)
    if summary_start == 0:
        return None  # valid file without a summary: walk the data section
    if not data_start <= summary_start <= foot:
        f.bad.append(_Bad(foot, "footer points outside the file", 2**63))
        return None
    if summary_crc and crc32(buf[summary_start : foot + 25]) != summary_crc:
        f.bad.append(_Bad(summary_start, "summary section checksum mismatch", 2**63))
        return None
    schemas: dict[int, str] = {}
    chunks, stats = [], None
    pos = summary_start
    try:
        while pos < foot:
            op = buf[pos]
            (ln,) = _U64.unpack_from(buf, pos + 1)
            body, end = pos + 9, pos + 9 + ln
            if end > foot:
                raise ValueError("record past the footer")
            if op == OP_SCHEMA:
                sid, name = _schema(buf, body, end)
                schemas[sid] = name
            elif op == OP_CHANNEL:
                cid, ch = _channel(buf, body, end, schemas)
                f.channels[cid] = ch
            elif op == OP_CHUNK_INDEX:
                start, stop, coff, clen = struct.unpack_from("<QQQQ", buf, body)
                (mlen,) = _U32.unpack_from(buf, body + 32)
                if body + 36 + mlen > end:
                    raise ValueError("chunk index past its record")
                offs = [
                    struct.unpack_from("<HQ", buf, body + 36 + 10 * i) for i in range(mlen // 10)
                ]
                (milen,) = _U64.unpack_from(buf, body + 36 + mlen)
                counts = _index_counts(buf, offs, coff + clen + milen, summary_start)
                chunks.append(_Chunk(coff, clen, start, stop, counts))
            elif op == OP_STATISTICS:
                (stats,) = _U64.unpack_from(buf, body)
            pos = end
    except (ValueError, struct.error, IndexError) as exc:
        f.bad.append(_Bad(pos, f"damaged summary section ({exc})", 2**63))
        f.channels.clear()
        return None
    if not chunks and stats:  # messages, but no chunk index: walk the data section
        return None
    f.chunks, f.message_count, f.indexed = chunks, stats, True
    return summary_start


def _index_counts(buf, offs, end: int, limit: int) -> dict[int, int]:
    """Count the messages per channel in a chunk.

    From its message index records (channel u16 | records length u32 | 16 bytes per message).
    """
    counts = {}
    for cid, off in offs:
        if not 0 < off < limit or buf[off] != OP_MESSAGE_INDEX:
            raise ValueError(f"message index of channel {cid} not at {off}")
        (n,) = _U32.unpack_from(buf, off + 11)
        counts[cid] = n // 16
    return counts


def _plausible_chunk(buf, pos: int, size: int) -> int:
    """Record length if a valid-looking chunk record starts at ``pos`` (else 0)."""
    if pos + 9 + 40 > size or buf[pos] != OP_CHUNK:
        return 0
    (ln,) = _U64.unpack_from(buf, pos + 1)
    if ln < 40 or pos + 9 + ln > size:
        return 0
    start, end, usize, _ = _CHUNK_HEAD.unpack_from(buf, pos + 9)
    if start > end or usize > _MAX_CHUNK:
        return 0
    (clen,) = _U32.unpack_from(buf, pos + 37)
    if clen > 8:
        return 0
    comp = bytes(buf[pos + 41 : pos + 41 + clen])
    if comp not in (b"", b"zstd", b"lz4"):
        return 0
    (rlen,) = _U64.unpack_from(buf, pos + 41 + clen)
    return ln if 28 + 4 + clen + 8 + rlen == ln else 0


def _walk(f: McapFile, buf, pos: int, size: int) -> None:
    """Walk the data section record by record (no usable summary).

    After a damaged record, resume at the next plausible chunk record.
    """
    schemas: dict[int, str] = {}
    last_time = 0
    while pos < size:
        op = buf[pos]
        ln = _U64.unpack_from(buf, pos + 1)[0] if pos + 9 <= size else None
        if op == OP_FOOTER or op == OP_DATA_END and ln is not None and pos + 9 + ln <= size:
            return
        problem = None
        if ln is None or pos + 9 + ln > size:
            problem = "record runs past the end of the file (truncated or damaged length)"
        elif op == 0:
            problem = "invalid record opcode 0"
        elif op == OP_CHUNK:
            if not _plausible_chunk(buf, pos, size):
                problem = "damaged chunk record header"
            else:
                start, end = struct.unpack_from("<QQ", buf, pos + 9)
                f.chunks.append(_Chunk(pos, 9 + ln, start, end))
                last_time = max(last_time, end)
        elif op == OP_MESSAGE:
            if ln < 22:
                problem = f"message record too short ({ln} bytes)"
            else:
                cid, _, t, _ = _MSG_HEAD.unpack_from(buf, pos + 9)
                f.loose.append((t, pos, cid, ln))
                last_time = max(last_time, t)
        elif op in (OP_SCHEMA, OP_CHANNEL):
            try:
                if op == OP_SCHEMA:
                    sid, name = _schema(buf, pos + 9, pos + 9 + ln)
                    schemas[sid] = name
                else:
                    cid, ch = _channel(buf, pos + 9, pos + 9 + ln, schemas)
                    f.channels[cid] = ch
            except (ValueError, struct.error):
                problem = "damaged schema/channel record"
        if problem is None:
            pos += 9 + ln
            continue
        f.bad.append(_Bad(pos, problem, last_time))
        nxt = pos + 1
        while True:
            nxt = buf.find(bytes([OP_CHUNK]), nxt)
            if nxt < 0 or _plausible_chunk(buf, nxt, size):
                break
            nxt += 1
        if nxt < 0:
            return
        pos = nxt
    f.bad.append(_Bad(size, "file ends without an MCAP footer (truncated)", 2**63))


def _chunk_records(buf, c: _Chunk) -> tuple[bytes, int]:
    """Decompressed, checked records of chunk ``c`` and the file offset of its records."""
    pos = c.offset
    if pos + 9 > len(buf) or buf[pos] != OP_CHUNK:
        raise Damaged(pos, "no chunk record where the chunk index points")
    (ln,) = _U64.unpack_from(buf, pos + 1)
    if c.length and ln + 9 != c.length:
        raise Damaged(pos, f"chunk record length {ln + 9} differs from its index ({c.length})")
    if pos + 9 + ln > len(buf) or ln < 40:
        raise Damaged(pos, "chunk record runs past the end of the file")
    _, _, usize, crc = _CHUNK_HEAD.unpack_from(buf, pos + 9)
    try:
        comp, p = _string(buf, pos + 37, pos + 9 + ln)
    except ValueError:
        raise Damaged(pos, "damaged chunk record header") from None
    (rlen,) = _U64.unpack_from(buf, p)
    if p + 8 + rlen != pos + 9 + ln or usize > _MAX_CHUNK:
        raise Damaged(pos, "chunk record lengths disagree")
    try:
        data = _decompress(buf[p + 8 : p + 8 + rlen], comp, usize)
    except Exception as exc:  # noqa: BLE001 - each decompressor raises its own types
        raise Damaged(
            pos, f"chunk does not decompress ({' '.join(str(exc).split())[:80]})"
        ) from None
    if len(data) != usize:
        raise Damaged(pos, f"chunk decompresses to {len(data)} bytes, header says {usize}")
    if crc and crc32(data) != crc:
        raise Damaged(pos, "chunk checksum (uncompressed_crc) mismatch")
    return data, p + 8


def _inner_records(buf, c: _Chunk):
    data, base = _chunk_records(buf, c)
    q, n = 0, len(data)
    while q < n:
        if q + 9 > n:
            raise Damaged(base + q, "record header past the end of its chunk")
        op = data[q]
        (ln,) = _U64.unpack_from(data, q + 1)
        if op == 0 or q + 9 + ln > n:
            raise Damaged(
                base + q,
                "record inside a chunk runs past the chunk (damaged length)"
                if op
                else "invalid record opcode 0 inside a chunk",
            )
        yield op, (data, q + 9), q + 9 + ln
        q += 9 + ln


def chunk_messages(
    buf, c: _Chunk, wanted: set[int] | None, schemas: dict[int, str], channels: dict[int, Channel]
) -> list[tuple[int, int, int, bytes]]:
    """Return every message of chunk ``c``, all checks passed.

    Each as (log_time, index in chunk, channel id, data); :class:`Damaged` if a check
    fails. Channel records inside the chunk are added to
    ``channels``.
    """
    out = []
    found: dict[int, int] = {}
    for op, (data, p), end in _inner_records(buf, c):
        if op == OP_MESSAGE:
            if end - p < 22:
                raise Damaged(c.offset, "message record too short inside a chunk")
            cid, _, t, _ = _MSG_HEAD.unpack_from(data, p)
            if not c.start <= t <= c.end:
                raise Damaged(c.offset, f"message time {t} outside its chunk's range")
            found[cid] = found.get(cid, 0) + 1
            if wanted is None or cid in wanted:
                out.append((t, len(out), cid, data[p + 22 : end]))
        elif op == OP_SCHEMA:
            sid, name = _schema(data, p, end)
            schemas[sid] = name
        elif op == OP_CHANNEL:
            cid, ch = _channel(data, p, end, schemas)
            channels.setdefault(cid, ch)
    if c.counts is not None and found != {k: v for k, v in c.counts.items() if v}:
        raise Damaged(
            c.offset,
            f"chunk holds {sum(found.values())} messages, its index {sum(c.counts.values())}",
        )
    out.sort()
    return out


Source = Iterator[tuple[int, tuple, object]]


def readable_after(f: McapFile, offset: int) -> bool:
    """Tell whether a chunk or an unchunked message starts after byte ``offset`` of the file.

    Parameters
    ----------
    f : McapFile
        The file as :func:`open_mcap` found it (its chunks and unchunked messages).
    offset : int
        Where a damaged record is.

    Returns
    -------
    bool
        True when a reader that skips the damage would still find messages after it; False
        when the file ends at its damage (a truncated copy, a recording killed mid-chunk).
    """
    return any(c.offset > offset for c in f.chunks) or any(off > offset for _, off, _, _ in f.loose)


def sources(
    f: McapFile, buf, wanted_topics: set[str] | None, on_bad: Callable[[int, str, int | None], None]
) -> list[Source]:
    """Return one time-ordered generator per chunk, damaged part or run of unchunked messages.

    One time-ordered generator per chunk / damaged part / run of unchunked messages, for a
    ``heapq.merge`` over (log_time, order, payload); payload None is a placeholder that only
    positions the source (nothing is decompressed before the merge reaches it).
    """
    schemas: dict[int, str] = {}
    out: list[Source] = []

    def wanted() -> set[int] | None:
        if wanted_topics is None:
            return None
        return {cid for cid, ch in f.channels.items() if ch.topic in wanted_topics}

    def chunk_src(i: int, c: _Chunk) -> Source:
        yield c.start, (i, -1), None
        try:
            msgs = chunk_messages(buf, c, wanted() if f.indexed else None, schemas, f.channels)
        except Damaged as exc:
            on_bad(exc.offset, exc.detail, sum(c.counts.values()) if c.counts is not None else None)
            return
        w = wanted()
        for t, k, cid, data in msgs:
            ch = f.channels.get(cid)
            if ch is None:
                on_bad(c.offset, f"message on undefined channel {cid}", 1)
                continue
            if w is None or cid in w:
                yield t, (i, k), (ch, data)

    def bad_src(i: int, b: _Bad) -> Source:
        yield b.time_hint, (i, -1), None
        on_bad(b.offset, b.detail, b.lost)

    def loose_src(i: int) -> Source:
        yield (f.loose[0][0] if f.loose else 0), (i, -1), None
        w = wanted()
        for k, (t, off, cid, ln) in enumerate(sorted(f.loose)):
            ch = f.channels.get(cid)
            if ch is None:
                on_bad(off, f"message on undefined channel {cid}", 1)
                continue
            if w is None or cid in w:
                yield t, (i, k), (ch, bytes(buf[off + 9 + 22 : off + 9 + ln]))

    items: list[tuple[int, object]] = [(c.offset, c) for c in f.chunks] + [
        (b.offset, b) for b in f.bad
    ]
    items.sort(key=lambda x: x[0])
    for i, (_, it) in enumerate(items):
        out.append(chunk_src(i, it) if isinstance(it, _Chunk) else bad_src(i, it))
    if f.loose:
        out.append(loose_src(len(items)))
    return out


def write_chunk_crcs(path: Path) -> int:
    """Fill in the ``uncompressed_crc`` of every chunk of an MCAP file written without them.

    Fill in the ``uncompressed_crc`` of every chunk of an MCAP file written without them
    (rosbags' writer leaves 0, "not set"), so that damage to a chunk is detected on reading.
    Returns the number of chunks updated.
    """
    f, buf = open_mcap(path)
    updates = []
    for c in f.chunks:
        (crc,) = _U32.unpack_from(buf, c.offset + 9 + 24)
        if crc == 0:
            data, _ = _chunk_records(buf, c)
            updates.append((c.offset + 9 + 24, crc32(data)))
    if isinstance(buf, mmap.mmap):
        buf.close()
    with open(path, "r+b") as fh:
        for off, crc in updates:
            fh.seek(off)
            fh.write(_U32.pack(crc))
    return len(updates)
