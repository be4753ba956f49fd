"""The flight report: one self-contained ``report.html`` per processed flight.

Built only from the products in the flight's output folder (``summary.json``,
``timing.json``, ``shifts.csv``, ``frames.csv``, ``telemetry.csv``,
``superres/``, ``bicubic/``, ``mosaic.png``), so ``subpix report OUTDIR``
rebuilds it at any time. Every picture is a matplotlib figure embedded as a
base64 PNG (``<img src="data:image/png;base64,...">``): no file beside it,
no script, no network; it opens from a USB stick.

Sections: header (flight, camera, telemetry, frames in / kept / skipped /
dropped by reason, processing time, problems, parameters); shift trajectory
(measured total shift against the reference with its standard errors beside
the shift expected from telemetry, METHODS eq. 1, and their residual);
registration (inliers and residual along/across the baseline per frame,
references started and why, tracking fallbacks); super-resolution per set
(labelled crops of bicubic vs super-resolved at the same scale, PSNR where a
rendered truth exists, the set's fractional shifts on the sub-pixel grid);
mosaic with the frame footprints and the GPS track; stage times (median,
p99) and memory.
"""

from __future__ import annotations

import json
from pathlib import Path

from subpix_ros.process.report_html import _CSS, _esc, _num, _table
from subpix_ros.process.report_sections import (
    _section_sets,
    _section_timing,
    mosaic_section,
    per_frame_sections,
)

__all__ = ["build_report", "write_report"]


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
    """
    folder = Path(folder)
    summary = json.loads((folder / "summary.json").read_text())
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
    h.extend(_header(summary, timing))
    drawn = dict(sections or {})  # what a helper drew; the rest is drawn here, the same way
    if not (drawn.get("shifts") and drawn.get("registration")):
        drawn.update(
            per_frame_sections(
                folder,
                summary.get("references", []),
                summary.get("stages", {}),
                t0,
                bool(tel.get("samples")),
            )
        )
    if not drawn.get("mosaic"):
        drawn.update(mosaic_section(folder, summary.get("mosaic", {})))
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
    h.append(_section_timing(timing))
    h.append("</body></html>\n")
    return "".join(h)


def _header(summary: dict, timing: dict) -> list[str]:
    """Build the flight table, problems, frames skipped/dropped by reason, and the parameters."""
    fl = summary.get("flight", {})
    fr = summary.get("frames", {})
    cam = summary.get("camera", {})
    tel = summary.get("telemetry", {})
    h = []
    h.append(
        _table(
            ["", ""],
            [
                ["bag", summary.get("bag_path")],
                ["status", summary.get("status")],
                [
                    "camera",
                    f"{cam.get('topic') or 'none'} ({cam.get('type') or '-'}), "
                    f"{cam.get('size') or '-'}",
                ],
                [
                    "telemetry",
                    f"{tel.get('source')} ({tel.get('samples', 0)} samples)"
                    + (f": {tel.get('note')}" if tel.get("note") else ""),
                ],
                ["telemetry vs frames", (tel.get("check") or {}).get("note") or "-"],
                ["flight time", f"{fl.get('duration_s', 0):.2f} s"],
                [
                    "frames",
                    f"{fr.get('in', 0)} in, {fr.get('kept', 0)} kept "
                    f"({fr.get('references', 0)} references, {fr.get('aligned', 0)} aligned), "
                    f"{fr.get('skipped', 0)} skipped, {fr.get('dropped', 0)} dropped; "
                    f"{fr.get('shifts', 0)} shifts",
                ],
                ["optics blur", (summary.get("blur") or {}).get("note") or "-"],
                [
                    "processing time",
                    f"{_num(timing.get('wall_s'), '{:.2f}')} s wall"
                    + (
                        f" ({timing['realtime_factor']:.2f}x real time)"
                        if timing.get("realtime_factor")
                        else " (no flight time: no frames)"
                    ),
                ],
            ],
        )
    )
    problems = summary.get("problems") or []
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
                + _table(
                    ["reason", "frames"],
                    sorted(([k, v] for k, v in reasons.items()), key=lambda x: -x[1]),
                )
            )
    h.append(
        "<details><summary>Parameters</summary>"
        + _table(
            ["stage", "parameter", "value"],
            [
                [n, k, json.dumps(v)]
                for n, ps in sorted(summary.get("parameters", {}).items())
                for k, v in sorted(ps.items())
            ],
        )
        + "<p>Parameters not listed take the stage defaults.</p></details>"
    )
    return h


def write_report(
    folder: str | Path, crops: dict | None = None, sections: dict[str, str] | None = None
) -> Path:
    """Write ``folder/report.html`` (atomically; ``crops`` and ``sections`` as in :func:`build_report`)."""
    folder = Path(folder)
    text = build_report(folder, crops, sections)
    tmp = folder / ".report.html.tmp"
    tmp.write_text(text)
    tmp.replace(folder / "report.html")
    return folder / "report.html"
