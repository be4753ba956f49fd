"""A bag's storage files, metadata and topics (names, types, counts, offered QoS)."""

from __future__ import annotations

import sqlite3
from pathlib import Path, PurePath

import yaml

from .records import BagCorrupt, BagError, TopicInfo, _one_line, _parse_qos
from .sqlite import _sqlite


def _what_it_holds(folder: Path) -> str:
    """Return a hint for a folder that is not a bag: the bag files or bags inside it."""
    try:
        entries = sorted(folder.iterdir())
    except OSError:
        return ""
    files = [e.name for e in entries if e.is_file() and e.suffix in (".mcap", ".db3")]
    bags = [e.name for e in entries if e.is_dir() and (e / "metadata.yaml").is_file()]
    if files:
        return f"; it holds {', '.join(files[:5])}: pass the file (read without metadata.yaml)"
    if bags:
        more = f" and {len(bags) - 5} more" if len(bags) > 5 else ""
        return f"; it holds the bags {', '.join(bags[:5])}{more}: pass them ({folder}/*)"
    return ""


def _bag_files(path: Path) -> tuple[str, list[Path], dict | None]:
    """(storage, storage files, parsed metadata.yaml or None) of a bag folder or single file."""
    if path.is_dir():
        meta_path = path / "metadata.yaml"
        if not meta_path.is_file():
            raise BagError(f"not a rosbag2 bag (no metadata.yaml): {path}{_what_it_holds(path)}")
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
    """Count the messages per channel of an MCAP file without a summary.

    From its readable chunks; this also collects the channel records inside them.
    """
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
