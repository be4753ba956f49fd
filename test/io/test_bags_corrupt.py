"""Damaged bags: stop at the first damaged record, or read past it with skip_corrupt.

Damaged bags: every reader of bags stops at the first damaged record with its offset and the
number of messages read, or (skip_corrupt) reads what can be read and reports what it skipped
(issue 19, item 2).
"""

import sqlite3
import struct

import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer

from subpix_ros.io import cdr
from subpix_ros.io.bags import BagCorrupt, BagWriter, ReadReport, bag_topics, read_messages

IMAGE = "sensor_msgs/msg/Image"


def _image(i, side=256):
    img = np.random.default_rng(i).integers(0, 256, (side, side)).astype(np.uint8)
    return cdr.image_to_cdr(img, "mono8", 10**9 + i * 10**8, "cam")


def _write_ours(path, n, storage="mcap"):
    with BagWriter(path, storage=storage) as w:
        for i in range(n):
            w.write("/cam", IMAGE, 10**9 + i * 10**8, _image(i))


def _write_rosbags(folder, n):
    """Return the writer of the rosbags library itself (chunks without uncompressed_crc)."""
    from subpix_ros.io.cdr import TYPESTORE

    with Writer(folder, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conn = w.add_connection("/cam", IMAGE, typestore=TYPESTORE)
        for i in range(n):
            w.write(conn, 10**9 + i * 10**8, _image(i))
    return next(folder.glob("*.mcap"))


def _overwrite(path, a, b, seed=9):
    raw = bytearray(path.read_bytes())
    raw[a:b] = np.random.default_rng(seed).bytes(b - a)
    path.write_bytes(bytes(raw))


def _middle_half(path):
    n = path.stat().st_size
    _overwrite(path, n // 4, 3 * n // 4)


@pytest.mark.parametrize("writer", ["ours", "rosbags"])
def test_mcap_middle_half_overwritten(tmp_path, writer):
    """Read the issue's bag, the middle half of the file overwritten.

    The issue's bag: 6 Image messages 256x256, the middle half of the file overwritten.
    """
    if writer == "ours":
        bag = tmp_path / "b.mcap"
        _write_ours(bag, 6)
        data = bag
    else:
        bag = tmp_path / "b"
        data = _write_rosbags(bag, 6)
    _middle_half(data)
    with pytest.raises(BagCorrupt) as err:
        list(read_messages(bag))
    e = err.value
    assert e.offset is not None and 0 < e.offset < data.stat().st_size and e.count == 0
    assert f"byte offset {e.offset}" in str(e) and "0 message(s) could be read" in str(e)
    assert len(str(e).splitlines()) == 1
    report = ReadReport()
    assert list(read_messages(bag, skip_corrupt=True, report=report)) == []
    assert report.skipped_records == 1 and report.skipped_messages == 6 and report.messages == 0


def test_writer_sets_chunk_crcs(tmp_path):
    from subpix_ros.io import _mcap

    _write_ours(tmp_path / "b.mcap", 40)  # > 1 MiB: several chunks
    f, buf = _mcap.open_mcap(tmp_path / "b.mcap")
    assert len(f.chunks) >= 2
    assert all(struct.unpack_from("<I", buf, c.offset + 9 + 24)[0] != 0 for c in f.chunks)


def _chunks(path):
    from subpix_ros.io import _mcap

    f, _ = _mcap.open_mcap(path)
    return [(c.offset, c.length, sum(c.counts.values())) for c in f.chunks]


@pytest.mark.parametrize("damage", ["payload", "length"])
def test_mcap_damaged_middle_chunk(tmp_path, damage):
    """Read three chunks, the middle one damaged.

    Three chunks, the middle one damaged: the first chunk's messages come out, then the error
    names the middle chunk; with skip_corrupt the third chunk's messages come out too.
    """
    bag = tmp_path / "b.mcap"
    _write_ours(bag, 45)
    chunks = _chunks(bag)
    assert len(chunks) == 3
    (o0, _, n0), (o1, l1, n1), (_, _, n2) = chunks
    if damage == "payload":  # a few bytes of image data: only the CRC can tell
        _overwrite(bag, o1 + l1 // 2, o1 + l1 // 2 + 16)
    else:  # the chunk record's own length field
        raw = bytearray(bag.read_bytes())
        raw[o1 + 1 : o1 + 9] = struct.pack("<Q", 2**40)
        bag.write_bytes(bytes(raw))
    got = []
    with pytest.raises(BagCorrupt) as err:
        for m in read_messages(bag):
            got.append(m)
    assert err.value.offset == o1 and err.value.count == n0 == len(got)
    report = ReadReport()
    msgs = list(read_messages(bag, skip_corrupt=True, report=report))
    assert len(msgs) == n0 + n2 and report.skipped_records == 1 and report.skipped_messages == n1
    stamps = [m.timestamp_ns for m in msgs]
    assert stamps == sorted(stamps)
    good = {m.timestamp_ns: m.raw for m in read_messages(tmp_path / "b.mcap", skip_corrupt=True)}
    assert all(good[m.timestamp_ns] == _image((m.timestamp_ns - 10**9) // 10**8) for m in msgs)


def test_mcap_truncated_reads_complete_chunks_when_asked(tmp_path):
    bag = tmp_path / "b.mcap"
    _write_ours(bag, 45)
    (_, _, n0), (o1, l1, _), _ = _chunks(bag)
    raw = bag.read_bytes()
    bag.write_bytes(raw[: o1 + l1 // 2])  # cut inside the second chunk: no summary, no footer
    with pytest.raises(BagCorrupt) as err:
        list(read_messages(bag))
    assert err.value.offset == o1 and err.value.count == n0
    report = ReadReport()
    assert len(list(read_messages(bag, skip_corrupt=True, report=report))) == n0
    assert report.skipped_records == 1 and "past the end" in report.problems[0]
    assert [(t.name, t.count) for t in bag_topics(bag)] == [("/cam", n0)]


def test_skip_corrupt_is_suggested_only_where_it_reads_more(tmp_path):
    """A damaged middle chunk or sqlite3 page has messages past it; a truncated file has none."""
    bag = tmp_path / "b.mcap"
    _write_ours(bag, 45)
    (_, _, n0), (o1, l1, _), _ = _chunks(bag)
    raw = bag.read_bytes()
    _overwrite(bag, o1 + l1 // 2, o1 + l1 // 2 + 16)
    with pytest.raises(BagCorrupt) as err:
        list(read_messages(bag))
    assert err.value.more and str(err.value).endswith("(--skip-corrupt reads on past the damage)")
    report = ReadReport()
    list(read_messages(bag, skip_corrupt=True, report=report))
    assert report.readable_after
    bag.write_bytes(raw[: o1 + l1 // 2])  # truncated inside the second chunk
    with pytest.raises(BagCorrupt) as err:
        list(read_messages(bag))
    assert not err.value.more and err.value.count == n0
    assert "--skip-corrupt" not in str(err.value), str(err.value)
    report = ReadReport()
    assert len(list(read_messages(bag, skip_corrupt=True, report=report))) == n0
    assert report.skipped_records == 1 and not report.readable_after
    db_bag = tmp_path / "db"
    _write_ours(db_bag, 6, storage="sqlite3")
    _middle_half(next(db_bag.glob("*.db3")))
    with pytest.raises(BagCorrupt) as err:
        list(read_messages(db_bag))
    assert err.value.count > 0 and err.value.more and "--skip-corrupt" in str(err.value)


def test_sqlite3_damaged(tmp_path):
    bag = tmp_path / "b"
    _write_ours(bag, 6, storage="sqlite3")
    db = next(bag.glob("*.db3"))
    _middle_half(db)
    with pytest.raises(BagCorrupt) as err:
        list(read_messages(bag))
    e = err.value
    assert e.offset is not None and 0 < e.offset < db.stat().st_size and e.count < 6
    assert "quick_check" in str(e) and len(str(e).splitlines()) == 1
    report = ReadReport()
    msgs = list(read_messages(bag, skip_corrupt=True, report=report))
    assert (
        len(msgs) == e.count
        and report.skipped_records == 1
        and report.skipped_messages == 6 - len(msgs)
    )
    for m in msgs:  # what is delivered is what was written
        assert m.raw == _image((m.timestamp_ns - 10**9) // 10**8)


def test_sqlite3_rows_missing_against_metadata(tmp_path):
    """Rows deleted from a sound database: only metadata.yaml's counts can tell."""
    bag = tmp_path / "b"
    _write_ours(bag, 6, storage="sqlite3")
    db = next(bag.glob("*.db3"))
    con = sqlite3.connect(db)
    con.execute("DELETE FROM messages WHERE id IN (2, 3)")
    con.commit()
    con.close()
    with pytest.raises(BagCorrupt, match="metadata.yaml says 6 messages, the storage holds 4"):
        list(read_messages(bag))
    report = ReadReport()
    assert len(list(read_messages(bag, skip_corrupt=True, report=report))) == 4
    assert report.skipped_messages == 2
