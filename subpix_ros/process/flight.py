"""One flight bag through the ROS-free stage pipeline, into products (``subpix process``).

:func:`process_bag` reads the bag (:mod:`subpix_ros.process.inputs`), feeds every telemetry
sample and frame in time order to one :class:`subpix_ros.stages.Pipeline` in this process (no
DDS, no queues: no frame is dropped for lack of time), collects what the stages report
(:mod:`subpix_ros.process.collector`) and writes the products
(:mod:`subpix_ros.process.products`, :mod:`subpix_ros.process.tables`).

Per frame it records what happened (``frames.csv``): a new reference (and why), aligned
(inliers, residual along/across the baseline, tracked or a tracking fallback), skipped by frame
selection (why), dropped (why: an image that does not decode, a frame of another size than the
flight's first, a stage error). Per aligned frame ``shifts.csv`` holds the estimated sub-pixel
shift (u, v) and its standard errors, whether it converged, the reference, the total shift
against the reference (the homography's whole pixels plus the estimated sub-pixel part), the
registration's displacement of the reference's centre (every frame with a homography, its
sub-pixel shift converged or not) and the shift expected from telemetry over the same time
(METHODS eq. 1, see :mod:`subpix_ros.process.tables`).

Bad input never raises out of :func:`process_bag`: a bag that cannot be opened, has no image
topic or no telemetry, breaks off (corrupt chunk) or has frames of mixed sizes is described by
one line in ``summary.json`` (``status``, ``problems``) and products are made from whatever is
usable.
"""

from __future__ import annotations

import json
import resource
import time
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import cv2

from subpix_ros.core.telemetry import TelemetryBuffer, TelemetrySample
from subpix_ros.io.bags import BagError, ReadReport
from subpix_ros.process.collector import (
    _clean,
    _Collector,
    _diag_statuses,
    _FrameRec,
    _pipe_stats,
    reason_key,
)
from subpix_ros.process.inputs import Flight, InputError, bag_name, find_tlog, open_flight
from subpix_ros.process.params import EXPECTED_SHIFT_PARAMS, pipeline_params
from subpix_ros.process.previews import _MonitorFeed, _mosaic, _preview
from subpix_ros.process.products import (
    INPUTS_FILE,
    Previous,
    ProductWriter,
    _json_default,
    input_files,
    inputs_record,
    previous_products,
    remove_leftovers,
)
from subpix_ros.process.summary import (
    _input_problems,
    _stage_stats,
    _summary,
    frame_gaps,
    telemetry_clock,
    telemetry_coverage,
    telemetry_unusable,
    time_jumps_back,
)
from subpix_ros.process.tables import (
    FRAME_COLUMNS,
    SHIFT_COLUMNS,
    TELEMETRY_COLUMNS,
    _interval_at,
    _shape_text,
    _shift_rows,
    _telemetry_row,
    telemetry_check,
)
from subpix_ros.process.timing import _Timer, _timing_record, prefetch
from subpix_ros.process.truth import _load_truth, set_scorer

__all__ = ["BagResult", "process_bag"]

DIAGNOSTICS_PERIOD_NS = 1_000_000_000


@dataclass
class BagResult:
    """What :func:`process_bag` reports back (also across processes: plain data only)."""

    bag: str
    name: str
    status: str  # "ok", "partial", "failed", "skipped"
    line: str  # one line for the terminal and the batch summary
    out: str | None = None
    frames_in: int = 0
    flight_s: float = 0.0
    wall_s: float = 0.0
    problems: list[str] = field(default_factory=list)
    previous_status: str | None = None  # "skipped": the status of the run that made the products


def process_bag(
    bag: str | Path,
    out_root: str | Path,
    params: dict[str, dict] | None = None,
    *,
    camera_topic: str | None = None,
    telemetry: str | None = None,
    force: bool = False,
    skip_corrupt: bool = False,
    progress: Callable[[int, int], None] | None = None,
    monitor: Any = None,
    sections_ahead: Any = None,
) -> BagResult:
    """Process one flight bag into ``out_root/<bag name>/``; never raise for bad input.

    Parameters
    ----------
    bag : path
        rosbag2 bag (directory, ``.mcap`` or ``.db3``).
    out_root : path
        The output folder; the products go to ``out_root/<bag name>/``.
    params : dict, optional
        Stage parameters keyed by node name (as in config/*.yaml).
    camera_topic, telemetry : str, optional
        As in :func:`subpix_ros.process.inputs.open_flight`.
    force : bool
        Redo a bag whose products are already complete (else it is skipped).
    skip_corrupt : bool
        Read past damaged chunks/records (counted in ``problems``, status "partial") instead of
        stopping the bag at the first one.
    progress : callable, optional
        ``progress(frames_done, frames_total)`` after every frame.
    monitor : subpix_ros.monitor.Monitor, optional
        A started live monitor fed as the bag is processed (``subpix process --serve``).
    sections_ahead : subpix_ros.process.report_ahead.SectionsAhead, optional
        A helper process that draws the report's per-frame sections while the last set is
        solved (the same report without it).

    Returns
    -------
    BagResult
        ``status`` "ok", "partial" (products made, but part of the input was
        unusable: see ``problems``), "failed" (no products) or "skipped".
    """
    t_wall = time.monotonic()
    cpu0 = time.process_time()
    bag = Path(bag)
    name = bag_name(bag)
    out_root = Path(out_root)
    final = out_root / name
    params = params or {}
    try:
        files = input_files(bag, find_tlog(bag))
    except OSError:
        files = [bag]  # not there or unreadable: open_flight says why
    record = inputs_record(
        files,
        params,
        {"camera_topic": camera_topic, "telemetry": telemetry, "skip_corrupt": skip_corrupt},
        bag,
    )
    refused = _refused_folder(bag, final)
    prev = previous_products(final, record) if refused is None else None
    if prev is not None and prev.state == "not products":
        refused = f"{prev.why}: not replaced; choose another output folder (-o) or move it"
    elif prev is not None and prev.state == "other bag" and not force:
        refused = f"{prev.why}: not replaced; choose another output folder (-o), or --force"
    if refused is not None:
        return BagResult(str(bag), name, "failed", f"{name}: failed: {refused}", problems=[refused])
    if prev.state == "up to date" and not force:
        return _skipped(bag, name, final, prev)
    try:
        flight = open_flight(bag, camera_topic, telemetry)
        flight.skip_corrupt = skip_corrupt
    except (InputError, BagError) as exc:
        return BagResult(str(bag), name, "failed", f"{name}: failed: {exc}", problems=[str(exc)])
    try:
        out_root.mkdir(parents=True, exist_ok=True)
        left = remove_leftovers(out_root, name)
        writer = ProductWriter(out_root, name)
        writer.json(INPUTS_FILE, record)
    except OSError as exc:  # a read-only or full disk: one line, not a traceback
        text = f"cannot write in {out_root}: {exc.strerror or exc}"
        return BagResult(str(bag), name, "failed", f"{name}: failed: {text}", problems=[text])
    try:
        res = _run(flight, writer, params, progress, monitor, sections_ahead)
        res = _finish_bag(res, writer, t_wall, cpu0, force or prev.state != "none")
        if prev.state in ("changed", "incomplete") and not force:
            res.line += f" (products redone: {prev.why})"
        if left:
            res.line += f" (removed {', '.join(left)}, left by a run that was killed)"
        return res
    except KeyboardInterrupt:
        writer.abort()
        raise
    except Exception as exc:  # noqa: BLE001 - one bad bag must not stop the others
        writer.abort()
        text = " ".join(f"{type(exc).__name__}: {exc}".split())[:300]
        return BagResult(str(bag), name, "failed", f"{name}: failed: {text}", problems=[text])


def _refused_folder(bag: Path, final: Path) -> str | None:
    """Return why the products must not go to ``final`` (the bag itself or a folder holding it)."""
    b, f = bag.resolve(), final.resolve()
    if b == f or f in b.parents:
        return (
            f"the products would replace the bag itself ({final} holds {bag}): "
            "choose another output folder (-o)"
        )
    return None


def _skipped(bag: Path, name: str, final: Path, prev: Previous) -> BagResult:
    """Return the result of a bag whose products are up to date, with the earlier status."""
    was = prev.status or "?"
    if prev.problem:
        was += f": {prev.problem}"
    return BagResult(
        str(bag),
        name,
        "skipped",
        f"{name}: skipped, products up to date in {final} (made from the same bag and "
        f"parameters; the flight was {was}) (--force redoes)",
        str(final),
        previous_status=prev.status,
        problems=[prev.problem] if prev.problem else [],
    )


def _finish_bag(
    res: BagResult, writer: ProductWriter, t_wall: float, cpu0: float, force: bool
) -> BagResult:
    """Write ``timing.json`` and the report, then move the finished products into place."""
    writer.close_bag()  # every queued write done
    res.wall_s = time.monotonic() - t_wall
    timing = res.__dict__.pop("_timing")
    crops = res.__dict__.pop("_crops", None)
    ahead = res.__dict__.pop("_ahead", None)
    # the report's figures a helper drew (the report draws what is missing)
    drawn = _drawn_ahead(*ahead) if ahead is not None else None
    timing.update(
        wall_s=res.wall_s,
        cpu_s=time.process_time() - cpu0,
        realtime_factor=(
            (res.flight_s / res.wall_s) if res.wall_s > 0 and res.flight_s > 0 else None
        ),
        peak_rss_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
        report_sections_ahead=sorted(k for k, v in (drawn or {}).items() if v and k != "offsets"),
        report_offsets_ahead=len((drawn or {}).get("offsets") or {}),
    )
    writer.json("timing.json", _clean(timing))
    try:
        from subpix_ros.process.report import write_report

        write_report(writer.tmp, crops=crops, sections=drawn)
    except Exception as exc:  # noqa: BLE001 - the products stand without the report
        _report_failed(res, writer, f"report not written: {type(exc).__name__}: {exc}")
    res.out = str(writer.commit(force))
    return res


def _report_failed(res: BagResult, writer: ProductWriter, problem: str) -> None:
    """Make a flight whose report could not be written ``partial``, in its line and summary.json.

    The other products stand; the folder lacks ``report.html``, so a re-run redoes it
    (:func:`subpix_ros.process.products.previous_products`). A failure to say so (the disk
    is full) raises: the bag has failed and nothing is moved into place.
    """
    res.problems.append(problem)
    if res.status == "ok":
        res.line = res.line.replace(f"{res.name}: ok:", f"{res.name}: partial:", 1)
        res.status = "partial"
    res.line += f"; {problem}"
    path = writer.tmp / "summary.json"
    summary = json.loads(path.read_text())
    summary["status"] = res.status
    summary["problems"] = list(summary.get("problems") or []) + [problem]
    writer.json("summary.json", summary)


def _run(
    flight: Flight,
    writer: ProductWriter,
    params: dict[str, dict],
    progress,
    monitor: Any = None,
    sections_ahead: Any = None,
) -> BagResult:
    """Feed the flight through the pipeline and write its products (all but timing, report)."""
    run = _FlightRun(flight, writer, params, monitor, sections_ahead)
    try:
        run.read(progress)
    except BaseException:
        run.pipe.close(emit=False)  # Ctrl-C, a failure: stop the reconstruction worker
        raise
    run.finish()
    mosaic_info = run.write_products()
    res = run.result(mosaic_info)
    if run.ahead is not None:
        res.__dict__["_ahead"] = (run.ahead, run.ahead_requests, run.offsets_ahead)
    return res


class _FlightRun:
    """One flight through the stage pipeline: its stages, collector and running counts."""

    def __init__(
        self,
        flight: Flight,
        writer: ProductWriter,
        params: dict[str, dict],
        monitor: Any,
        sections_ahead: Any = None,
    ) -> None:
        from subpix_ros.stages import MosaicStage, Pipeline

        self.flight = flight
        self.writer = writer
        self.pparams = pipeline_params(params)
        self.problems = _input_problems(flight)
        # The mosaic runs beside the pipeline (not inside it) so that a 16-bit flight's frames
        # reach it as 8-bit previews (the core mosaic draws uint8).
        # overlap: each set is solved on a worker thread while the next frames are registered,
        # when this process has a core to spare (a --jobs worker has cores // jobs OpenCV
        # threads); the products are the same either way (the images are emitted at the same
        # points)
        self.pipe = Pipeline(
            self.pparams, with_mosaic=False, overlap=True, solve_thread=cv2.getNumThreads() > 1
        )
        self.mosaic = MosaicStage.from_params(self.pparams["mosaic_node"])
        self.reg_params = {k: self.pipe.registration.param(k) for k in EXPECTED_SHIFT_PARAMS}
        self.collector = _Collector(
            writer,
            self.reg_params,
            self.pipe.registration.stats,
            score=set_scorer(_load_truth(flight.path)),
        )
        self._connect(monitor)
        self.ahead = sections_ahead
        self.offsets_ahead: dict[str, int | None] = {}  # offsets_key -> the helper's request
        # the factor the report reads from summary.json's parameters (2 when not set)
        self.report_factor = int(
            _as_json(self.pparams).get("reconstruction_node", {}).get("factor", 2)
        )
        if sections_ahead is not None:  # after the collector's: the set's entry is made
            self.pipe.on("super_resolved", self._draw_offsets_ahead)
        self.mosaic_pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="subpix-mosaic")
        self.mosaic_jobs: list[tuple[_FrameRec, Any]] = []
        self.timer = _Timer()
        stages = {
            "registration": self.pipe.registration,
            "shift": self.pipe.shift,
            "reconstruction": self.pipe.reconstruction,
            "mosaic": self.mosaic,
        }
        for stage_name, stage in stages.items():
            # the reconstruction's time is its solve (on the pipeline's worker thread)
            self.timer.wrap(
                stage_name, stage, "reconstruct" if stage_name == "reconstruction" else "add"
            )
        self.samples: list[TelemetrySample] = []
        self.dropped: Counter = Counter()
        self.examples: dict[str, str] = {}  # the first full reason of each kind
        self.size: tuple | None = None
        self.first_ns: int | None = None
        self.last_ns: int | None = None
        self.jumps_back_ns: list[int] = []  # how far each frame's stamp fell behind the last
        self.next_diag: int | None = None
        self.done = 0
        self.total = flight.frames_total
        self.status = "ok"
        self.broke_off: str | None = None
        self.add_ms: list[float] = []
        self.rows: list[dict] = []  # shifts.csv's rows (write_tables)
        self.telemetry_check = None  # the frames' shifts against the telemetry's (finish)
        self.buf: TelemetryBuffer | None = None
        self.ahead_requests: dict[str, int | None] = {}  # report section -> helper request

    def _connect(self, monitor: Any) -> None:
        """Route the pipeline's events to the collector (and to the live monitor, if any)."""
        collector = self.collector
        for kind, callback in (
            ("reference", collector.on_reference),
            ("aligned", collector.on_aligned),
            ("skipped", collector.on_skipped),
            ("shift", collector.on_shift),
            ("super_resolved", collector.on_super_resolved),
            ("error", collector.on_error),
            ("warning", collector.on_warning),
        ):
            self.pipe.on(kind, callback)
        # The mosaic runs on its own thread (it needs nothing from the other stages), frames in
        # order; its problems are warnings: a frame missing from the preview loses no product.
        self.mosaic.on_problem = lambda level, msg: collector.on_warning(("mosaic_node", msg))
        self.feed = _MonitorFeed(monitor, self.mosaic) if monitor is not None else None
        if self.feed is not None:
            self.pipe.on("shift", self.feed.shift)
            self.pipe.on("super_resolved", self.feed.super_resolved)

    def _draw_offsets_ahead(self, _sr: Any) -> None:
        """Ask the helper for the offsets figure of the set just recorded (its members)."""
        from subpix_ros.process.report_sections import offsets_key

        members = _as_json(self.collector.sets[-1]["members"])
        factor = self.report_factor
        self.offsets_ahead[offsets_key(members, factor)] = self.ahead.submit(
            "offsets_svg", members, factor
        )

    def mosaic_wait(self) -> None:
        """Wait for the queued mosaic additions and record on each frame whether it was drawn."""
        for rec, fut in self.mosaic_jobs:
            try:
                rec.mosaic = fut is not None and bool(fut.result())
            except Exception as exc:  # noqa: BLE001 - the mosaic is a preview: the frame goes on
                rec.mosaic = False
                self.collector.on_warning(("mosaic_node", f"{type(exc).__name__}: {exc}"))
        self.mosaic_jobs.clear()

    def all_stats(self) -> dict:
        """Every stage's statistics record by node name."""
        return {**_pipe_stats(self.pipe), "mosaic_node": self.mosaic.stats}

    def read(self, progress: Callable[[int, int], None] | None) -> None:
        """Feed every telemetry sample and frame of the bag, in time order, to the stages."""
        try:
            for kind, item in prefetch(self.flight.events()):
                if kind == "telemetry":
                    self.samples.append(item)
                    self.pipe.add_telemetry(item)
                    if self.feed is not None:
                        self.feed.telemetry(item)
                    continue
                self.done += 1
                if kind == "bad_frame":
                    stamp, why = item
                    self.collector.frames.append(
                        _FrameRec(len(self.collector.frames), int(stamp), "dropped", why)
                    )
                    self._drop(why)
                else:
                    self._frame(item)
                if progress is not None:
                    progress(self.done, self.total)
        except BagError as exc:
            self.broke_off = str(exc)
            self.status = "partial"
            self.problems.append(f"bag breaks off after {self.done} of {self.total} frames: {exc}")

    def _drop(self, reason: str) -> None:
        """Count a dropped frame by the kind of its reason (the first full reason kept)."""
        self.dropped[reason_key(reason)] += 1
        self.examples.setdefault(reason_key(reason), reason)

    def _frame(self, frame: Any) -> None:
        """One decoded frame: size check, mosaic job, pipeline, diagnostics once a second."""
        collector = self.collector
        rec = _FrameRec(len(collector.frames), int(frame.stamp_ns))
        collector.frames.append(rec)
        shape = (frame.image.shape, str(frame.image.dtype))
        if self.size is None:
            self.size = shape
            collector.dtype = str(frame.image.dtype)
            collector.shape = frame.image.shape[:2]
        if shape != self.size:
            rec.status = "dropped"
            rec.reason = (
                f"frame size {_shape_text(shape)} differs from the flight's "
                f"{_shape_text(self.size)}"
            )
            self._drop(rec.reason)
            return
        self.first_ns = rec.stamp_ns if self.first_ns is None else self.first_ns
        if self.last_ns is not None and rec.stamp_ns < self.last_ns:  # the stages restart
            self.jumps_back_ns.append(self.last_ns - rec.stamp_ns)
        self.last_ns = rec.stamp_ns
        collector.current = rec
        t0 = time.perf_counter()
        # the min_interval gate here, the drawing on the mosaic thread (woken for those only)
        taken = self.mosaic.take(frame)
        job = self.mosaic_pool.submit(self.mosaic.draw, _preview(frame)) if taken else None
        self.mosaic_jobs.append((rec, job))
        try:
            self.pipe.add(frame)
        except Exception as exc:  # noqa: BLE001 - a stage failure drops the frame, not the flight
            collector.on_error(f"{type(exc).__name__}: {exc}")
        self.add_ms.append(1000.0 * (time.perf_counter() - t0))
        if self.feed is not None:
            self.feed.frame(frame, len(self.mosaic_jobs))
        if rec.status == "in":
            rec.status = "dropped" if collector.errors else "in"
        collector.current = None
        if self.next_diag is None or rec.stamp_ns >= self.next_diag:
            self.next_diag = rec.stamp_ns + DIAGNOSTICS_PERIOD_NS
            self.mosaic_wait()  # the figures as of this frame, whatever the threads' timing
            statuses = _diag_statuses(self.all_stats())
            self.writer.diagnostics(rec.stamp_ns, statuses)
            if self.feed is not None:  # the live monitor's health table: the same statuses
                self.feed.diagnostics(statuses)

    def finish(self) -> None:
        """End of stream: wait for the mosaic, write the tables, flush the pipeline, state what went wrong.

        Once every frame is registered, measured and drawn into the mosaic, the per-frame tables
        are final (the flush only solves the last sets): they are written before it, and
        the helper (:class:`~subpix_ros.process.report_ahead.SectionsAhead`), if any, draws the
        report's per-frame sections from them while the last set is solved.
        """
        collector = self.collector
        collector.current = None
        self.mosaic_wait()
        self.mosaic_pool.shutdown(wait=True)
        self.rows = self.write_tables()
        self.telemetry_check = telemetry_check(collector, self.rows) if self.samples else None
        if self.ahead is not None:
            self.ahead_requests["per_frame"] = self.ahead.submit(
                "per_frame_sections",
                self.writer.tmp,
                _as_json(collector.references),
                {"registration_node": _as_json(_stage_stats(self)["registration_node"])},
                self.first_ns * 1e-9 if self.first_ns is not None else None,
                bool(self.samples),
                telemetry_clock({"registration_node": self.reg_params}),
            )
        try:
            self.pipe.flush()
        except Exception as exc:  # noqa: BLE001
            collector.on_error(f"flush: {type(exc).__name__}: {exc}")
        finally:
            self.pipe.close()
        if self.dropped:
            self.problems.extend(
                f"{n} frame(s) dropped: {self.examples[k]}" for k, n in sorted(self.dropped.items())
            )
        if collector.errors:
            self.problems.append(
                f"{len(collector.errors)} stage error(s), last: {collector.errors[-1]}"
            )
        read_on = _read_past_damage(self.flight.read_report, self.broke_off, self.done, self.total)
        if read_on:
            self.status = "partial"
            self.problems.append(read_on)

    def write_tables(self) -> list[dict]:
        """Write ``shifts.csv``, ``frames.csv`` and ``telemetry.csv``; return the shift rows."""
        collector, writer, reg_params = self.collector, self.writer, self.reg_params
        buf = self.buf = TelemetryBuffer(
            max_age_s=1e9,
            stale_after_s=float(reg_params["telemetry_timeout_s"]),
            max_samples=10**8,
        )
        for sample in self.samples:
            buf.add(sample)
        rows = _shift_rows(collector, buf, reg_params)
        writer.csv("shifts.csv", SHIFT_COLUMNS, rows)
        for rec in collector.frames:
            if rec.status == "in":
                rec.status = "kept"
        writer.csv("frames.csv", FRAME_COLUMNS, [vars(r) for r in collector.frames])
        writer.csv("telemetry.csv", TELEMETRY_COLUMNS, [_telemetry_row(s) for s in self.samples])
        return rows

    def write_products(self) -> dict:
        """Write the frame intervals, mosaic and last diagnostics (the tables are written)."""
        collector, writer, reg_params, buf = self.collector, self.writer, self.reg_params, self.buf
        for rec in collector.frames:
            if rec.status in ("aligned", "reference", "kept") and self.samples:
                interval = _interval_at(buf, rec.stamp_ns * 1e-9, reg_params)
                if interval is not None:
                    writer.frame_interval(rec.stamp_ns, interval)
        mosaic_info = _mosaic(self.mosaic, writer, self.last_ns)
        if self.last_ns is not None:
            writer.diagnostics(self.last_ns, _diag_statuses(self.all_stats()))
        return mosaic_info

    def result(self, mosaic_info: dict) -> BagResult:
        """Write ``summary.json`` and return the result with its one line and its timing."""
        flight, collector = self.flight, self.collector
        self.writer.flush()  # the sets' scores are added on the products thread
        if self.ahead is not None:  # mosaic.png and telemetry.csv are written
            self.ahead_requests["mosaic"] = self.ahead.submit(
                "mosaic_section",
                self.writer.tmp,
                _as_json(mosaic_info),
                telemetry_clock({"registration_node": self.reg_params}),
            )
        summary = _summary(self, mosaic_info)
        repeated = [
            r for r in collector.frames if r.status == "skipped" and "duplicate_stamp" in r.reason
        ]
        if repeated:  # a second frame of one stamp cannot be told apart downstream: left out
            self.problems.append(
                f"{len(repeated)} of {self.done} frames left out: each repeats the stamp of the "
                f"frame before it (first at {repeated[0].stamp_ns} ns); does the camera driver "
                "stamp its images?"
            )
        unusable = telemetry_unusable(self.samples)
        if unusable:  # telemetry read but not usable: said, not passed off as none received
            self.problems.append(unusable)
            tel = summary["telemetry"]
            tel["note"] = "; ".join(x for x in (tel["note"], unusable) if x)
        jumps = time_jumps_back(self.jumps_back_ns)
        if jumps:  # every stage restarted at each: sets and tracking cut short
            self.problems.append(jumps)
        gaps = frame_gaps([r.stamp_ns for r in collector.frames])
        if gaps:  # frames the bag never had: said, the products are what the bag allows
            self.problems.append(gaps)
        coverage = telemetry_coverage(
            [sm.t for sm in self.samples],
            [r.stamp_ns * 1e-9 for r in collector.frames],
            float(self.reg_params["telemetry_time_offset_s"]),
            float(self.reg_params["telemetry_timeout_s"]),
        )
        if coverage:  # telemetry read, but not at the frames' times: said, not left silent
            self.problems.append(coverage)
        check = summary["telemetry"]["check"]
        disagrees = check is not None and check["agrees"] is False
        if disagrees:  # products made, but the telemetry (or the camera's parameters) is wrong
            self.problems.append(check["note"])
        # frames that did not move under a moving vehicle: the input, not a parameter, is bad
        still = check is not None and bool(check.get("still"))
        if not collector.sets and flight.frames_total:
            self.problems.append(
                "no super-resolved image: no set reached min_frames" + _why_no_set(collector)
            )
        small = _sets_too_small(
            summary["stages"].get("reconstruction_node") or {},
            summary["parameters_in_effect"].get("reconstruction_node") or {},
        )
        if small:  # aligned and shifted, then let go: said, not left to a warning's count
            self.problems.append(small)
        failed = _failed_shifts(self.rows)
        if failed:  # many aligned frames without a shift: the sets lack members, said why
            self.problems.append(failed)
        fell = [st for st in collector.sets if st.get("fell_back")]
        if fell:  # a bicubic upscale in place of a super-resolved image: said, not counted as SR
            self.problems.append(
                f"{len(fell)} of {len(collector.sets)} sets fell back to bicubic "
                f"({fell[0].get('reason') or 'no reason given'})"
            )
        unaligned = summary["frames"]["kept"] > 1 and not summary["frames"]["aligned"]
        if self.status == "ok" and (
            not flight.frames_total
            or self.dropped
            or collector.errors
            or unaligned
            or repeated
            or still
            or jumps
            or unusable
            or flight.telemetry_unusable
            or coverage
            or disagrees
        ):
            self.status = "partial"  # part of the input (or all of it) could not be used
        summary["status"] = self.status
        self.writer.json("summary.json", _clean(summary))
        flight_s = summary["flight"]["duration_s"]
        frames = summary["frames"]
        line = (
            f"{flight.name}: {self.status}: {self.done} frames in, {frames['kept']} kept, "
            f"{frames['skipped']} skipped, {frames['dropped']} dropped, "
            f"{frames['shifts']} shifts, {len(collector.sets) - len(fell)} super-resolved"
            + (f" and {len(fell)} bicubic fallbacks" if fell else "")
            + _blur_words(summary["blur"])
        )
        problems = self.problems
        if problems:
            more = f" (+{len(problems) - 1} more)" if len(problems) > 1 else ""
            line += f"; {problems[0]}{more}"
        res = BagResult(
            str(flight.path),
            flight.name,
            self.status,
            line,
            frames_in=self.done,
            flight_s=flight_s,
            problems=problems,
        )
        res.__dict__["_timing"] = _timing_record(
            self.add_ms, self.timer, self.all_stats(), flight_s
        )
        res.__dict__["_crops"] = self.collector.crops
        return res


def _read_past_damage(
    report: ReadReport, broke_off: str | None, frames_read: int, frames_total: int
) -> str | None:
    """Say what a corrupt bag read with ``--skip-corrupt`` gave and lost (None otherwise).

    Parameters
    ----------
    report : ReadReport
        What the bag reader skipped.
    broke_off : str or None
        The error the reading stopped at (without ``--skip-corrupt``): then the break is the
        one statement (``bag breaks off after ...``) and this says nothing.
    frames_read, frames_total : int
        Frames read, and the bag's count of them.

    Returns
    -------
    str or None
        One problem line: whether the reader went on past the damage or the storage ended at
        it (a truncated file), what it skipped, and how many frames were read.
    """
    if not report.skipped_records or broke_off is not None:
        return None
    how = (
        "read past its damage"
        if report.readable_after
        else "read up to its damage (nothing readable after it)"
    )
    return f"corrupt bag {how}: {report.summary()}; {frames_read} of {frames_total} frames read"


def _failed_shifts(rows: list[dict]) -> str | None:
    """Say how many aligned frames have no sub-pixel shift, and why, when over max(2, 20 %).

    A few unconverged pairs are ordinary (a frame with a moving object); more mean the sets
    lose members (or every one) for a reason the operator should see in the flight's line.
    """
    bad = [r.get("reason") or "no reason given" for r in rows if not r.get("converged")]
    if len(bad) <= max(2, 0.2 * len(rows)):
        return None
    return f"{len(bad)} of {len(rows)} aligned frames have no sub-pixel shift: {_kinds(bad, 3)}"


def _sets_too_small(rec: dict, params: dict) -> str:
    """Say how many sets were too small to reconstruct and how many aligned frames went unused.

    ``rec`` is the reconstruction stage's statistics (``sets_dropped``, ``dropped``: the
    members of those sets) and ``params`` its parameters in effect (``min_frames``). '' when no
    set was dropped.
    """
    n, frames = int(rec.get("sets_dropped") or 0), int(rec.get("dropped") or 0)
    if not n:
        return ""
    rule = (
        f"each < min_frames {params['min_frames']}"
        if "min_frames" in params
        else "below min_frames"
    )
    return (
        f"{n} set{'s' if n > 1 else ''} too small to reconstruct ({rule}): "
        f"{frames} aligned frame{'s' if frames != 1 else ''} not used; a new reference before "
        "n_frames (max_frames_per_reference, a failed registration) or the end of the flight "
        "leaves such a set"
    )


def _why_no_set(collector: _Collector) -> str:
    """Say what became of the frames when no set reached min_frames ('' without frames).

    The references and why each started, and how many frames were aligned to them: e.g. every
    frame a new reference because every registration failed on blank frames.
    """
    refs = collector.references
    aligned = sum(1 for r in collector.frames if r.status == "aligned")
    if not refs:
        return ""
    why = _kinds([r["reason"] for r in refs])
    return f" ({aligned} frames aligned to {len(refs)} references, started by: {why})"


def _kinds(reasons: list[str], top: int | None = None) -> str:
    """Count reasons by kind (:func:`reason_key`): ``"n x <first full reason>, ..."``, commonest first."""
    kinds: Counter = Counter(reason_key(r) for r in reasons)
    first: dict[str, str] = {}
    for r in reasons:
        first.setdefault(reason_key(r), r)
    return ", ".join(f"{n} x {first[k]}" for k, n in kinds.most_common(top))


def _blur_words(blur: dict) -> str:
    """Say the optics blur of the flight's sets in a few words for its one line ('' if none)."""
    edges, used, n = blur.get("edges_px"), blur.get("used_px"), blur.get("sets_by_source", {})
    if edges is not None:
        return f" (optics blur {edges:.3f} px from edges)"
    if used is None:
        return ""
    if n.get("fallback"):
        return f" (optics blur: fallback {used[0]:.2f} px, no straight edge)"
    return f" (optics blur {used[0]:.3f} px given)"


def _as_json(data: Any) -> Any:
    """Return ``data`` as ``summary.json`` holds it (cleaned, through JSON): what the report reads."""
    return json.loads(json.dumps(_clean(data), default=_json_default))


def _drawn_ahead(
    ahead: Any, requests: dict[str, int | None], offsets: dict[str, int | None]
) -> dict:
    """Collect what the helper drew: report sections by name, and the sets' offsets figures."""
    drawn: dict[str, Any] = {}
    for rid in requests.values():
        drawn.update(ahead.result(rid) or {})
    svgs = {key: ahead.result(r) for key, r in offsets.items()}
    drawn["offsets"] = {key: svg for key, svg in svgs.items() if svg}
    return drawn
