"""The sqlite3 storage of rosbag2, read with its integrity checked (``PRAGMA quick_check``)."""

from __future__ import annotations

import contextlib
import re
import sqlite3
from pathlib import Path
from typing import Iterator

from .records import BagError, BagMessage, _one_line


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
    """Yield the messages of one sqlite3 storage file in time order.

    Damaged pages are found with ``PRAGMA quick_check`` before anything is delivered, and
    then every row is read by its id.
    """
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
        yield from _damaged_rows(con, db, tmap, where, topics, expected, bad, on_bad)


def _damaged_rows(
    con: sqlite3.Connection,
    db: Path,
    tmap: dict,
    where: str,
    topics: set[str] | None,
    expected: dict[str, int] | None,
    bad: tuple,
    on_bad,
) -> Iterator[BagMessage]:
    """Yield the readable rows of a damaged storage file, read one by one by id."""
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
        bool(good),  # none delivered yet: skipping the damage reads them
    )
    for ts, rid, tid in sorted(good):
        try:
            (data,) = con.execute("SELECT data FROM messages WHERE id = ?", (rid,)).fetchone()
        except sqlite3.DatabaseError:
            continue
        name, typ = tmap[tid]
        yield BagMessage(name, typ, ts, bytes(data))
