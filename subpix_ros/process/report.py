"""The flight report: one self-contained ``report.html`` per processed flight.

Built only from the products in the flight's output folder (``summary.json``,
``timing.json``, ``shifts.csv``, ``frames.csv``, ``telemetry.csv``,
``superres/``, ``bicubic/``, ``mosaic.png``), so ``subpix report OUTDIR``
rebuilds it at any time. Every picture is a matplotlib figure embedded as a
base64 PNG (``<img src="data:image/png;base64,...">``): no file beside it,
no script, no network; it opens from a USB stick.

Sections: header (flight, camera, telemetry, frames in / kept / skipped /
dropped by reason, each reason quoted in full from ``frames.csv``, processing time,
problems, the parameters in effect); shift trajectory (measured total shift against the
reference with its standard errors beside the shift expected from telemetry, METHODS eq. 1,
and their residual; frames without a converged shift at the registration's displacement as
hollow markers, ticks on the time axis where they have none either);
registration (inliers and residual along/across the baseline per frame, references started
and why, tracking fallbacks); super-resolution per set (labelled crops of bicubic vs
super-resolved at the same scale, around the set's MTF edge when it has one, PSNR where a
rendered truth exists, the set's fractional shifts on the sub-pixel grid); mosaic with the
frame footprints and the GPS track (the frames' stretch marked); stage times (calls,
median, p99 from 20 calls on) and memory. A panel without data says why; legends sit
beside the plots, never over them.
"""

from __future__ import annotations

import json
from pathlib import Path

from subpix_ros.process.report_html import _CSS, _esc, _num, _plural, _sig, _table
from subpix_ros.process.report_sections import (
    _read_table,
    _section_sets,
    _section_timing,
    missing_note,
    mosaic_section,
    per_frame_sections,
)
from subpix_ros.process.summary import telemetry_clock

__all__ = ["ReportInputError", "build_report", "missing_products", "read_summary", "write_report"]


class ReportInputError(ValueError):
    """A flight folder whose report cannot be built: its ``summary.json`` is missing or unreadable."""


def read_summary(folder: str | Path) -> dict:
    """Return the ``summary.json`` of the flight in ``folder``.

    Parameters
    ----------
    folder : str or Path
        A processed flight's output folder.

    Returns
    -------
    dict
        The flight's summary.

    Raises
    ------
    ReportInputError
        "no summary.json", or "summary.json unreadable (<reason>)" when the file is there but
        cannot be read or parsed (a truncated copy, say) or holds no JSON object.
    """
    path = Path(folder) / "summary.json"
    try:
        summary = json.loads(path.read_text())
    except FileNotFoundError:
        raise ReportInputError("no summary.json") from None
    except OSError as exc:
        raise ReportInputError(f"summary.json unreadable ({exc.strerror or exc})") from None
    except ValueError as exc:  # JSONDecodeError, UnicodeDecodeError
        raise ReportInputError(f"summary.json unreadable ({exc})") from None
    if not isinstance(summary, dict):
        kind = type(summary).__name__
        raise ReportInputError(f"summary.json unreadable (a JSON {kind}, not an object)")
    return summary


def missing_products(folder: str | Path, summary: dict) -> list[str]:
    """Return the products of the run that are not in ``folder`` (moved or deleted since).

    Parameters
    ----------
    folder : str or Path
        A processed flight's output folder.
    summary : dict
        Its ``summary.json`` (:func:`read_summary`): whether the run wrote ``mosaic.png``,
        and each set's ``superres`` and ``bicubic`` PNGs.

    Returns
    -------
    list of str
        The missing files, relative to ``folder``: the tables, ``results.mcap`` and
        ``timing.json`` (:data:`~subpix_ros.process.products.REQUIRED`; ``inputs.json``,
        which only tells the next run whether to redo the flight, is not the report's
        business, nor the report itself, which is being written), then ``mosaic.png`` and the
        sets' PNGs (:func:`~subpix_ros.process.products.listed_images`).
    """
    from subpix_ros.process.products import INPUTS_FILE, REQUIRED, listed_images

    folder = Path(folder)
    names = [n for n in REQUIRED if n not in ("summary.json", INPUTS_FILE, "report.html")]
    names += listed_images(summary)
    return [n for n in names if not (folder / n).is_file()]


def build_report(
    folder: str | Path, crops: dict | None = None, sections: dict[str, str] | None = None
) -> str:
    """Build the report of the flight in ``folder`` (its products) as one HTML string.

    Parameters
    ----------
    folder : str or Path
        A processed flight's output folder (``summary.json`` at least).
    crops : dict, optional
        Per set's ``superres`` path, its :class:`~subpix_ros.process.report_sections.SetCrop`
        (kept by the run that made the set); sets without one are cut from their PNGs.
    sections : dict, optional
        What a helper process drew ahead (:mod:`~subpix_ros.process.report_ahead`) with the
        functions used here: the ``"shifts"`` and ``"registration"`` sections
        (:func:`~subpix_ros.process.report_sections.per_frame_sections`), ``"mosaic"``
        (:func:`~subpix_ros.process.report_sections.mosaic_section`), and
        ``"offsets"``, the sets' offsets figures by
        :func:`~subpix_ros.process.report_sections.offsets_key`; whatever is missing is drawn
        here.

    Returns
    -------
    str
        The self-contained HTML document.

    Raises
    ------
    ReportInputError
        When ``summary.json`` is missing or unreadable (:func:`read_summary`).
    """
    folder = Path(folder)
    summary = read_summary(folder)
    missing = missing_products(folder, summary)
    try:
        timing = json.loads((folder / "timing.json").read_text())
    except (OSError, ValueError):
        timing = {}
    fl = summary.get("flight", {})
    t0 = fl.get("first_stamp_ns")
    t0 = t0 * 1e-9 if t0 is not None else None
    tel = summary.get("telemetry", {})
    factor = int(
        (summary.get("parameters", {}).get("reconstruction_node", {}) or {}).get("factor", 2)
    )
    h = [
        "<!DOCTYPE html><html><head><meta charset='utf-8'>"
        f"<title>Flight report: {_esc(summary.get('bag'))}"
        f"</title><style>{_CSS}</style></head><body>"
    ]
    h.append(f"<h1>Flight report: {_esc(summary.get('bag'))}</h1>")
    h.extend(_header(summary, timing, _read_table(folder, "frames.csv"), missing))
    drawn = dict(sections or {})  # what a helper drew; the rest is drawn here, the same way
    clock = telemetry_clock(summary.get("parameters_in_effect") or {})
    if not (drawn.get("shifts") and drawn.get("registration")):
        drawn.update(
            per_frame_sections(
                folder,
                summary.get("references", []),
                summary.get("stages", {}),
                t0,
                bool(tel.get("samples")),
                clock,
            )
        )
    if not drawn.get("mosaic"):
        drawn.update(mosaic_section(folder, summary.get("mosaic", {}), clock))
    h.append("<h2>Shift trajectory</h2>")
    h.append(drawn["shifts"])
    h.append("<h2>Registration</h2>")
    h.append(drawn["registration"])
    h.append("<h2>Super-resolution</h2>")
    h.append(
        _section_sets(folder, summary.get("sets", []), factor, t0, crops, drawn.get("offsets"))
    )
    h.append("<h2>Mosaic and track</h2>")
    h.append(drawn["mosaic"])
    h.append("<h2>Stage times and memory</h2>")
    h.append(missing_note([n for n in missing if n == "timing.json"], "no stage times to show"))
    h.append(_section_timing(timing))
    h.append("</body></html>\n")
    return "".join(h)


def _processing_time(timing: dict, frames_in: int) -> str:
    """Say the processing's wall time and how it compares with the flight's own duration."""
    text = f"{_num(timing.get('wall_s'), '{:.2f}')} s wall"
    factor = timing.get("realtime_factor")
    if factor:
        pace = (
            "faster than the flight"
            if factor >= 1.0
            else f"slower than the flight: {1.0 / factor:.2g} s of processing per s of flight"
        )
        return text + f" ({_sig(factor, 2)}x real time: {pace})"
    if frames_in == 1:
        return text + " (no real-time factor: a 1-frame flight has zero duration)"
    if frames_in > 1:
        return text + " (no real-time factor: the frames span zero time)"
    return text + " (no flight time: no frames)"


def _frames_text(fr: dict) -> str:
    """Say the frames in, kept (references, aligned), skipped, dropped and the shifts."""
    return (
        f"{fr.get('in', 0)} in, {fr.get('kept', 0)} kept "
        f"({_plural(fr.get('references', 0), 'reference')}, "
        f"{fr.get('aligned', 0)} aligned), "
        f"{fr.get('skipped', 0)} skipped, {fr.get('dropped', 0)} dropped; "
        f"{_plural(fr.get('shifts', 0), 'shift')}"
    )


def _reason_rows(reasons: dict, frames: list[dict], status: str) -> list[list]:
    """Return the rows ``[reason, frames]`` of a by-reason count, each reason in full.

    ``summary.json`` counts reasons of one kind together under a key with its numbers
    masked (``bgr# image data too short: # bytes``); the text shown is the first full reason
    of the group in ``frames.csv`` (an example; "first of n" when the numbers may differ), or
    the one quoted in the problems, never the masked key.
    """
    from subpix_ros.process.collector import reason_key

    first: dict[str, str] = {}
    for r in frames:
        if r.get("status") == status and r.get("reason"):
            first.setdefault(reason_key(r["reason"]), r["reason"])
    rows = []
    for key, n in sorted(reasons.items(), key=lambda kv: (-kv[1], kv[0])):
        example = first.get(key) or first.get(reason_key(key))
        if example is None:  # no row to quote: say where the numbers were, not "#"
            example = key.replace("#", "(n)")
        elif n > 1:
            example = f"{example} (first of {n}; the numbers may differ)"
        rows.append([example, n])
    return rows


def _header(
    summary: dict, timing: dict, frames: list[dict] | None = None, missing: list[str] = ()
) -> list[str]:
    """Build the flight table, problems, frames skipped/dropped by reason, and the parameters.

    ``missing``: the products no longer in the folder (:func:`missing_products`), said beside
    the run's status and first among the problems.
    """
    fl = summary.get("flight", {})
    fr = summary.get("frames", {})
    cam = summary.get("camera", {})
    tel = summary.get("telemetry", {})
    h = []
    h.append(
        _table(
            None,
            [
                ["bag", summary.get("bag_path")],
                [
                    "status",
                    f"{summary.get('status')}"
                    + (
                        f" (the run's; {_plural(len(missing), 'product')} missing since: "
                        "see Problems)"
                        if missing
                        else ""
                    ),
                ],
                [
                    "camera",
                    f"{cam.get('topic') or 'none'} ({cam.get('type') or '-'}), "
                    f"{cam.get('size') or '-'}",
                ],
                [
                    "telemetry",
                    f"{tel.get('source')} ({_plural(tel.get('samples', 0), 'sample')})"
                    + (f": {tel.get('note')}" if tel.get("note") else ""),
                ],
                ["telemetry vs frames", (tel.get("check") or {}).get("note") or "-"],
                [
                    "flight time",
                    f"{fl.get('duration_s', 0):.2f} s"
                    + (" (one frame: no duration)" if fr.get("in") == 1 else ""),
                ],
                ["frames", _frames_text(fr)],
                ["optics blur", (summary.get("blur") or {}).get("note") or "-"],
                ["processing time", _processing_time(timing, int(fr.get("in") or 0))],
            ],
        )
    )
    problems = summary.get("problems") or []
    if missing:
        problems = [
            f"Missing from the flight's folder (moved or deleted after the run): "
            f"{', '.join(missing)}; the sections that show them say so. "
            "`subpix process --force` writes them again.",
            *problems,
        ]
    if problems:
        h.append(
            "<h2>Problems</h2><ul>"
            + "".join(f"<li class='problem'>{_esc(p)}</li>" for p in problems)
            + "</ul>"
        )
    for title, key in (("skipped", "skipped_by_reason"), ("dropped", "dropped_by_reason")):
        reasons = fr.get(key) or {}
        if reasons:
            h.append(
                f"<p>Frames {title} by reason:</p>"
                + _table(["reason (example)", "frames"], _reason_rows(reasons, frames or [], title))
            )
    h.append(_parameters(summary.get("parameters") or {}, summary.get("parameters_in_effect")))
    return h


def _parameters(given: dict[str, dict], in_effect: dict[str, dict] | None = None) -> str:
    """Show the parameters in effect: the stage defaults merged with those given (marked).

    ``summary.json`` records the parameters given (``--params``) and those the run used
    (``parameters_in_effect``); a summary written before the latter was recorded is shown with
    this version's stage defaults for the rest, and says so.
    """
    from subpix_ros.process.params import PROCESS_NODES, pipeline_params, stage_classes

    defaults = pipeline_params(
        {n: {s.name: s.default for s in cls.PARAMS} for n, cls in stage_classes().items()}
    )
    # the values: what the run used where summary.json records it, else this version's defaults
    used = in_effect or defaults
    rows = []
    n_given = 0
    for node in [*PROCESS_NODES, *sorted(set(given) - set(PROCESS_NODES))]:  # pipeline order
        mine, values = given.get(node) or {}, used.get(node, {})
        for k in sorted(set(values) | set(mine)):
            if k in mine:
                n_given += 1
                d = defaults.get(node, {}).get(k)
                note = "given" + (f" (default {json.dumps(d)})" if d is not None else "")
                shown = values.get(k, mine[k]) if in_effect else mine[k]
                rows.append([node, k, json.dumps(shown), note])
            else:
                rows.append([node, k, json.dumps(values[k]), "default"])
    return (
        f"<details><summary>Parameters in effect ({_plural(n_given, 'value')} given, "
        "the rest the stage defaults)</summary>"
        + _table(["stage", "parameter", "value", "from"], rows)
        + (
            "<p>Given: from --params. Default: the stage's own value in the run "
            "(summary.json records both).</p></details>"
            if in_effect
            else "<p>Given: from --params (summary.json records these). Default: the stage's "
            f"default in subpix_ros {_esc(_version())}, which made this report.</p></details>"
        )
    )


def _version() -> str:
    """Return the package's version (the one whose defaults the parameters table shows)."""
    import subpix_ros

    return str(subpix_ros.__version__)


def write_report(
    folder: str | Path, crops: dict | None = None, sections: dict[str, str] | None = None
) -> Path:
    """Write ``folder/report.html`` (atomically; ``crops`` and ``sections`` as in :func:`build_report`)."""
    folder = Path(folder)
    text = build_report(folder, crops, sections)
    tmp = folder / ".report.html.tmp"
    try:
        tmp.write_text(text)
        tmp.replace(folder / "report.html")
    except BaseException:  # a full disk, Ctrl-C: no half-written file left beside the products
        tmp.unlink(missing_ok=True)
        raise
    return folder / "report.html"
