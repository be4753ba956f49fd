"""The content of a processed flight's ``summary.json``: what it lacked, what became of it."""

from __future__ import annotations

import math
from collections import Counter
from typing import TYPE_CHECKING

import numpy as np

from subpix_ros.core.telemetry import TelemetrySample, validate_sample
from subpix_ros.core.timing_check import TelemetryAgreement, what_would_fit
from subpix_ros.process.collector import _TIME_KEY, _clean, _stats_dict, reason_key
from subpix_ros.process.inputs import Flight, no_telemetry_topics
from subpix_ros.process.tables import _shape_text

if TYPE_CHECKING:
    from subpix_ros.process.flight import _FlightRun


def _input_problems(flight: Flight) -> list[str]:
    """List what the flight lacks before any frame is read: images, telemetry."""
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
    if flight.telemetry_unusable:  # a source that is there, but gave nothing
        problems.append(
            f"telemetry unusable: {flight.telemetry_unusable}: every frame kept, no expected "
            "shift, no GPS track"
        )
    elif not flight.has_telemetry:
        problems.append(
            f"no telemetry ({no_telemetry_topics(flight.topics)}; no .tlog beside the bag"
            + (f": {flight.telemetry_note}" if flight.telemetry_note else "")
            + "): every frame kept, no expected shift, no GPS track"
        )
    elif flight.telemetry_note:
        problems.append(f"telemetry: {flight.telemetry_note}")
    return problems


def blur_summary(sets: list[dict]) -> dict:
    """Summarise the optics blur the flight's sets were reconstructed with.

    Parameters
    ----------
    sets : list of dict
        ``summary.json``'s sets (``blur_sigma`` in input px, ``blur_source``, ``blur_reason``).

    Returns
    -------
    dict
        ``sets_by_source`` (sets per source: ``edges``, ``fallback``, ``parameter``),
        ``edges_px`` (the last blur measured on straight edges, input px, or None),
        ``used_px`` ([least, largest] used, or None) and ``note``: one sentence for the
        operator, saying where the blur came from and, when it was measured, that it can be
        given as ``blur_sigma`` for this camera's flights without straight edges.
    """
    solved = [st for st in sets if st.get("blur_sigma") is not None]
    by_source = Counter(str(st.get("blur_source")) for st in solved)
    edges = [st for st in solved if st.get("blur_source") == "edges"]
    used = sorted(float(st["blur_sigma"]) for st in solved)
    measured = float(edges[-1]["blur_sigma"]) if edges else None
    if not solved:
        note = "no set was reconstructed with an optics model"
    elif measured is not None:
        note = (
            f"measured on straight edges ({len(edges)} of {len(solved)} sets): "
            f"{measured:.3f} px, biased low; for this camera's flights without straight edges "
            f"give blur_sigma: {measured:.3f} (it is checked against any edges they have)"
        )
    elif by_source.get("fallback"):
        note = (
            f"no usable straight edge in this flight: {by_source['fallback']} of "
            f"{len(solved)} sets used the fallback {used[0]:.2f} px, safe but a smaller gain "
            "where the camera is blurrier; a blur measured once (subpix blur on photographs "
            "of a slanted-edge target or on a flight over roofs) can be given as blur_sigma"
        )
    else:
        note = f"given as blur_sigma: {used[0]:.3f} px ({solved[-1].get('blur_reason') or 'given'})"
    return {
        "sets_by_source": dict(sorted(by_source.items())),
        "edges_px": measured,
        "used_px": [used[0], used[-1]] if used else None,
        "note": note,
    }


def frames_covered(sample_times, frame_times, offset_s: float, stale_after_s: float) -> np.ndarray:
    """Return which frames fall within the telemetry's time span (bool per frame).

    Parameters
    ----------
    sample_times, frame_times : array-like of float
        The telemetry samples' times and the frames' stamps, s.
    offset_s : float
        ``telemetry_time_offset_s``: a frame's telemetry time is its stamp plus this.
    stale_after_s : float
        ``telemetry_timeout_s``: the newest sample is held this long after it.

    Notes
    -----
    A frame is covered when ``first sample <= stamp + offset_s <= last sample +
    stale_after_s``: the one rule of the flight's problem line (:func:`telemetry_coverage`) and
    of the report's panels.
    """
    f = np.asarray(frame_times, dtype=np.float64) + float(offset_s)
    t = np.asarray(sample_times, dtype=np.float64)
    t = t[np.isfinite(t)]
    if not t.size:
        return np.zeros(f.shape, dtype=bool)
    return (f >= t.min()) & (f <= t.max() + float(stale_after_s))


def telemetry_clock(params: dict) -> tuple[float, float]:
    """Return ``(telemetry_time_offset_s, telemetry_timeout_s)`` from parameters by node.

    ``params`` is ``summary.json``'s ``parameters_in_effect`` (or the run's parameters); the
    registration stage's defaults where it holds none (a summary written before it was kept).
    """
    reg = params.get("registration_node") or {}
    return float(reg.get("telemetry_time_offset_s", 0.0)), float(
        reg.get("telemetry_timeout_s", 1.0)
    )


def telemetry_coverage(
    sample_times: list[float], frame_times: list[float], offset_s: float, stale_after_s: float
) -> str | None:
    """Say when the telemetry's time span leaves frames uncovered (None when it covers them).

    Parameters
    ----------
    sample_times : list of float
        The telemetry samples' times, POSIX s.
    frame_times : list of float
        The frames' stamps, s.
    offset_s : float
        ``telemetry_time_offset_s``: a frame's telemetry time is its stamp plus this.
    stale_after_s : float
        ``telemetry_timeout_s``: the newest sample is held this long after it.

    Returns
    -------
    str or None
        One problem line when no frame, or fewer than all but ``max(2, 10 %)``, falls inside
        ``[first sample, last sample + stale_after_s]``: both spans (UTC) and how far apart
        they are (another clock, e.g. a camera stamping boot time against the autopilot's
        UTC, or another flight's log).
    """
    if not sample_times or not frame_times:
        return None
    t0, t1 = min(sample_times), max(sample_times) + stale_after_s
    ft = [t + offset_s for t in frame_times]
    covered = int(frames_covered(sample_times, frame_times, offset_s, stale_after_s).sum())
    missed = len(ft) - covered
    if covered and missed <= max(2, 0.1 * len(ft)):
        return None
    f0, f1 = min(ft), max(ft)
    gap = t0 - f1 if t0 > f1 else (f0 - t1 if f0 > t1 else 0.0)
    where = (
        f"; the telemetry starts {gap:.1f} s after the last frame"
        if t0 > f1
        else (f"; it ends {gap:.1f} s before the first frame" if f0 > t1 else "")
    )
    return (
        f"telemetry covers {covered} of {len(ft)} frames: its samples span "
        f"{_utc(min(sample_times))} - {_utc(max(sample_times))} UTC, the frames (stamp + "
        f"telemetry_time_offset_s {offset_s:g} s) {_utc(f0)} - {_utc(f1)}{where} (another "
        "clock, or another flight's telemetry?); frames outside it are kept without frame "
        "timing or an expected shift"
    )


def _unusable(sample: TelemetrySample) -> tuple[str, str, float | None] | None:
    """Say why a sample cannot time frames or give an expected shift (None if it can).

    Returns
    -------
    tuple or None
        The kind (``"height"``, ``"velocity"``, ``"invalid"``), what the samples of that kind
        have (with ``{}`` for the value) and the value (None for ``"invalid"``). A hovering
        vehicle's sample is valid (it is said as hovering by the frame selection).
    """
    h = sample.height_agl_m
    if not (math.isfinite(h) and h > 0.0):
        need = "> 0" if math.isfinite(h) else "finite and > 0"
        return "height", f"have height {{}} m (must be {need})", h
    speed = sample.ground_speed_mps
    if not (math.isfinite(speed) and np.all(np.isfinite(sample.vel_ned_mps))):
        return "velocity", "have velocity {} m/s (must be finite)", speed
    ok, why = validate_sample(sample)
    return None if ok else ("invalid", f"are invalid ({why})", None)


def telemetry_unusable(samples: list[TelemetrySample]) -> str | None:
    """Say when the telemetry was read but its samples cannot be used (None when they can).

    Parameters
    ----------
    samples : list of TelemetrySample
        The flight's samples as read (``telemetry.csv``'s rows), valid or not.

    Returns
    -------
    str or None
        One problem line when all samples, or more than ``max(2, 10 %)``, have a height that
        is not finite and > 0, a velocity that is not finite, or fail
        :func:`~subpix_ros.core.telemetry.validate_sample`: how many of how many, of each kind
        (commonest first) with its value (``e.g.`` when the values differ), and what the
        frames lack for it.
    """
    bad = [why for why in map(_unusable, samples) if why is not None]
    if not bad or (len(bad) < len(samples) and len(bad) <= max(2, 0.1 * len(samples))):
        return None
    kinds = Counter(kind for kind, _, _ in bad)
    parts = [_kind_text(kind, bad) for kind, _ in kinds.most_common()]
    whole = len(bad) == len(samples)
    counts = [kinds[kind] for kind, _ in kinds.most_common()]
    said = f"{counts[0]} of {len(samples)} samples {parts[0]}" + "".join(
        f", {n} {part}" for n, part in zip(counts[1:], parts[1:])
    )
    if whole:
        return f"telemetry unusable: {said}: no frame timing or expected shift from it"
    return (
        f"telemetry partly unusable: {said}: the frames at their times have no frame timing "
        "or expected shift"
    )


def _kind_text(kind: str, bad: list[tuple[str, str, float | None]]) -> str:
    """Say what the unusable samples of one kind have, with the first value (e.g. if they differ)."""
    same = [(text, value) for k, text, value in bad if k == kind]
    text, value = same[0]
    if value is None:
        return text
    differ = len({repr(v) for _, v in same}) > 1  # repr: NaN equals NaN
    return text.format(f"e.g. {value:g}" if differ else f"{value:g}")


def time_jumps_back(jumps_ns: list[int]) -> str | None:
    """Say how often the frames' stamps went back in time, and what that did (None if never).

    Parameters
    ----------
    jumps_ns : list of int
        For each frame stamped earlier than the frame before it, by how much, ns.

    Returns
    -------
    str or None
        One problem line: the number of jumps, the largest, that every stage restarted at
        each (reference, tracking, sets, telemetry, mosaic) and the likely cause.
    """
    if not jumps_ns:
        return None
    return (
        f"{len(jumps_ns)} time jump(s) back in the frames' stamps (largest "
        f"{max(jumps_ns) * 1e-9:.3g} s): the pipeline restarted at each (reference, sets and "
        "mosaic begun anew); frames out of order in the bag, or a camera clock that was reset?"
    )


def frame_gaps(stamps_ns: list[int], factor: float = 1.8, min_frames: int = 8) -> str | None:
    """Say where the camera's stream has gaps: frames lost before they reached the bag.

    Parameters
    ----------
    stamps_ns : list of int
        Every frame's stamp in bag order (ns), frames the pipeline left out included.
    factor : float, optional
        An interval longer than ``factor`` times the median interval is a gap.
    min_frames : int, optional
        Fewer frames: nothing said (no stable median interval).

    Returns
    -------
    str or None
        One problem line: the number of gaps, the frames they would have held at the median
        interval, the largest gap, and the likely cause; None without a gap.

    Notes
    -----
    With intervals ``d_i = t_(i+1) - t_i > 0`` and ``m`` their median, a gap is ``d_i > factor
    m`` and is counted as ``round(d_i / m) - 1`` missing frames. Intervals that go back in
    time are :func:`time_jumps_back`'s, not counted here.
    """
    t = np.asarray(stamps_ns, dtype=np.float64)
    if t.size < min_frames:
        return None
    d = np.diff(t)
    d = d[d > 0]
    if d.size < min_frames - 1:
        return None
    m = float(np.median(d))
    gaps = d[d > factor * m]
    if not gaps.size:
        return None
    missing = int(np.sum(np.rint(gaps / m) - 1))
    n = gaps.size
    return (
        f"{n} gap{'s' if n > 1 else ''} in the camera's stream (about {missing} frame"
        f"{'s' if missing != 1 else ''} missing at the median interval {m * 1e-9:.3g} s; largest "
        f"{gaps.max() * 1e-9:.3g} s): frames lost before the bag (camera driver, a recorder or "
        "link that could not keep up)?"
    )


def _utc(t: float) -> str:
    """Format POSIX seconds as ``YYYY-MM-DD HH:MM:SS.s`` (UTC)."""
    import datetime

    d = datetime.datetime.fromtimestamp(t, tz=datetime.timezone.utc)
    return d.strftime("%Y-%m-%d %H:%M:%S.") + f"{d.microsecond // 100000}"


def telemetry_check_summary(check: TelemetryAgreement | None, reg_params: dict) -> dict | None:
    """Summarise the fit of the frames' shifts to the telemetry's (``summary.json``'s check).

    Parameters
    ----------
    check : TelemetryAgreement or None
        :func:`~subpix_ros.process.tables.telemetry_check` (None: the flight has no telemetry).
    reg_params : dict
        The registration stage's ``focal_length_mm``, ``pixel_pitch_um`` and
        ``camera_yaw_offset_deg`` the expected shifts were made with.

    Returns
    -------
    dict or None
        The fit's figures, ``agrees`` (True, False or None: not enough to tell) and ``note``:
        one sentence for the operator; when they disagree, which parameter would fit the frames
        (the focal length in pixels ``k f / a`` they imply, e.g. the pixel pitch ``a / k``; the
        yaw offset plus the rotation).
    """
    if check is None:
        return None
    out = {k: v for k, v in vars(check).items() if k not in ("reason",)}
    note = check.reason
    if check.agrees is False:
        advice = what_would_fit(
            check,
            float(reg_params["focal_length_mm"]),
            float(reg_params["pixel_pitch_um"]),
            float(reg_params["camera_yaw_offset_deg"]),
        )
        note = f"telemetry {check.reason}: {advice}"
    out["note"] = note
    return out


def _stage_stats(run: _FlightRun) -> dict:
    """Each stage's statistics as ``summary.json`` has them (no timing keys)."""
    return {
        k: _clean({kk: vv for kk, vv in _stats_dict(v).items() if not _TIME_KEY.search(kk)})
        for k, v in run.all_stats().items()
    }


def _in_effect(run: _FlightRun) -> dict[str, dict]:
    """Every stage's parameters as the run used them (the defaults and those given), by node."""
    stages = {**run.pipe.stages(), "mosaic_node": run.mosaic}
    out = {}
    for name, stage in stages.items():
        params = getattr(stage, "params", None)
        if isinstance(params, dict):
            out[name] = _clean({**params, **getattr(stage, "extra", {})})
    return out


def _summary(run: _FlightRun, mosaic_info: dict) -> dict:
    """Build the content of ``summary.json`` (its final ``status`` is set by the caller)."""
    flight, collector, rows = run.flight, run.collector, run.rows
    stage_stats = _stage_stats(run)
    statuses = Counter(r.status for r in collector.frames)
    skipped = Counter(reason_key(r.reason) for r in collector.frames if r.status == "skipped")
    first_ns, last_ns = run.first_ns, run.last_ns
    return {
        "bag": flight.name,
        "bag_path": str(flight.path),
        "status": run.status,
        "problems": run.problems,
        "camera": {
            "topic": flight.camera_topic,
            "type": flight.camera_type,
            "size": _shape_text(run.size) if run.size else None,
            "dtype": collector.dtype,
        },
        "telemetry": {
            "source": flight.telemetry_source,
            "samples": len(run.samples),
            "note": flight.telemetry_unusable or flight.telemetry_note,
            "check": telemetry_check_summary(run.telemetry_check, run.reg_params),
        },
        "flight": {
            "first_stamp_ns": first_ns,
            "last_stamp_ns": last_ns,
            "duration_s": (last_ns - first_ns) * 1e-9 if first_ns is not None else 0.0,
        },
        "frames": {
            "in": run.done,
            "total_in_bag": run.total,
            "kept": statuses["aligned"] + statuses["reference"] + statuses["kept"],
            "references": statuses["reference"],
            "aligned": statuses["aligned"],
            "skipped": statuses["skipped"],
            "skipped_by_reason": dict(sorted(skipped.items())),
            "dropped": statuses["dropped"],
            "dropped_by_reason": dict(sorted(run.dropped.items())),
            "shifts": sum(1 for r in rows if r.get("converged")),
            "shifts_not_converged": sum(1 for r in rows if not r.get("converged")),
        },
        "references": collector.references,
        "sets": collector.sets,
        "blur": blur_summary(collector.sets),
        "mosaic": mosaic_info,
        "stages": stage_stats,
        "warnings": {
            collector.warning_examples[k]: n for k, n in sorted(collector.warnings.items())
        },
        "parameters": _clean(run.pparams),
        "parameters_in_effect": _in_effect(run),
        "broke_off": run.broke_off,
    }
