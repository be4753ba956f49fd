"""rosbag2 read/write through subpix_ros.io.bags, and the bundled sample flights."""

import json
import shutil

import numpy as np
import pytest

from subpix_ros.io import cdr
from subpix_ros.io.bags import BagError, BagWriter, bag_topics, read_messages


def _write(path, storage="mcap", n=5):
    with BagWriter(path, storage=storage) as w:
        for i in range(n):
            img = np.full((4, 6), i, np.uint8)
            w.write(
                "/cam",
                "sensor_msgs/msg/Image",
                1_000_000_000 + i,
                cdr.image_to_cdr(img, "mono8", 1_000 + i, "c"),
            )
            w.write(
                "/h",
                "std_msgs/msg/Float64",
                1_000_000_000 + i,
                cdr.serialize(
                    cdr.TYPESTORE.types["std_msgs/msg/Float64"](data=float(i)),
                    "std_msgs/msg/Float64",
                ),
            )


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_round_trip_bag_folder(tmp_path, storage):
    _write(tmp_path / "b", storage)
    topics = {t.name: (t.msgtype, t.count) for t in bag_topics(tmp_path / "b")}
    assert topics == {"/cam": ("sensor_msgs/msg/Image", 5), "/h": ("std_msgs/msg/Float64", 5)}
    msgs = list(read_messages(tmp_path / "b", ["/cam"]))
    assert [m.timestamp_ns for m in msgs] == [1_000_000_000 + i for i in range(5)]
    for i, m in enumerate(msgs):
        arr, header = cdr.cdr_to_image(m.raw)
        assert arr.shape == (4, 6) and int(arr[0, 0]) == i and cdr.header_to_ns(header) == 1000 + i


def test_single_mcap_file(tmp_path):
    _write(tmp_path / "one.mcap")
    assert (tmp_path / "one.mcap").is_file()
    assert len(list(read_messages(tmp_path / "one.mcap"))) == 10


def test_missing_bag(tmp_path):
    with pytest.raises(BagError, match="bag not found"):
        bag_topics(tmp_path / "nope")


def test_a_folder_that_is_not_a_bag_says_what_it_holds(tmp_path):
    """A folder of bags, or of a bare .mcap, is not a bag: the error says what to pass instead."""
    (tmp_path / "flights").mkdir()
    _write(tmp_path / "flights" / "a")
    _write(tmp_path / "flights" / "b")
    with pytest.raises(BagError, match=r"no metadata.yaml.*holds the bags a, b: pass them"):
        bag_topics(tmp_path / "flights")
    (tmp_path / "copied").mkdir()
    _write(tmp_path / "copied" / "flight.mcap")
    with pytest.raises(BagError, match=r"holds flight.mcap: pass the file"):
        bag_topics(tmp_path / "copied")
    assert len(bag_topics(tmp_path / "copied" / "flight.mcap")) == 2  # as the hint says
    (tmp_path / "empty").mkdir()
    with pytest.raises(BagError, match=r"no metadata.yaml\): \S+empty$"):
        bag_topics(tmp_path / "empty")


def test_missing_topic(tmp_path):
    _write(tmp_path / "b")
    with pytest.raises(BagError, match="not in bag.*/nope"):
        list(read_messages(tmp_path / "b", ["/nope"]))


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_truncated_bag(tmp_path, storage):
    _write(tmp_path / "b", storage, n=50)
    data = next(p for p in (tmp_path / "b").iterdir() if p.suffix in (".mcap", ".db3"))
    raw = data.read_bytes()
    data.write_bytes(raw[: len(raw) // 2])
    with pytest.raises(BagError, match="corrupt|truncated|cannot open"):
        list(read_messages(tmp_path / "b"))


def test_garbage_bag(tmp_path):
    (tmp_path / "g.mcap").write_bytes(b"this is not an mcap file" * 10)
    with pytest.raises(BagError):
        list(read_messages(tmp_path / "g.mcap"))


def test_writer_refuses_existing_output(tmp_path):
    _write(tmp_path / "b")
    with pytest.raises(BagError, match="exists"):
        BagWriter(tmp_path / "b")


def test_seneca_sample_bag(sample_bags):
    topics = {t.name: t for t in bag_topics(sample_bags / "seneca")}
    assert topics["/camera/image_raw"].count == 9
    assert topics["/camera/image_raw"].msgtype == "sensor_msgs/msg/Image"
    for name, typ in [
        ("/telemetry/fix", "sensor_msgs/msg/NavSatFix"),
        ("/telemetry/velocity", "geometry_msgs/msg/TwistStamped"),
        ("/telemetry/height", "std_msgs/msg/Float64"),
        ("/telemetry/imu", "sensor_msgs/msg/Imu"),
    ]:
        assert topics[name].msgtype == typ and topics[name].count > 300  # 10 Hz over the 36 s strip
    first = next(read_messages(sample_bags / "seneca", ["/camera/image_raw"]))
    img, header = cdr.cdr_to_image(first.raw)
    assert img.shape == (1350, 1800, 3)
    # stamped at the real EXIF capture time of IMG_0461 (2013-06-04 13:39:05, read as UTC)
    assert cdr.header_to_ns(header) == first.timestamp_ns == 1370353145 * 10**9
    assert (sample_bags / "seneca.tlog").stat().st_size > 10_000


def test_subpixel_sample_bag_matches_truth(sample_bags):
    truth = json.loads((sample_bags / "subpixel" / "truth.json").read_text())
    msgs = list(read_messages(sample_bags / "subpixel", ["/camera/image_raw"]))
    assert len(msgs) == len(truth["frames"]) == 24
    stamps = [cdr.header_to_ns(cdr.cdr_to_image(m.raw)[1]) for m in msgs]
    assert stamps == [f["stamp_ns"] for f in truth["frames"]]
    assert np.allclose(np.diff(stamps), 1e9 / truth["rate_hz"], atol=1)
    u = np.array([f["u"] for f in truth["frames"]])
    assert np.allclose(np.diff(u), truth["step_px"][0])


def test_sqlite3_sample_build(tmp_path):
    """The builder also writes sqlite3 storage, and it reads back the same."""
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    subprocess.run(
        [
            sys.executable,
            str(root / "scripts" / "build_sample_flight.py"),
            "--out",
            str(tmp_path),
            "--storage",
            "sqlite3",
        ],
        check=True,
        capture_output=True,
    )
    assert any(p.suffix == ".db3" for p in (tmp_path / "subpixel").iterdir())
    assert len(list(read_messages(tmp_path / "subpixel", ["/camera/image_raw"]))) == 24
    shutil.rmtree(tmp_path)


@pytest.mark.parametrize(
    "storage, mode",
    [
        ("mcap", "MESSAGE"),
        ("mcap", "FILE"),
        ("mcap", "STORAGE"),
        ("sqlite3", "MESSAGE"),
        ("sqlite3", "FILE"),
    ],
)
def test_compressed_bags_read_back(tmp_path, storage, mode):
    """Read back rosbag2's compression modes as the rosbags writer makes them.

    rosbag2's compression modes (per message, whole file, mcap chunks) as the rosbags writer
    makes them: the same bytes come back.
    """
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer

    raws = [cdr.image_to_cdr(np.full((8, 8), i, np.uint8), "mono8", i, "c") for i in range(5)]
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    w = Writer(tmp_path / "z", version=9, storage_plugin=plugin)
    w.set_compression(CompressionMode[mode], CompressionFormat.ZSTD)
    with w:
        conn = w.add_connection("/cam", "sensor_msgs/msg/Image", typestore=cdr.TYPESTORE)
        for i, raw in enumerate(raws):
            w.write(conn, 10 + i, raw)
    assert [m.raw for m in read_messages(tmp_path / "z")] == raws
    assert [(t.name, t.count) for t in bag_topics(tmp_path / "z")] == [("/cam", 5)]
