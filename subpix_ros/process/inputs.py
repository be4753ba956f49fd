"""Flight bags as a time-ordered stream of camera frames and telemetry samples (no ROS).

A flight bag is a rosbag2 bag (mcap or sqlite3, read through
:mod:`subpix_ros.io.bags`) with a camera topic (``sensor_msgs/Image`` or
``sensor_msgs/CompressedImage``) and, optionally, the telemetry node's
``/telemetry/*`` topics or a MAVLink ``.tlog`` beside it (``<bag>.tlog``, or
the single ``*.tlog`` inside a bag directory).

:func:`open_flight` inspects the bag (topics, frame count, telemetry
source); :meth:`Flight.events` yields ``("telemetry", TelemetrySample)`` and
``("frame", Frame)`` / ``("bad_frame", (stamp_ns, reason))`` in the bag's
time order, with every telemetry sample at or before a frame's stamp given
before that frame (as a live pipeline would have received it).

Telemetry from topics is rebuilt as the registration node does it from the
same messages: a sample per ``telemetry/velocity`` (TwistStamped, ENU) with
the latest ``telemetry/height`` (Float64, m above ground), the heading of the
latest ``telemetry/imu`` orientation and the latest ``telemetry/fix``
position (for the GPS track of the report).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

from subpix_ros.core.telemetry import TelemetrySample
from subpix_ros.io import cdr
from subpix_ros.io.bags import BagError, ReadReport, bag_topics, read_messages
from subpix_ros.io.telemetry_msgs import TelemetryFromTopics

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
TELEMETRY_TOPICS = {
    "/telemetry/velocity": "geometry_msgs/msg/TwistStamped",
    "/telemetry/height": "std_msgs/msg/Float64",
    "/telemetry/imu": "sensor_msgs/msg/Imu",
    "/telemetry/fix": "sensor_msgs/msg/NavSatFix",
}
PREFERRED_CAMERA = "/camera/image_raw"


class InputError(Exception):
    """The bag cannot be processed at all; the message is one user-facing line."""


def bag_name(path: str | Path) -> str:
    """Name of a bag for its output folder: the directory name, or the file name without suffix."""
    p = Path(path)
    return p.stem if p.is_file() else p.name


def find_tlog(path: str | Path) -> Path | None:
    """Find the MAVLink log that belongs to bag ``path``.

    ``<bag>.tlog`` beside it, else the single
    ``*.tlog`` inside the bag directory; None if there is none.
    """
    p = Path(path)
    beside = p.parent / f"{bag_name(p)}.tlog"
    if beside.is_file():
        return beside
    if p.is_dir():
        inside = sorted(p.glob("*.tlog"))
        if len(inside) == 1:
            return inside[0]
    return None


def read_tlog(path: str | Path) -> tuple[list[TelemetrySample], str]:
    """Every accepted sample with a GNSS fix of a ``.tlog`` (read at full speed), and a note on the rest."""
    from subpix_ros.io.mavlink import LinkLoss, MavlinkReader

    samples: list[TelemetrySample] = []
    try:
        reader = MavlinkReader(str(path), rate=None, on_sample=samples.append)
        reader.start()
    except Exception as exc:  # noqa: BLE001 - pymavlink raises many types for bad files
        raise InputError(f"cannot read telemetry log {path}: {exc}") from None
    reader.join()
    reader.stop()
    st = reader.stats
    notes = []
    if not samples and not st.rejected:  # what the log holds instead
        notes.append(
            f"none of its {st.packets} MAVLink frames ({st.heartbeats} HEARTBEAT) is a "
            "GLOBAL_POSITION_INT, which a telemetry sample is made from"
        )
    if st.rejected:
        notes.append(f"{st.rejected} samples rejected ({st.last_reject})")
    if st.bad_crc or st.bad_data:
        notes.append(f"{st.bad_crc} bad CRC, {st.bad_data} bad data")
    lost = LinkLoss.share(st.packets, st.packets_lost)
    if lost > LinkLoss.WARN_ABOVE:
        notes.append(
            f"the recorded link lost {st.packets_lost} of {st.packets + st.packets_lost} MAVLink "
            f"frames ({100 * lost:.0f} %, gaps in the senders' sequence numbers)"
        )
    # as telemetry_node: without a GNSS fix the velocity and height are the autopilot's guesses
    fixed = [s for s in samples if s.has_fix]
    if len(fixed) < len(samples):
        notes.append(
            f"{len(samples) - len(fixed)} of {len(samples)} samples without a GNSS fix left out"
        )
    fixed.sort(key=lambda s: s.t)
    return fixed, "; ".join(notes)


@dataclass
class Flight:
    """What :func:`open_flight` found in a bag; :meth:`events` streams it."""

    path: Path
    name: str
    camera_topic: str | None
    camera_type: str | None
    frames_total: int
    topics: dict[str, tuple[str, int]]  # topic -> (type, count)
    telemetry_source: str  # "topics", "tlog <path>", or "none"
    telemetry_note: str = ""
    #: the namespace the bag's telemetry topics are under ("" for /telemetry/*, "/drone1" for
    #: /drone1/telemetry/*, as a telemetry_node started with -r __ns:=/drone1 publishes them)
    telemetry_ns: str = ""
    #: why a telemetry source that is there (a .tlog beside the bag) gave nothing usable
    telemetry_unusable: str = ""
    tlog_samples: list[TelemetrySample] = field(default_factory=list)
    camera_note: str = ""
    skip_corrupt: bool = False  # read past damaged chunks (counted in read_report)
    read_report: ReadReport = field(default_factory=ReadReport)

    @property
    def has_telemetry(self) -> bool:
        """Whether the flight has telemetry (topics or a .tlog)."""
        return self.telemetry_source != "none"

    def events(self) -> Iterator[tuple[str, object]]:
        """Yield the flight's telemetry samples and frames in time order.

        Items ``("telemetry", sample)``, ``("frame", Frame)`` and
        ``("bad_frame", (stamp_ns, reason))``. Raises :class:`BagError` if the storage turns out corrupt while reading
        (after yielding everything before the damage).
        """
        from subpix_ros.nodes.payloads import frame_from_cdr, frame_from_compressed_cdr

        topics = [self.camera_topic] if self.camera_topic else []
        use_topics = self.telemetry_source == "topics"
        ns = self.telemetry_ns
        if use_topics:
            topics += [ns + t for t in TELEMETRY_TOPICS if ns + t in self.topics]
        pending = list(self.tlog_samples)
        i = 0
        rebuild = _TopicTelemetry()
        decode = frame_from_compressed_cdr if self.camera_type == COMPRESSED else frame_from_cdr
        if not topics:
            return
        for m in read_messages(
            self.path, topics, skip_corrupt=self.skip_corrupt, report=self.read_report
        ):
            if m.topic == self.camera_topic:
                try:
                    frame = decode(m.raw, received=0.0)
                except Exception as exc:  # noqa: BLE001 - a bad frame is counted, not fatal
                    yield (
                        "bad_frame",
                        (
                            m.timestamp_ns,
                            f"undecodable image: {' '.join(str(exc).split())[:160]}",
                        ),
                    )
                    continue
                while i < len(pending) and pending[i].t <= frame.stamp_s:
                    yield "telemetry", pending[i]
                    i += 1
                yield "frame", frame
            else:
                try:
                    s = rebuild.add(m.topic.removeprefix(ns), m.raw, m.timestamp_ns)
                except Exception:  # noqa: BLE001 - a malformed telemetry message is skipped
                    rebuild.bad += 1
                    continue
                if s is not None:
                    yield "telemetry", s
        while i < len(pending):
            yield "telemetry", pending[i]
            i += 1

    def telemetry_samples(self) -> list[TelemetrySample]:
        """All telemetry samples of the flight (for the report's track and expected shifts)."""
        if self.telemetry_source == "none":
            return []
        if self.telemetry_source != "topics":
            return list(self.tlog_samples)
        rebuild = _TopicTelemetry()
        out = []
        ns = self.telemetry_ns
        tel = [ns + t for t in TELEMETRY_TOPICS if ns + t in self.topics]
        for m in read_messages(self.path, tel, skip_corrupt=self.skip_corrupt):
            try:
                s = rebuild.add(m.topic.removeprefix(ns), m.raw, m.timestamp_ns)
            except Exception:  # noqa: BLE001
                continue
            if s is not None:
                out.append(s)
        return out


class _TopicTelemetry(TelemetryFromTopics):
    """:class:`TelemetryFromTopics` fed raw CDR from a bag (topic names as the telemetry node's)."""

    bad = 0  # messages that could not be decoded

    def add(self, topic: str, raw: bytes, bag_ns: int) -> TelemetrySample | None:
        take = {
            "/telemetry/height": self.height,
            "/telemetry/imu": self.imu,
            "/telemetry/fix": self.navsat,
            "/telemetry/velocity": self.velocity,
        }.get(topic)
        return None if take is None else take(cdr.deserialize(raw, TELEMETRY_TOPICS[topic]))


def open_flight(
    path: str | Path, camera_topic: str | None = None, telemetry: str | None = None
) -> Flight:
    """Inspect bag ``path``: camera topic, frame count and telemetry source.

    Parameters
    ----------
    path : str or Path
        The bag (directory, ``.mcap`` or ``.db3``).
    camera_topic : str, optional
        None picks the bag's image topic: ``/camera/image_raw`` if present, else the image topic
        whose first frame is largest (a thumbnail stream may have more messages), then the one
        with most messages.
    telemetry : str, optional
        ``"topics"`` (the bag's ``/telemetry/*``), ``"tlog"`` (the ``.tlog`` beside the bag) or
        None (topics if the bag has them, else a tlog if one exists, else none).

    Returns
    -------
    Flight
        A bag without images is not an error here (``camera_topic`` None, ``frames_total`` 0).

    Raises
    ------
    InputError, BagError
        The bag cannot be opened or a requested source is missing.
    """
    p = Path(path)
    try:
        infos = bag_topics(p)
    except BagError:
        raise
    topics = {t.name: (t.msgtype, t.count) for t in infos}
    cam, note = _choose_camera(p, topics, camera_topic)
    flight = Flight(
        p,
        bag_name(p),
        cam,
        topics[cam][0] if cam else None,
        topics[cam][1] if cam else 0,
        topics,
        "none",
        camera_note=note,
    )
    _attach_telemetry(flight, p, topics, telemetry)
    return flight


def _choose_camera(
    p: Path, topics: dict[str, tuple[str, int]], camera_topic: str | None
) -> tuple[str | None, str]:
    """Return the camera topic (the one asked for, else chosen) and a note on the choice."""
    images = {n: tc for n, tc in topics.items() if tc[0] in (IMAGE, COMPRESSED)}
    note = ""
    if camera_topic:
        if camera_topic not in topics:
            raise InputError(
                f"camera topic {camera_topic} not in bag {p} (image topics: "
                f"{', '.join(sorted(images)) or 'none'})"
            )
        if topics[camera_topic][0] not in (IMAGE, COMPRESSED):
            raise InputError(f"topic {camera_topic} is {topics[camera_topic][0]}, not an image")
        cam = camera_topic
    elif PREFERRED_CAMERA in images:
        cam = PREFERRED_CAMERA
    elif len(images) == 1:
        cam = next(iter(images))
    elif images:
        # the camera is the largest picture (a thumbnail or preview stream often has more
        # messages), then the most frames
        sizes = {n: _first_frame_size(p, n, images[n][0]) for n in images}
        cam = sorted(images, key=lambda n: (-sizes[n][0] * sizes[n][1], -images[n][1], n))[0]
        seen = ", ".join(
            f"{n} ({'x'.join(map(str, sizes[n])) if sizes[n][0] else 'unreadable'}, "
            f"{images[n][1]} frames)"
            for n in sorted(images)
        )
        note = (
            f"camera topic {cam} chosen, the largest frames, of {seen} (--camera-topic to choose)"
        )
    else:
        cam = None
    return cam, note


def _first_frame_size(p: Path, topic: str, msgtype: str) -> tuple[int, int]:
    """Return (width, height) of the first readable frame of ``topic``, (0, 0) if none."""
    try:
        for m in read_messages(p, [topic]):
            try:
                if msgtype == IMAGE:
                    msg = cdr.cdr_to_image_msg(m.raw)
                    return int(msg.width), int(msg.height)
                img, _ = cdr.cdr_to_compressed(m.raw)
                return int(img.shape[1]), int(img.shape[0])
            except Exception:  # noqa: BLE001 - a bad first frame: try the next
                continue
    except BagError:
        pass
    return 0, 0


def _attach_telemetry(
    flight: Flight, p: Path, topics: dict[str, tuple[str, int]], telemetry: str | None
) -> None:
    """Set the flight's telemetry source: its topics, the tlog beside the bag, or none."""
    spaces = telemetry_namespaces(topics)
    has_topics = len(spaces) == 1
    if has_topics:
        flight.telemetry_ns = spaces[0]
    if telemetry == "topics" or (telemetry is None and has_topics):
        if not has_topics:
            raise InputError(f"bag {p}: {no_telemetry_topics(topics)}")
        flight.telemetry_source = "topics"
        if flight.telemetry_ns:
            flight.telemetry_note = (
                f"read from {flight.telemetry_ns}/telemetry/* (the bag has no "
                "/telemetry/*: a telemetry_node in a namespace)"
            )
    elif telemetry in ("tlog", None):
        tlog = find_tlog(p)
        if tlog is None:
            if telemetry == "tlog":
                raise InputError(
                    f"no .tlog beside bag {p} (looked for {p.parent / (bag_name(p) + '.tlog')})"
                )
        else:
            flight.tlog_samples, flight.telemetry_note = read_tlog(tlog)
            flight.telemetry_source = f"tlog {tlog.name}"
            if not flight.tlog_samples:
                flight.telemetry_source = "none"
                flight.telemetry_unusable = f"{tlog.name} has no usable telemetry sample" + (
                    f" ({flight.telemetry_note})" if flight.telemetry_note else ""
                )
                flight.telemetry_note = ""
    else:
        raise InputError(f"unknown telemetry source {telemetry!r} (tlog or topics)")


def telemetry_namespaces(topics: dict[str, tuple[str, int]]) -> list[str]:
    """Return the namespaces under which the bag has the telemetry node's topics.

    ``""`` for ``/telemetry/velocity`` and ``/telemetry/height`` at the root, ``"/drone1"``
    for ``/drone1/telemetry/...``; the root first, then the others sorted.
    """
    found = []
    for name in topics:
        if name.endswith("/telemetry/velocity"):
            ns = name.removesuffix("/telemetry/velocity")
            if ns + "/telemetry/height" in topics:
                found.append(ns)
    return sorted(found, key=lambda ns: (ns != "", ns))


def no_telemetry_topics(topics: dict[str, tuple[str, int]]) -> str:
    """Say why the bag's topics give no telemetry, naming what it has instead."""
    spaces = telemetry_namespaces(topics)
    if len(spaces) > 1:
        shown = ", ".join(f"{ns or ''}/telemetry/*" for ns in spaces)
        return f"telemetry topics under several namespaces ({shown}): which is this camera's?"
    mavros = sorted(t for t in topics if t.startswith("/mavros/"))
    if mavros:
        shown = ", ".join(mavros[:3]) + (f" and {len(mavros) - 3} more" if len(mavros) > 3 else "")
        return (
            f"no /telemetry/* topics, but mavros topics ({shown}): subpix process reads "
            "telemetry_node's /telemetry/* (record them: telemetry_node source:=mavros) or the "
            "flight's .tlog beside the bag"
        )
    return "no /telemetry/velocity and /telemetry/height topics"
