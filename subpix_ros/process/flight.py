"""One flight bag through the ROS-free stage pipeline, into products (``subpix process``).

:func:`process_bag` reads the bag (:mod:`subpix_ros.process.inputs`), feeds
every telemetry sample and frame in time order to one
:class:`subpix_ros.stages.Pipeline` in this process (no DDS, no queues: no
frame is dropped for lack of time), collects what the stages report and
writes the products (:mod:`subpix_ros.process.products`).

Per frame it records what happened (``frames.csv``): a new reference (and
why), aligned (inliers, residual along/across the baseline, tracked or a
tracking fallback), skipped by frame selection (why), dropped (why: an image
that does not decode, a frame of another size than the flight's first, a
stage error). Per aligned frame ``shifts.csv`` holds the estimated
sub-pixel shift (u, v) and its standard errors, whether it converged, the
reference, the total shift against the reference (the homography's whole
pixels plus the estimated sub-pixel part) and the shift expected from
telemetry over the same time (METHODS eq. 1):

    u_exp = s dt cos(course - heading),  v_exp = -s dt sin(course - heading),
    s = f V / (H a),  dt = t_frame - t_reference

(rows, columns; compass angles; ``heading`` = vehicle yaw + the camera's yaw
offset: :func:`subpix_ros.core.timing.expected_shift_px`).

Bad input never raises out of :func:`process_bag`: a bag that cannot be
opened, has no image topic or no telemetry, breaks off (corrupt chunk) or
has frames of mixed sizes is described by one line in ``summary.json``
(``status``, ``problems``) and products are made from whatever is usable.
"""

from __future__ import annotations

import math
import queue
import re
import resource
import threading
import time
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

from subpix_ros.core.telemetry import TelemetryBuffer, TelemetrySample
from subpix_ros.core.timing import expected_shift_px, frame_interval
from subpix_ros.io.bags import BagError
from subpix_ros.process.inputs import Flight, InputError, bag_name, open_flight
from subpix_ros.process.products import ProductWriter, is_complete, rounded

# The registration stage's parameters that the expected shift and frame interval use.
EXPECTED_SHIFT_PARAMS = (
    "focal_length_mm",
    "pixel_pitch_um",
    "camera_yaw_offset_deg",
    "telemetry_time_offset_s",
    "telemetry_timeout_s",
    "p",
    "min_speed_mps",
)
DIAGNOSTICS_PERIOD_NS = 1_000_000_000
SHIFT_COLUMNS = (
    "stamp_ns",
    "reference_stamp_ns",
    "u_px",
    "v_px",
    "u_std_px",
    "v_std_px",
    "converged",
    "reason",
    "u_total_px",
    "v_total_px",
    "u_expected_px",
    "v_expected_px",
    "u_residual_px",
    "v_residual_px",
)
FRAME_COLUMNS = (
    "index",
    "stamp_ns",
    "status",
    "reason",
    "reference_stamp_ns",
    "inliers",
    "rms_px",
    "rms_along_px",
    "rms_cross_px",
    "tracked",
    "mosaic",
)
TELEMETRY_COLUMNS = (
    "t_s",
    "lat_deg",
    "lon_deg",
    "alt_msl_m",
    "height_agl_m",
    "ground_speed_mps",
    "course_deg",
    "heading_deg",
)


def reason_key(reason: str) -> str:
    """A reason without its numbers, for counting reasons of one kind together."""
    return re.sub(r"[-+]?\d+(\.\d+)?(e[-+]?\d+)?", "#", str(reason)).strip() or "unspecified"


def _clean(o: Any) -> Any:
    """JSON-safe copy: floats to 10 significant digits (:func:`rounded`), non-finite -> None,
    numpy scalars -> Python."""
    if isinstance(o, dict):
        return {str(k): _clean(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_clean(v) for v in o]
    if isinstance(o, (np.floating, float)):
        return rounded(o) if math.isfinite(float(o)) else None
    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, np.bool_):
        return bool(o)
    return o


def _stats_dict(st: Any) -> dict:
    if st is None:
        return {}
    if hasattr(st, "as_dict"):
        return dict(st.as_dict())
    if isinstance(st, dict):
        return dict(st)
    return dict(getattr(st, "__dict__", {}))


_TIME_KEY = re.compile(r"(^times$|_ms$|time_s$)")  # stage figures that are processing times


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


@dataclass
class _FrameRec:
    index: int
    stamp_ns: int
    status: str = "in"
    reason: str = ""
    reference_stamp_ns: int | None = None
    inliers: int | None = None
    rms_px: float | None = None
    rms_along_px: float | None = None
    rms_cross_px: float | None = None
    tracked: bool | None = None
    mosaic: bool | None = None


class _Collector:
    """Turns the pipeline's events for the frame being added into records and products."""

    def __init__(self, writer: ProductWriter, reg_params: dict, reg_stats: Any = None) -> None:
        self.w = writer
        self.reg_stats = reg_stats
        self._tracked = self._fallbacks = 0
        self.reg_params = reg_params
        self.frames: list[_FrameRec] = []
        self.current: _FrameRec | None = None
        self.shifts: dict[int, dict] = {}
        self.references: list[dict] = []
        self.sets: list[dict] = []
        self.sr_images: list[Any] = []
        self.errors: list[str] = []
        self.homographies: dict[int, np.ndarray] = {}
        self.priors: dict[int, tuple[float, float] | None] = {}
        self.ref_of: dict[int, int] = {}
        self.dtype: str | None = None
        self.shape: tuple = (0, 0)
        self.warnings: Counter = Counter()
        self.lock = threading.Lock()
        self.warning_examples: dict[str, str] = {}

    # --------------------------------------------------------- pipeline callbacks
    def on_reference(self, ev: Any) -> None:
        frame = getattr(ev, "frame", ev)
        reason = str(getattr(ev, "reason", "") or "")
        stamp = int(getattr(frame, "stamp_ns"))
        self.references.append({"stamp_ns": stamp, "reason": reason})
        rec = self.current
        if rec is not None and rec.stamp_ns == stamp:
            rec.status, rec.reason, rec.reference_stamp_ns = "reference", reason, stamp

    def on_aligned(self, a: Any) -> None:
        rec = self.current
        ref = int(a.reference.stamp_ns)
        self.ref_of[int(a.stamp_ns)] = ref
        self.homographies[int(a.stamp_ns)] = np.asarray(a.homography, np.float64).reshape(3, 3)
        self.priors[int(a.stamp_ns)] = (
            tuple(a.prior) if getattr(a, "prior", None) is not None else None
        )
        self.w.homography(a.stamp_ns, a.homography)
        self.w.reference_link(a.stamp_ns, ref, getattr(a, "frame_id", ""))
        if rec is not None and rec.stamp_ns == int(a.stamp_ns):
            rec.status, rec.reference_stamp_ns = "aligned", ref
            st = self.reg_stats  # the registration stage's figures of the frame just aligned
            if st is not None:
                rec.inliers, rec.rms_px = st.inliers, st.rms_px
                rec.rms_along_px, rec.rms_cross_px = st.rms_along_px, st.rms_cross_px
                tracked, fallbacks = st.tracked, st.fallbacks
                if tracked > self._tracked:
                    rec.tracked = True
                elif fallbacks > self._fallbacks:
                    rec.tracked = False
                self._tracked, self._fallbacks = tracked, fallbacks
        self.shifts[int(a.stamp_ns)] = {
            "stamp_ns": int(a.stamp_ns),
            "reference_stamp_ns": ref,
            "converged": False,
            "reason": "no shift reported",
        }

    def on_skipped(self, item: Any) -> None:
        stage, sk = item if isinstance(item, tuple) else ("", item)
        rec = self.current
        reason = str(getattr(sk, "reason", sk))
        detail = str(getattr(sk, "detail", "") or "")
        if detail:
            reason = f"{reason}: {detail}"
        stamp = getattr(sk, "stamp_ns", None)
        stamp = rec.stamp_ns if stamp is None and rec is not None else stamp
        if stamp is not None and int(stamp) in self.shifts and (not stage or "shift" in stage):
            self.shifts[int(stamp)].update(converged=False, reason=reason)
            return
        if rec is not None and (stamp is None or int(stamp) == rec.stamp_ns):
            rec.status, rec.reason = "skipped", reason

    def on_shift(self, item: Any) -> None:
        s = item[0] if isinstance(item, tuple) else item
        row = self.shifts.setdefault(int(s.stamp_ns), {"stamp_ns": int(s.stamp_ns)})
        row.update(
            reference_stamp_ns=int(s.reference_stamp_ns),
            u_px=rounded(s.u),
            v_px=rounded(s.v),
            u_std_px=rounded(s.u_std),
            v_std_px=rounded(s.v_std),
            converged=True,
            reason="",
        )
        self.w.shift(s.stamp_ns, s.u, s.v, s.z, getattr(s, "frame_id", ""))

    def on_super_resolved(self, sr: Any) -> None:
        ref = sr.reference
        stamp = int(ref.stamp_ns)
        img = np.asarray(sr.image)
        bic = np.asarray(sr.bicubic)
        self.w.png(f"superres/{stamp}.png", img)
        self.w.png(f"bicubic/{stamp}.png", bic)
        self.w.image("/super_resolved", img, stamp, getattr(ref, "frame_id", ""))
        members = []
        for s, a in getattr(sr, "members", []) or []:
            members.append(
                {"stamp_ns": int(s.stamp_ns), "u_px": rounded(s.u), "v_px": rounded(s.v)}
            )
        self.sets.append(
            {
                "reference_stamp_ns": stamp,
                "frames": 1 + len(members),
                "members": members,
                "method": str(getattr(sr, "method", "")),
                "fell_back": bool(getattr(sr, "fell_back", False)),
                "reason": str(getattr(sr, "reason", "") or ""),
                "blur_sigma": getattr(sr, "blur_sigma", None),
                "blur_source": getattr(sr, "blur_source", None),
                "superres": f"superres/{stamp}.png",
                "bicubic": f"bicubic/{stamp}.png",
                "shape": list(img.shape),
                "dtype": str(img.dtype),
            }
        )
        self.sr_images.append((stamp, img, ref))

    def on_warning(self, item: Any) -> None:
        stage, msg = item if isinstance(item, tuple) else ("", item)
        key = f"{stage}: {reason_key(msg)}" if stage else reason_key(msg)
        with self.lock:  # the mosaic thread warns too
            self.warnings[key] += 1
            self.warning_examples.setdefault(key, f"{stage}: {msg}" if stage else str(msg))

    def on_error(self, err: Any) -> None:
        if isinstance(err, tuple):
            err = f"{err[0]}: {err[1]}"
        text = " ".join(str(err).split())[:200]
        self.errors.append(text)
        rec = self.current
        if rec is not None and rec.status in ("in",):
            rec.status, rec.reason = "dropped", f"stage error: {text}"


def _load_truth(bag: Path) -> tuple[dict[int, tuple[float, float]], np.ndarray | None, int] | None:
    """Rendered ground truth beside the bag (``truth.json`` + ``truth_hr.png``), if any."""
    import json

    import cv2

    d = bag if bag.is_dir() else bag.parent
    tj, th = d / "truth.json", d / "truth_hr.png"
    if not (tj.is_file() and th.is_file()):
        return None
    try:
        truth = json.loads(tj.read_text())
        shifts = {int(f["stamp_ns"]): (float(f["u"]), float(f["v"])) for f in truth["frames"]}
        return shifts, cv2.imread(str(th), cv2.IMREAD_UNCHANGED), int(truth["factor"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


class _Timer:
    """Wall time of every call of a stage's ``add`` (for timing.json: median, p99)."""

    def __init__(self) -> None:
        self.ms: dict[str, list[float]] = {}

    def wrap(self, name: str, obj: Any) -> None:
        add = obj.add
        times = self.ms.setdefault(name, [])

        def timed(*a, **k):
            t0 = time.perf_counter()
            try:
                return add(*a, **k)
            finally:
                times.append(1000.0 * (time.perf_counter() - t0))

        try:
            obj.add = timed
        except (AttributeError, TypeError):
            pass

    def summary(self) -> dict[str, dict[str, float]]:
        out = {}
        for name, v in self.ms.items():
            if v:
                a = np.asarray(v)
                out[name] = {
                    "calls": int(a.size),
                    "median_ms": float(np.median(a)),
                    "p99_ms": float(np.percentile(a, 99)),
                    "max_ms": float(a.max()),
                    "total_s": float(a.sum() / 1000.0),
                }
        return out


def prefetch(events: Iterator, depth: int = 4) -> Iterator:
    """``events`` read (and decoded) on a background thread, up to ``depth`` items ahead, in order.

    Reading the bag and decoding images (JPEG/PNG of a CompressedImage camera) then overlaps
    the stages' work. An exception of the reader (a corrupt bag) is raised here, in order.
    """
    q: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()
    end = object()

    def run() -> None:
        try:
            for ev in events:
                while not stop.is_set():
                    try:
                        q.put((None, ev), timeout=0.1)
                        break
                    except queue.Full:
                        continue
                if stop.is_set():
                    return
            q.put((None, end))
        except BaseException as exc:  # noqa: BLE001 - handed to the consumer
            q.put((exc, None))

    t = threading.Thread(target=run, name="subpix-reader", daemon=True)
    t.start()
    try:
        while True:
            exc, ev = q.get()
            if exc is not None:
                raise exc
            if ev is end:
                return
            yield ev
    finally:
        stop.set()
        t.join(timeout=5.0)


def load_params(path: str | Path | None) -> dict[str, dict]:
    """Stage parameters by node name from a config/*.yaml (``node: ros__parameters: {...}``)."""
    if path is None:
        return {}
    import yaml

    try:
        data = yaml.safe_load(Path(path).read_text()) or {}
    except (OSError, yaml.YAMLError) as exc:
        raise InputError(
            f"cannot read parameters {path}: {' '.join(str(exc).split())[:200]}"
        ) from None
    if not isinstance(data, dict):
        raise InputError(f"parameters {path}: expected a mapping of node names")
    out: dict[str, dict] = {}
    for node, body in data.items():
        if isinstance(body, dict) and "ros__parameters" in body:
            body = body["ros__parameters"]
        if not isinstance(body, dict):
            raise InputError(f"parameters {path}: {node} is not a mapping")
        out[str(node).lstrip("/")] = dict(body)
    return out


# Parameters of the DDS transport only (QoS, queues, publication rate): meaningless in-process.
_TRANSPORT = {"camera_reliable", "queue_size", "publish_rate_hz", "jpeg_quality"}


def pipeline_params(params: dict[str, dict]) -> dict[str, dict]:
    """The stage pipeline's parameters: the four processing nodes, transport keys left out."""
    keep = ("registration_node", "shift_node", "reconstruction_node", "mosaic_node")
    return {n: {k: v for k, v in params.get(n, {}).items() if k not in _TRANSPORT} for n in keep}


def check_params(params: dict[str, dict]) -> None:
    """Raise :class:`InputError` (one line) if a stage rejects a parameter."""
    from subpix_ros.stages import MosaicStage, Pipeline

    pp = pipeline_params(params)
    try:
        Pipeline(pp, with_mosaic=False)
        MosaicStage.from_params(pp["mosaic_node"])
    except (ValueError, TypeError) as exc:
        raise InputError(f"bad parameter: {exc}") from None


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
) -> BagResult:
    """Process one flight bag into ``out_root/<bag name>/``; never raises for bad input.

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
    monitor : subpix_ros.monitor.Monitor, optional
        A started live monitor fed as the bag is processed (``subpix process --serve``).
    progress : callable, optional
        ``progress(frames_done, frames_total)`` after every frame.

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
    if is_complete(final) and not force:
        return BagResult(
            str(bag),
            name,
            "skipped",
            f"{name}: skipped, complete products in {final} (--force redoes)",
            str(final),
        )
    params = params or {}
    try:
        flight = open_flight(bag, camera_topic, telemetry)
        flight.skip_corrupt = skip_corrupt
    except (InputError, BagError) as exc:
        return BagResult(str(bag), name, "failed", f"{name}: failed: {exc}", problems=[str(exc)])
    out_root.mkdir(parents=True, exist_ok=True)
    writer = ProductWriter(out_root, name)
    try:
        res = _run(flight, writer, params, progress, monitor)
        writer.close_bag()  # every queued write done
        res.wall_s = time.monotonic() - t_wall
        timing = res.__dict__.pop("_timing")
        timing.update(
            wall_s=res.wall_s,
            cpu_s=time.process_time() - cpu0,
            realtime_factor=(
                (res.flight_s / res.wall_s) if res.wall_s > 0 and res.flight_s > 0 else None
            ),
            peak_rss_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
        )
        writer.json("timing.json", _clean(timing))
        try:
            from subpix_ros.process.report import write_report

            write_report(writer.tmp)
        except Exception as exc:  # noqa: BLE001 - the products stand without the report
            res.problems.append(f"report not written: {type(exc).__name__}: {exc}")
        res.out = str(writer.commit(force))
        return res
    except KeyboardInterrupt:
        writer.abort()
        raise
    except Exception as exc:  # noqa: BLE001 - one bad bag must not stop the others
        writer.abort()
        text = " ".join(f"{type(exc).__name__}: {exc}".split())[:300]
        return BagResult(str(bag), name, "failed", f"{name}: failed: {text}", problems=[text])


def _run(
    flight: Flight, w: ProductWriter, params: dict[str, dict], progress, monitor: Any = None
) -> BagResult:
    from subpix_ros.stages import MosaicStage, Pipeline

    pparams = pipeline_params(params)
    problems: list[str] = []
    if flight.camera_note:
        problems.append(flight.camera_note)
    if flight.camera_topic is None:
        problems.append(
            f"no images: the bag has no sensor_msgs/Image or CompressedImage topic "
            f"(topics: {', '.join(sorted(flight.topics)) or 'none'})"
        )
    elif flight.frames_total == 0:
        problems.append(f"no images: camera topic {flight.camera_topic} has no messages")
    if not flight.has_telemetry:
        problems.append(
            "no telemetry (no /telemetry/* topics, no .tlog beside the bag"
            + (f": {flight.telemetry_note}" if flight.telemetry_note else "")
            + "): every frame kept, no expected shift, no GPS track"
        )
    elif flight.telemetry_note:
        problems.append(f"telemetry: {flight.telemetry_note}")

    # The mosaic runs beside the pipeline (not inside it) so that a 16-bit flight's frames reach it
    # as 8-bit previews (the core mosaic draws uint8).
    pipe = Pipeline(pparams, with_mosaic=False)
    mosaic = MosaicStage.from_params(pparams["mosaic_node"])
    reg_params = {k: pipe.registration.param(k) for k in EXPECTED_SHIFT_PARAMS}
    col = _Collector(w, reg_params, pipe.registration.stats)
    for kind, cb in (
        ("reference", col.on_reference),
        ("aligned", col.on_aligned),
        ("skipped", col.on_skipped),
        ("shift", col.on_shift),
        ("super_resolved", col.on_super_resolved),
        ("error", col.on_error),
        ("warning", col.on_warning),
    ):
        pipe.on(kind, cb)
    # The mosaic runs on its own thread (it needs nothing from the other stages), frames in order;
    # its problems are warnings: a frame missing from the preview loses no product.
    mosaic.on_problem = lambda level, msg: col.on_warning(("mosaic_node", msg))
    feed = _MonitorFeed(monitor, mosaic) if monitor is not None else None
    if feed is not None:
        pipe.on("shift", feed.shift)
        pipe.on("super_resolved", feed.super_resolved)
    mosaic_pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="subpix-mosaic")
    mosaic_jobs: list[tuple[_FrameRec, Any]] = []

    def mosaic_wait() -> None:
        for r, fut in mosaic_jobs:
            try:
                r.mosaic = bool(fut.result())
            except Exception as exc:  # noqa: BLE001 - the mosaic is a preview: the frame goes on
                r.mosaic = False
                col.on_warning(("mosaic_node", f"{type(exc).__name__}: {exc}"))
        mosaic_jobs.clear()

    timer = _Timer()
    stages = {
        "registration": pipe.registration,
        "shift": pipe.shift,
        "reconstruction": pipe.reconstruction,
        "mosaic": mosaic,
    }
    for sname, obj in stages.items():
        timer.wrap(sname, obj)

    def all_stats() -> dict:
        return {**_pipe_stats(pipe), "mosaic_node": mosaic.stats}

    samples: list[TelemetrySample] = []
    dropped: Counter = Counter()
    examples: dict[str, str] = {}  # the first full reason of each kind
    size: tuple | None = None
    first_ns = last_ns = None
    next_diag = None
    done = 0
    total = flight.frames_total
    status = "ok"
    broke_off = None
    add_ms: list[float] = []
    try:
        for kind, item in prefetch(flight.events()):
            if kind == "telemetry":
                samples.append(item)
                pipe.add_telemetry(item)
                if feed is not None:
                    feed.telemetry(item)
                continue
            done += 1
            if kind == "bad_frame":
                stamp, why = item
                col.frames.append(_FrameRec(len(col.frames), int(stamp), "dropped", why))
                dropped[reason_key(why)] += 1
                examples.setdefault(reason_key(why), why)
            else:
                frame = item
                rec = _FrameRec(len(col.frames), int(frame.stamp_ns))
                col.frames.append(rec)
                shape = (frame.image.shape, str(frame.image.dtype))
                if size is None:
                    size = shape
                    col.dtype = str(frame.image.dtype)
                    col.shape = frame.image.shape[:2]
                if shape != size:
                    rec.status = "dropped"
                    rec.reason = (
                        f"frame size {_shape_text(shape)} differs from the flight's "
                        f"{_shape_text(size)}"
                    )
                    dropped[reason_key(rec.reason)] += 1
                    examples.setdefault(reason_key(rec.reason), rec.reason)
                else:
                    first_ns = rec.stamp_ns if first_ns is None else first_ns
                    last_ns = rec.stamp_ns
                    col.current = rec
                    t0 = time.perf_counter()
                    mosaic_jobs.append((rec, mosaic_pool.submit(mosaic.add, _preview(frame))))
                    try:
                        pipe.add(frame)
                    except Exception as exc:  # noqa: BLE001 - a stage failure drops the frame, not the flight
                        col.on_error(f"{type(exc).__name__}: {exc}")
                    add_ms.append(1000.0 * (time.perf_counter() - t0))
                    if feed is not None:
                        feed.frame(frame, len(mosaic_jobs))
                    if rec.status == "in":
                        rec.status = "dropped" if col.errors else "in"
                    col.current = None
                    if next_diag is None or rec.stamp_ns >= next_diag:
                        next_diag = rec.stamp_ns + DIAGNOSTICS_PERIOD_NS
                        mosaic_wait()  # the figures as of this frame, whatever the threads' timing
                        w.diagnostics(rec.stamp_ns, _diag_statuses(all_stats()))
            if progress is not None:
                progress(done, total)
    except BagError as exc:
        broke_off = str(exc)
        status = "partial"
        problems.append(f"bag breaks off after {done} of {total} frames: {exc}")
    col.current = None
    mosaic_wait()
    mosaic_pool.shutdown(wait=True)
    try:
        pipe.flush()
    except Exception as exc:  # noqa: BLE001
        col.on_error(f"flush: {type(exc).__name__}: {exc}")
    if dropped:
        problems.extend(f"{n} frame(s) dropped: {examples[k]}" for k, n in sorted(dropped.items()))
    if col.errors:
        problems.append(f"{len(col.errors)} stage error(s), last: {col.errors[-1]}")
    if flight.read_report.skipped_records:
        status = "partial"
        problems.append(f"corrupt bag read past its damage: {flight.read_report.summary()}")

    # ---- per-frame products
    buf = TelemetryBuffer(
        max_age_s=1e9, stale_after_s=float(reg_params["telemetry_timeout_s"]), max_samples=10**8
    )
    for s in samples:
        buf.add(s)
    rows = _shift_rows(col, buf, reg_params)
    w.csv("shifts.csv", SHIFT_COLUMNS, rows)
    for rec in col.frames:
        if rec.status == "in":
            rec.status = "kept"
    w.csv("frames.csv", FRAME_COLUMNS, [vars(r) for r in col.frames])
    w.csv("telemetry.csv", TELEMETRY_COLUMNS, [_telemetry_row(s) for s in samples])
    for rec in col.frames:
        if rec.status in ("aligned", "reference", "kept") and samples:
            iv = _interval_at(buf, rec.stamp_ns * 1e-9, reg_params)
            if iv is not None:
                w.frame_interval(rec.stamp_ns, iv)
    mosaic_info = _mosaic(mosaic, w, last_ns)
    if last_ns is not None:
        w.diagnostics(last_ns, _diag_statuses(all_stats()))
    truth = _load_truth(flight.path)
    if truth is not None:
        _score_sets(col, truth)
    st = {
        k: _clean({kk: vv for kk, vv in _stats_dict(v).items() if not _TIME_KEY.search(kk)})
        for k, v in all_stats().items()
    }
    statuses = Counter(r.status for r in col.frames)
    skipped = Counter(reason_key(r.reason) for r in col.frames if r.status == "skipped")
    summary = {
        "bag": flight.name,
        "bag_path": str(flight.path),
        "status": status,
        "problems": problems,
        "camera": {
            "topic": flight.camera_topic,
            "type": flight.camera_type,
            "size": _shape_text(size) if size else None,
            "dtype": col.dtype,
        },
        "telemetry": {
            "source": flight.telemetry_source,
            "samples": len(samples),
            "note": flight.telemetry_note,
        },
        "flight": {
            "first_stamp_ns": first_ns,
            "last_stamp_ns": last_ns,
            "duration_s": (last_ns - first_ns) * 1e-9 if first_ns is not None else 0.0,
        },
        "frames": {
            "in": done,
            "total_in_bag": total,
            "kept": statuses["aligned"] + statuses["reference"] + statuses["kept"],
            "references": statuses["reference"],
            "aligned": statuses["aligned"],
            "skipped": statuses["skipped"],
            "skipped_by_reason": dict(sorted(skipped.items())),
            "dropped": statuses["dropped"],
            "dropped_by_reason": dict(sorted(dropped.items())),
            "shifts": sum(1 for r in rows if r.get("converged")),
            "shifts_not_converged": sum(1 for r in rows if not r.get("converged")),
        },
        "references": col.references,
        "sets": col.sets,
        "mosaic": mosaic_info,
        "stages": st,
        "warnings": {col.warning_examples[k]: n for k, n in sorted(col.warnings.items())},
        "parameters": _clean(pparams),
        "broke_off": broke_off,
    }
    if not col.sets and flight.frames_total:
        problems.append("no super-resolved image: no set reached min_frames")
    if status == "ok" and (not flight.frames_total or dropped or col.errors):
        status = "partial"  # part of the input (or all of it) could not be used
    summary["status"] = status
    w.json("summary.json", _clean(summary))
    flight_s = summary["flight"]["duration_s"]
    line = (
        f"{flight.name}: {status}: {done} frames in, {summary['frames']['kept']} kept, "
        f"{summary['frames']['skipped']} skipped, {summary['frames']['dropped']} dropped, "
        f"{summary['frames']['shifts']} shifts, {len(col.sets)} super-resolved"
    )
    if problems:
        line += f"; {problems[0]}" + (f" (+{len(problems) - 1} more)" if len(problems) > 1 else "")
    res = BagResult(
        str(flight.path),
        flight.name,
        status,
        line,
        frames_in=done,
        flight_s=flight_s,
        problems=problems,
    )
    a = np.asarray(add_ms) if add_ms else np.zeros(0)
    res.__dict__["_timing"] = {
        "frames": int(a.size),
        "frame_ms": {
            "median": float(np.median(a)) if a.size else None,
            "p99": float(np.percentile(a, 99)) if a.size else None,
            "max": float(a.max()) if a.size else None,
        },
        "stages": timer.summary(),
        "stage_stats_ms": {
            k: {kk: vv for kk, vv in _stats_dict(v).items() if _TIME_KEY.search(kk)}
            for k, v in all_stats().items()
        },
        "flight_s": flight_s,
    }
    return res


def _shape_text(shape) -> str:
    dims, dtype = shape
    hw = f"{dims[1]}x{dims[0]}"
    ch = "" if len(dims) == 2 else f"x{dims[2]}"
    return f"{hw}{ch} {dtype}"


class _MonitorFeed:
    """Hands what the bag's pipeline produces to a live :class:`~subpix_ros.monitor.Monitor`.

    The monitor keeps only the newest item per image stream and sends within its link budget, so
    feeding it every frame costs a reference each; the mosaic canvas is drawn once every
    ``MOSAIC_EVERY`` frames.
    """

    MOSAIC_EVERY = 10

    def __init__(self, monitor: Any, mosaic: Any) -> None:
        self.monitor = monitor
        self.mosaic = mosaic

    def frame(self, frame: Any, n: int) -> None:
        self.monitor.on_camera(_to8(frame.image), int(frame.stamp_ns))  # JPEGs are 8-bit
        if n % self.MOSAIC_EVERY == 0:
            canvas = self.mosaic.canvas()
            if canvas is not None:
                self.monitor.on_mosaic(canvas, int(frame.stamp_ns))

    def shift(self, item: Any) -> None:
        s = item[0] if isinstance(item, tuple) else item
        self.monitor.on_shift(int(s.stamp_ns), s.u, s.v, s.u_std, s.v_std, True)

    def super_resolved(self, sr: Any) -> None:
        stamp = int(sr.reference.stamp_ns)
        self.monitor.on_super_resolved(_to8(sr.image), _to8(sr.bicubic), stamp, sr.factor)

    def telemetry(self, s: TelemetrySample) -> None:
        self.monitor.on_fix(s.lat_deg, s.lon_deg, s.alt_msl_m, int(round(s.t * 1e9)))


def _pipe_stats(pipe: Any) -> dict:
    try:
        st = pipe.stats()
    except Exception:  # noqa: BLE001
        return {}
    return dict(st) if isinstance(st, dict) else {}


def _diag_statuses(stats: dict) -> dict[str, tuple[int, str, dict]]:
    out = {}
    for name, st in stats.items():
        d = {k: v for k, v in _stats_dict(st).items() if not _TIME_KEY.search(k)}
        flat = {}
        for k, v in d.items():
            if isinstance(v, dict):
                flat.update({f"{k}.{kk}": vv for kk, vv in v.items()})
            else:
                flat[k] = v
        err = d.get("last_error") or ""
        out[str(name)] = (1 if err else 0, f"last error: {err}" if err else "ok", flat)
    return out


def _image_rate(buf: TelemetryBuffer, t: float, rp: dict) -> tuple[float, float] | None:
    s, _ = buf.at(t + float(rp["telemetry_time_offset_s"]))
    if s is None or s.ground_speed_mps < float(rp["min_speed_mps"]) or s.height_agl_m <= 0:
        return None
    heading = (s.yaw_rad if s.yaw_rad is not None else s.course_rad) + math.radians(
        float(rp["camera_yaw_offset_deg"])
    )
    try:
        return expected_shift_px(
            s.ground_speed_mps,
            s.course_rad,
            s.height_agl_m,
            float(rp["focal_length_mm"]) * 1e-3,
            float(rp["pixel_pitch_um"]) * 1e-6,
            1.0,
            heading,
        )
    except ValueError:
        return None


def _interval_at(buf: TelemetryBuffer, t: float, rp: dict) -> float | None:
    s, _ = buf.at(t + float(rp["telemetry_time_offset_s"]))
    if s is None:
        return None
    iv = frame_interval(
        float(rp["pixel_pitch_um"]) * 1e-6,
        s.height_agl_m,
        float(rp["focal_length_mm"]) * 1e-3,
        s.ground_speed_mps,
        float(rp["p"]),
    )
    return iv.interval_s if iv.ok else None


def _shift_rows(col: _Collector, buf: TelemetryBuffer, rp: dict) -> list[dict]:
    rows = []
    for stamp in sorted(col.shifts):
        row = dict(col.shifts[stamp])
        ref = row.get("reference_stamp_ns")
        h = col.homographies.get(stamp)
        prior = col.priors.get(stamp)
        if h is not None and row.get("converged"):
            total = _total_shift(h, prior, row["u_px"], row["v_px"], col.shape)
            if total is not None:
                row["u_total_px"], row["v_total_px"] = rounded(total[0]), rounded(total[1])
        if ref is not None and len(buf):
            t_ref, t = ref * 1e-9, stamp * 1e-9
            r0, r1 = _image_rate(buf, t_ref, rp), _image_rate(buf, t, rp)
            if (
                r0 is not None and r1 is not None
            ):  # mean image velocity over the interval (trapezoid)
                dt = t - t_ref
                row["u_expected_px"] = rounded(0.5 * (r0[0] + r1[0]) * dt)
                row["v_expected_px"] = rounded(0.5 * (r0[1] + r1[1]) * dt)
                if "u_total_px" in row:  # from the rounded values: the same digits in every process
                    row["u_residual_px"] = rounded(row["u_total_px"] - row["u_expected_px"])
                    row["v_residual_px"] = rounded(row["v_total_px"] - row["v_expected_px"])
        rows.append(row)
    return rows


def _total_shift(h: np.ndarray, prior, u: float, v: float, shape) -> tuple[float, float] | None:
    """Whole-pixel part of the homography's shift plus the estimated sub-pixel part (rows, cols).

    The homography maps moving-frame px to reference px, so the reference's
    centre ``c`` appears at ``H^-1 c`` in the moving frame; the aligned frame
    keeps ``prior`` of that displacement (the sub-pixel remainder), which the
    shift stage measures as (u, v).
    """
    try:
        hi = np.linalg.inv(h)
    except np.linalg.LinAlgError:
        return None
    cy, cx = (shape[0] - 1) / 2.0, (shape[1] - 1) / 2.0
    q = hi @ np.array([cx, cy, 1.0])
    if abs(q[2]) < 1e-12:
        return None
    dx, dy = q[0] / q[2] - cx, q[1] / q[2] - cy
    py, px = prior if prior is not None else (0.0, 0.0)
    return round(dy - py) + u, round(dx - px) + v


def _telemetry_row(s: TelemetrySample) -> dict:
    return {
        "t_s": f"{s.t:.3f}",
        "lat_deg": f"{s.lat_deg:.7f}",
        "lon_deg": f"{s.lon_deg:.7f}",
        "alt_msl_m": s.alt_msl_m,
        "height_agl_m": s.height_agl_m,
        "ground_speed_mps": s.ground_speed_mps,
        "course_deg": math.degrees(s.course_rad),
        "heading_deg": None if s.yaw_rad is None else math.degrees(s.yaw_rad) % 360.0,
    }


def _preview(frame: Any) -> Any:
    """The frame as the mosaic draws it: 8 bit (16-bit frames scaled by 255/65535)."""
    if frame.image.dtype == np.uint8:
        return frame
    from subpix_ros.stages import Frame

    return Frame(frame.stamp_ns, _to8(frame.image), frame.frame_id, frame.received)


def _to8(img: np.ndarray) -> np.ndarray:
    """An image as 8 bit (16-bit values scaled by 255/65535), unchanged if already 8 bit."""
    if img.dtype == np.uint8:
        return img
    return np.clip(np.rint(img.astype(np.float32) * (255.0 / 65535.0)), 0, 255).astype(np.uint8)


def _mosaic(stage: Any, w: ProductWriter, last_ns: int | None) -> dict:
    """mosaic.png and the frame footprints on it (canvas px)."""
    canvas = stage.canvas()
    if canvas is None or getattr(canvas, "size", 0) == 0:
        return {"written": False}
    w.png("mosaic.png", canvas)
    if last_ns is not None:
        w.image("/mosaic", canvas, last_ns, "mosaic")
    info: dict = {
        "written": True,
        "size": [int(canvas.shape[1]), int(canvas.shape[0])],
        "footprints": [],
    }
    core = getattr(stage, "mosaic", None)
    geos = getattr(core, "geometries", None)
    if core is not None and geos is not None:
        for i, g in enumerate(geos):
            if g is None:
                continue
            hh, ww = g.shape
            corners = np.array([[0, 0], [ww - 1, 0], [ww - 1, hh - 1], [0, hh - 1]], np.float64)
            try:
                info["footprints"].append(np.round(core.to_canvas(i, corners), 1).tolist())
            except Exception:  # noqa: BLE001
                continue
    return info


def _score_sets(col: _Collector, truth) -> None:
    """PSNR of each super-resolved image and of the bicubic reference against the rendered truth."""
    from subpix_ros.core.evaluate import gain_over_bicubic, truth_on_grid

    shifts, hr, factor = truth
    if hr is None:
        return
    for entry, (stamp, img, ref) in zip(col.sets, col.sr_images):
        if stamp not in shifts or img.dtype != np.uint8:
            continue
        try:
            truth_k = truth_on_grid(hr, shifts[stamp], factor)
            if truth_k.shape != img.shape[:2]:
                continue
            p_sr, p_bic = gain_over_bicubic(img, ref.image, truth_k, factor, border=24)
        except Exception:  # noqa: BLE001 - scoring is extra information
            continue
        entry.update(psnr_sr_db=p_sr, psnr_bicubic_db=p_bic, gain_db=p_sr - p_bic)
