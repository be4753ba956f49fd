"""The products of one processed flight, written atomically into ``OUTDIR/<bag name>/``.

Everything is written into a hidden temporary folder beside the target
(``OUTDIR/.<name>.partial-<pid>``) and renamed to ``OUTDIR/<name>`` only when
complete, so an interrupted run never leaves a folder that looks complete: a
folder ``OUTDIR/<name>`` with ``summary.json`` is complete by construction.

Products (byte-identical for the same bag and parameters):

* ``results.mcap``: ROS 2 messages, each with the log time (and header
  stamp) of its source frame: ``/shift`` and ``/shift/std`` (Vector3Stamped), ``/homography``
  (Float64MultiArray), ``/aligned/reference_stamp`` (TimeReference),
  ``/super_resolved/compressed`` (CompressedImage, the set reference's stamp),
  ``/mosaic/compressed`` (CompressedImage, the last frame's stamp), both lossless PNG
  (the same bytes as ``superres/<stamp>.png`` and ``mosaic.png``),
  ``/telemetry/frame_interval`` (Float64, eq. 1 at the frame) and ``/diagnostics``
  (DiagnosticArray, once per second of flight time and at the end; counts and reasons
  only, no wall-clock times);
* ``superres/<stamp>.png`` and ``bicubic/<stamp>.png`` (same size and bit
  depth; the set's reference upsampled bicubically), ``mosaic.png``;
* ``shifts.csv``, ``frames.csv``, ``telemetry.csv``, ``summary.json``;
* ``inputs.json``: what they were made from (:func:`inputs_record`), so that a re-run
  skips only products of the same inputs (:func:`previous_products`).

``timing.json`` (processing time, stage times, memory) and ``report.html``
(which shows them) are the only files that change between runs.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import os
import shutil
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from subpix_ros.io import cdr
from subpix_ros.io.bags import BagWriter

DETERMINISTIC = (
    "results.mcap",
    "superres",
    "bicubic",
    "mosaic.png",
    "shifts.csv",
    "frames.csv",
    "telemetry.csv",
    "summary.json",
    "mosaic.json",
)
TIMING_FILES = ("timing.json", "report.html")
#: What a run writes whatever the flight (a report that could not be written makes the flight
#: partial, and its folder incomplete: a re-run redoes it)
REQUIRED = (
    "summary.json",
    "shifts.csv",
    "frames.csv",
    "telemetry.csv",
    "results.mcap",
    "timing.json",
    "inputs.json",
    "report.html",
)
INPUTS_FILE = "inputs.json"
#: What ``subpix process`` writes into OUTDIR itself, beside the flights' folders: never an input
BATCH_SUMMARY = "batch_summary.json"

_T = cdr.TYPESTORE.types
_DIAG_ARRAY = "diagnostic_msgs/msg/DiagnosticArray"
_FLOAT64 = "std_msgs/msg/Float64"


def rounded(x: float) -> float:
    """``x`` to 10 significant digits: the products' precision.

    The last bits of the estimates differ between runs and processes (OpenCV's
    thread pool, SIMD/BLAS kernels chosen by memory alignment), so the products
    carry 10 significant digits, far above that noise and below any accuracy
    that matters; with them the products are byte-identical whatever the
    number of threads or jobs (test/process/test_cli_process.py).
    """
    x = float(x)
    return float(f"{x:.10g}") if np.isfinite(x) else x


def is_complete(folder: Path) -> bool:
    """Return True if a product folder is complete: a readable summary.json (renamed into place)."""
    try:
        json.loads((folder / "summary.json").read_text())
        return True
    except (OSError, ValueError):
        return False


def input_files(bag: str | Path, tlog: Path | None) -> list[Path]:
    """Return the files a bag's products are made from: the bag's own files and its ``.tlog``.

    A ``batch_summary.json`` and hidden files (temporary ones) in the bag's folder are left
    out: that is what ``subpix process`` writes there when OUTDIR is the bag's folder, not an
    input.
    """
    p = Path(bag)
    files = (
        sorted(
            f
            for f in p.iterdir()
            if f.is_file() and f.name != BATCH_SUMMARY and not f.name.startswith(".")
        )
        if p.is_dir()
        else [p]
    )
    if tlog is not None and tlog not in files:
        files.append(tlog)
    return files


def inputs_record(
    files: Sequence[Path], params: dict, options: dict, bag: str | Path | None = None
) -> dict:
    """Return what a run's products were made from, with its fingerprint (``inputs.json``).

    Parameters
    ----------
    files : sequence of Path
        The input files (:func:`input_files`); each is identified by name, size and
        modification time (as make and rsync do: the bag's contents are not read).
    params : dict
        The stage parameters by node, as the run uses them.
    options : dict
        The run's other choices that change the products (camera topic, telemetry source,
        reading past corrupt records).
    bag : path, optional
        The bag, recorded as its absolute path (``bag``) outside the fingerprint: a bag moved
        elsewhere is still the same inputs, but a folder holding another bag's products is
        told apart (:func:`previous_products`).

    Returns
    -------
    dict
        ``fingerprint`` (SHA-256 of the rest, canonical JSON), ``files``, ``params``,
        ``options``, the package ``version`` and ``bag``.
    """
    from subpix_ros import __version__

    listed = []
    for f in files:
        try:
            st = f.stat()
            listed.append({"name": f.name, "size": st.st_size, "mtime_ns": st.st_mtime_ns})
        except OSError:
            listed.append({"name": f.name, "size": None, "mtime_ns": None})
    body = {"files": listed, "params": params, "options": options, "version": __version__}
    text = json.dumps(body, sort_keys=True, default=str)
    record = {"fingerprint": hashlib.sha256(text.encode()).hexdigest(), **body}
    if bag is not None:
        record["bag"] = str(Path(bag).absolute())
    return record


@dataclass
class Previous:
    """What an earlier run left in a bag's product folder.

    ``state``: "none" (no folder, or an empty one), "up to date" (complete, made from the
    same inputs), "changed" (complete, from other inputs: ``why`` names which), "incomplete"
    (a product folder without every product: ``why`` names what is missing), "other bag"
    (the products of another bag of the same name: ``why`` names it) or "not products" (a
    folder that no run of ``subpix process`` made: ``why`` says what it holds). ``status``
    and ``problem``: the earlier run's flight status and first problem (complete folders
    only).
    """

    state: str
    why: str = ""
    status: str | None = None
    problem: str | None = None


def listed_images(summary: dict) -> list[str]:
    """Return the image files a flight's ``summary.json`` says were written (relative paths)."""
    names = [
        st[k] for st in summary.get("sets") or [] for k in ("superres", "bicubic") if st.get(k)
    ]
    if (summary.get("mosaic") or {}).get("written"):
        names.append("mosaic.png")
    return names


def previous_products(folder: Path, record: dict) -> Previous:
    """Compare the products in ``folder`` with the inputs ``record`` of the run about to start."""
    if not folder.exists():
        return Previous("none")
    if not folder.is_dir():
        return Previous("not products", f"{folder} is a file")
    held = sorted(p.name for p in folder.iterdir())
    if not held:
        return Previous("none")
    if "summary.json" not in held and INPUTS_FILE not in held:
        shown = ", ".join(held[:3]) + (f" and {len(held) - 3} more" if len(held) > 3 else "")
        return Previous(
            "not products", f"{folder} holds files that subpix process did not write ({shown})"
        )
    missing = [n for n in REQUIRED if not (folder / n).is_file()]
    try:
        summary = json.loads((folder / "summary.json").read_text())
        old = json.loads((folder / INPUTS_FILE).read_text())
    except (OSError, ValueError):
        return Previous(
            "incomplete", f"{', '.join(missing) or 'summary.json'} missing or unreadable"
        )
    files = {f["name"]: f for f in old.get("files", [])}
    now = {f["name"]: f for f in record["files"]}
    if old.get("bag") and record.get("bag") and old["bag"] != record["bag"] and files != now:
        return Previous("other bag", f"{folder} holds the products of another bag, {old['bag']}")
    missing += [n for n in listed_images(summary) if not (folder / n).is_file()]
    if missing:
        shown = ", ".join(missing[:4]) + (
            f" and {len(missing) - 4} more" if len(missing) > 4 else ""
        )
        return Previous("incomplete", f"{shown} missing")
    status = summary.get("status")
    problems = summary.get("problems") or []
    if old.get("fingerprint") == record["fingerprint"]:
        return Previous("up to date", status=status, problem=problems[0] if problems else None)
    changed = [k for k in ("params", "options", "version") if old.get(k) != record.get(k)]
    changed += [f"file {n}" for n in sorted(set(files) | set(now)) if files.get(n) != now.get(n)]
    words = {"params": "parameters", "options": "options", "version": "subpix_ros version"}
    what = ", ".join(words.get(c, c) for c in changed) or "inputs"
    return Previous("changed", f"{what} changed since the last run")


def remove_leftovers(out_root: Path, name: str) -> list[str]:
    """Remove the temporary folders of ``name`` left by runs that were killed; return their names.

    A run writes into ``.<name>.partial-<pid>`` (and moves an old folder aside as
    ``.<name>.old-<pid>``); one whose process is gone (SIGKILL, power loss) left it behind.
    """
    removed = []
    for d in sorted(Path(out_root).glob(f".{name}.partial-*")) + sorted(
        Path(out_root).glob(f".{name}.old-*")
    ):
        try:
            pid = int(d.name.rsplit("-", 1)[1])
        except ValueError:
            continue
        if pid == os.getpid() or _alive(pid):
            continue
        shutil.rmtree(d, ignore_errors=True)
        removed.append(d.name)
    return removed


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _fmt(x: Any) -> str:
    if x is None:
        return ""
    if isinstance(x, (bool, np.bool_)):
        return "1" if x else "0"
    if isinstance(x, (float, np.floating)):
        return "" if not np.isfinite(x) else f"{float(x):.10g}"
    return str(x)


def write_csv(path: Path, columns: Sequence[str], rows: Sequence[dict]) -> None:
    """Write ``rows`` as CSV with ``columns`` (floats to 10 significant digits, NaN empty)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(columns)
    for r in rows:
        w.writerow([_fmt(r.get(c)) for c in columns])
    path.write_text(buf.getvalue())


def read_csv(path: Path) -> list[dict[str, str]]:
    """Read a CSV product as one dict of strings per row."""
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


class ProductWriter:
    """Writes one flight's products into a temporary folder; :meth:`commit` moves it in place."""

    def __init__(self, out_root: Path, name: str) -> None:
        self.final = Path(out_root) / name
        self.tmp = Path(out_root) / f".{name}.partial-{os.getpid()}"
        if self.tmp.exists():
            shutil.rmtree(self.tmp)
        (self.tmp / "superres").mkdir(parents=True)
        (self.tmp / "bicubic").mkdir()
        self.bag = BagWriter(self.tmp / "results.mcap")
        self._closed = False
        # Encoding and writing (PNG, the results bag) run on one background thread, in call order
        # (so results.mcap is the same every run), at most 16 calls ahead of the pipeline.
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="subpix-products")
        self._room = threading.BoundedSemaphore(16)
        self._error: BaseException | None = None

    def _later(self, fn, *args) -> None:
        if self._error is not None:
            raise self._error
        self._room.acquire()

        def run() -> None:
            try:
                if self._error is None:
                    fn(*args)
            except BaseException as exc:  # noqa: BLE001 - re-raised in the caller's thread
                self._error = exc
            finally:
                self._room.release()

        self._pool.submit(run)

    def later(self, fn, *args) -> None:
        """Queue ``fn(*args)`` on the products thread, after every write queued so far.

        For work on a product that need not hold up the pipeline (a set's report crop and
        scores); ``fn`` must not queue writes itself (it would wait on its own queue).
        """
        self._later(fn, *args)

    def flush(self) -> None:
        """Block until every call queued so far is done; re-raise the first error of one."""
        if self._error is None:
            self._pool.submit(lambda: None).result()  # one worker: runs after the rest
        if self._error is not None:
            raise self._error

    def wait(self) -> None:
        """Block until every queued write is done; re-raise the first error of one."""
        self._pool.shutdown(wait=True)
        if self._error is not None:
            raise self._error

    # ---------------------------------------------------------------- results.mcap
    def shift(self, stamp_ns: int, u: float, v: float, z: float, frame_id: str = "") -> None:
        """Record a shift estimate in the results bag (``/shift``)."""
        vec = (rounded(u), rounded(v), rounded(z))
        raw = cdr.vector3_stamped_to_cdr(vec, stamp_ns, frame_id)
        self._later(self.bag.write, "/shift", cdr.VECTOR3_STAMPED, stamp_ns, raw)

    def shift_std(self, stamp_ns: int, u_std: float, v_std: float, frame_id: str = "") -> None:
        """Record a shift's standard errors (px) in the results bag (``/shift/std``, as shift_node)."""
        vec = (rounded(u_std), rounded(v_std), 0.0)
        raw = cdr.vector3_stamped_to_cdr(vec, stamp_ns, frame_id)
        self._later(self.bag.write, "/shift/std", cdr.VECTOR3_STAMPED, stamp_ns, raw)

    def homography(self, stamp_ns: int, h: np.ndarray) -> None:
        """Record a homography in the results bag (``/homography``)."""
        hh = np.array([rounded(x) for x in np.asarray(h, np.float64).ravel()]).reshape(3, 3)
        raw = cdr.float64_array_to_cdr(hh, ["rows", "cols"])
        self._later(self.bag.write, "/homography", cdr.FLOAT64_MULTI_ARRAY, stamp_ns, raw)

    def reference_link(self, stamp_ns: int, reference_ns: int, frame_id: str = "") -> None:
        """Record which reference frame ``stamp_ns`` was aligned to (results bag)."""
        raw = cdr.time_reference_to_cdr(
            stamp_ns, reference_ns, frame_id, "subpix_ros reference frame"
        )
        self._later(
            self.bag.write,
            "/aligned/reference_stamp",
            "sensor_msgs/msg/TimeReference",
            stamp_ns,
            raw,
        )

    def frame_interval(self, stamp_ns: int, interval_s: float) -> None:
        """Record the frame interval (s) at ``stamp_ns`` in the results bag."""
        raw = cdr.serialize(_T[_FLOAT64](data=rounded(interval_s)), _FLOAT64)
        self._later(self.bag.write, "/telemetry/frame_interval", _FLOAT64, stamp_ns, raw)

    def diagnostics(
        self, stamp_ns: int, statuses: dict[str, tuple[int, str, dict[str, Any]]]
    ) -> None:
        """``statuses``: name -> (level 0 OK / 1 WARN / 2 ERROR, message, key values)."""
        KV, Status = _T["diagnostic_msgs/msg/KeyValue"], _T["diagnostic_msgs/msg/DiagnosticStatus"]
        status = [
            Status(
                level=int(lvl),
                name=name,
                message=str(msg)[:300],
                hardware_id="subpix process",
                values=[KV(key=str(k), value=_fmt(v)) for k, v in sorted(vals.items())],
            )
            for name, (lvl, msg, vals) in sorted(statuses.items())
        ]
        msg = _T[_DIAG_ARRAY](header=cdr.make_header(stamp_ns, ""), status=status)
        self._later(
            self.bag.write, "/diagnostics", _DIAG_ARRAY, stamp_ns, cdr.serialize(msg, _DIAG_ARRAY)
        )

    # ---------------------------------------------------------------- files
    def png(
        self,
        rel: str,
        image: np.ndarray | Callable[[], np.ndarray],
        topic: str | None = None,
        stamp_ns: int = 0,
        frame_id: str = "",
    ) -> None:
        """Queue writing ``image`` as PNG at ``rel`` in the flight's folder.

        ``image`` may be a function returning it, then called on the products thread. With
        ``topic`` the same PNG bytes also go into the results bag as a
        ``sensor_msgs/CompressedImage`` on ``topic`` (image_transport's format string,
        e.g. ``"bgr8; png compressed bgr8"``) stamped ``stamp_ns``: lossless, encoded once.
        """
        from subpix_ros.io.images import compressed_format, compressible_encoding
        from subpix_ros.io.images.png import encode_png

        path = self.tmp / rel
        path.parent.mkdir(parents=True, exist_ok=True)

        def write() -> None:
            img = np.asarray(image() if callable(image) else image)
            try:
                data = encode_png(img)
                path.write_bytes(data)
            except (OSError, ValueError) as exc:
                raise OSError(f"cannot write {rel}: {exc}") from exc
            if topic is not None:
                fmt = compressed_format(compressible_encoding(img), "png")
                raw = cdr.encoded_to_compressed_cdr(data, fmt, stamp_ns, frame_id)
                self.bag.write(topic, cdr.COMPRESSED_IMAGE, stamp_ns, raw)

        self._later(write)

    def csv(self, rel: str, columns: Sequence[str], rows: Sequence[dict]) -> None:
        """Write a CSV product at ``rel``."""
        write_csv(self.tmp / rel, columns, rows)

    def json(self, rel: str, data: Any) -> None:
        """Write a JSON product at ``rel``."""
        (self.tmp / rel).write_text(
            json.dumps(data, indent=1, sort_keys=True, default=_json_default) + "\n"
        )

    def close_bag(self) -> None:
        """Finish every queued write and close the results bag."""
        if not self._closed:
            self._closed = True
            try:
                self.wait()
            finally:
                self.bag.close()

    def commit(self, force: bool) -> Path:
        """Rename the finished folder into place (replacing an old one only with ``force``)."""
        self.close_bag()
        if self.final.is_dir() and not any(self.final.iterdir()):
            self.final.rmdir()  # an empty folder (made by hand, or a mount point's stub)
        if self.final.exists():
            if not force:
                raise FileExistsError(f"{self.final} appeared while processing (another run?)")
            trash = self.final.with_name(f".{self.final.name}.old-{os.getpid()}")
            os.rename(self.final, trash)
            os.rename(self.tmp, self.final)
            shutil.rmtree(trash, ignore_errors=True)
        else:
            os.rename(self.tmp, self.final)
        return self.final

    def abort(self) -> None:
        """Discard the unfinished folder (interrupted or failed bag)."""
        try:
            self.close_bag()
        except Exception:  # noqa: BLE001 - cleaning up after a failure
            pass
        shutil.rmtree(self.tmp, ignore_errors=True)


def _json_default(o: Any) -> Any:
    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, np.floating):
        return None if not np.isfinite(o) else float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")
