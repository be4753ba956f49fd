"""What the flight report says and draws, read from its HTML and its figures' data.

The figures are taken before they become PNGs (``_img`` replaced by a recorder) and read as
matplotlib objects: which series are drawn where, the legends, the sentences in the panels.
Small synthetic tables, no bag: fast.
"""

from __future__ import annotations

import csv
import re
from pathlib import Path

import numpy as np
import pytest

from subpix_ros.process import report, report_sections
from subpix_ros.process.report_html import _plural, _sig, _table

T0_NS = 1_000_000_000_000_000_000


@pytest.fixture
def figures(monkeypatch):
    """Record the figures the sections draw (drawn once, as in the report), not encoded."""
    got = []

    def record(fig, alt, vector=False):
        fig.canvas.draw()
        got.append(fig)
        return f'<img alt="{alt}">'

    monkeypatch.setattr(report_sections, "_img", record)
    yield got
    import matplotlib.pyplot as plt

    for fig in got:
        plt.close(fig)


def _write_csv(path: Path, rows: list[dict]) -> None:
    keys = sorted({k for r in rows for k in r}) if rows else ["stamp_ns"]
    with path.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        w.writerows(rows)


def _no_shift_rows() -> list[dict]:
    """shifts.csv of the seneca sample: no shift converged, ~800 px expected."""
    rows = []
    for k, exp in enumerate((None, 805.0, 740.2, 839.6)):
        stamp = T0_NS + (4 + 10 * k) * 10**9
        rows.append(
            {
                "stamp_ns": str(stamp),
                "reference_stamp_ns": str(stamp - 4 * 10**9),
                "converged": "0",
                "reason": "failed: Gauss-Newton did not converge (last step 0.558 px)",
                "u_expected_px": "" if exp is None else str(exp),
                "v_expected_px": "" if exp is None else "-5.8",
            }
        )
    return rows


def _converged_rows(n: int = 8, expected: bool = True) -> list[dict]:
    rows = []
    for k in range(n):
        u, v = 0.4 * (k % 4) + 0.4, 0.27 * (k % 4) + 0.3
        row = {
            "stamp_ns": str(T0_NS + 33_333_333 * (k + 1)),
            "reference_stamp_ns": str(T0_NS + 133_333_332 * (k // 4)),
            "converged": "1",
            "u_total_px": f"{u + 1e-4:.5f}",
            "v_total_px": f"{v - 3e-4:.5f}",
            "u_std_px": "0.0003",
            "v_std_px": "0.0003",
        }
        if expected:
            row.update(
                u_expected_px=f"{u:.5f}",
                v_expected_px=f"{v:.5f}",
                u_residual_px="0.00010",
                v_residual_px="-0.00034",
            )
        rows.append(row)
    return rows


def _legend_labels(fig) -> list[str]:
    legends = list(fig.legends) + [ax.get_legend() for ax in fig.axes if ax.get_legend()]
    return [t.get_text() for lg in legends for t in lg.get_texts()]


def _texts(ax) -> str:
    return " ".join([t.get_text() for t in ax.texts] + [ax.get_title(), ax.get_title("left")])


# --- 1. a flight where no shift converged ---------------------------------------------------


def test_frames_without_a_shift_are_not_drawn_as_measured_zeros(figures):
    html = report_sections._section_shifts(_no_shift_rows(), T0_NS * 1e-9, True)
    top, bottom = figures[0].axes
    labels = _legend_labels(figures[0])
    # no legend entry for a series with no point (nothing was measured)
    assert not any("measured" in lab for lab in labels), labels
    assert any("expected" in lab for lab in labels)
    marks = [ln for ln in top.get_lines() if "without a converged shift" in ln.get_label()]
    assert len(marks) == 1
    # ticks on the time axis (y in axes fraction), not points at 0 px in the data
    assert marks[0].get_transform() != top.transData
    assert list(marks[0].get_xdata()) == pytest.approx([4, 14, 24, 34])
    assert not top.containers  # no error bars: no measured point
    # the empty residual panel says why
    assert "no converged shift" in _texts(bottom)
    assert "0 of 4 aligned frames have a converged shift" in html


def test_frames_without_a_shift_are_drawn_at_the_registrations_displacement(figures):
    """Registration measured the motion: hollow markers there, ticks only for the rest."""
    rows = _no_shift_rows()
    registered = {4: (776.0185721, -30.47822581), 14: (749.304175, -109.4162714)}
    for r in rows:
        at = round((int(r["stamp_ns"]) - T0_NS) * 1e-9)
        if at in registered:
            r.update(
                u_registration_px=str(registered[at][0]), v_registration_px=str(registered[at][1])
            )
    stamp = T0_NS + 44 * 10**9  # a converged frame: a measured point, not a hollow marker
    rows.append(
        {
            "stamp_ns": str(stamp),
            "reference_stamp_ns": str(stamp - 4 * 10**9),
            "converged": "1",
            "u_total_px": "801.4",
            "v_total_px": "-6.3",
            "u_std_px": "0.01",
            "v_std_px": "0.01",
            "u_registration_px": "801.1",
            "v_registration_px": "-6.1",
        }
    )
    html = report_sections._section_shifts(rows, T0_NS * 1e-9, True)
    top, _ = figures[0].axes
    for k, key in enumerate(("u (rows)", "v (columns)")):
        label = f"{key} registration only (no sub-pixel shift)"
        assert label in _legend_labels(figures[0])
        (line,) = [ln for ln in top.get_lines() if ln.get_label() == label]
        assert line.get_transform() == top.transData  # at the displacement, in px
        assert list(line.get_xdata()) == pytest.approx([4, 14])
        assert list(line.get_ydata()) == pytest.approx([registered[4][k], registered[14][k]])
        assert line.get_marker() == "o" and line.get_markerfacecolor() == "none"  # hollow
    ticks = [ln for ln in top.get_lines() if "without a converged shift" in ln.get_label()]
    assert len(ticks) == 1 and list(ticks[0].get_xdata()) == pytest.approx([24, 34])
    assert "1 of 5 aligned frames have a converged shift" in html
    assert "2 frames without a converged shift are drawn at the registration's" in html
    assert "(hollow markers: whole-frame motion, no sub-pixel shift, no residual)" in html


def test_a_flight_where_every_shift_failed_shows_the_registrations_motion(figures):
    """No sub-pixel shift, no telemetry: the frames' motion is still drawn, not ticks."""
    rows = _no_shift_rows()
    for k, r in enumerate(rows):
        r.update(u_expected_px="", v_expected_px="")
        r.update(u_registration_px=str(700.0 + k), v_registration_px=str(-30.0 * k))
    report_sections._section_shifts(rows, T0_NS * 1e-9, False)
    top, _ = figures[0].axes
    assert "no value to draw" not in _texts(top)
    assert "hollow markers: the registration's displacement" in _texts(top)
    assert not [ln for ln in top.get_lines() if "without a converged shift" in ln.get_label()]
    (u,) = [ln for ln in top.get_lines() if ln.get_label().startswith("u (rows) registration")]
    assert list(u.get_ydata()) == pytest.approx([700.0, 701.0, 702.0, 703.0])


def test_a_panel_without_data_says_why_and_shows_no_value_axis(figures):
    rows = [dict(r, u_expected_px="", v_expected_px="") for r in _no_shift_rows()]
    report_sections._section_shifts(rows, T0_NS * 1e-9, False)
    top, bottom = figures[0].axes
    assert "no value to draw" in _texts(top) and len(top.get_yticks()) == 0
    assert "no telemetry" in _texts(bottom) and len(bottom.get_yticks()) == 0


# --- 2. telemetry that does not cover the frames' times ------------------------------------


def _flight_tables(folder: Path, shifts: list[dict], tel_offset_s: float) -> None:
    _write_csv(folder / "shifts.csv", shifts)
    frames = [
        {
            "index": "0",
            "stamp_ns": str(T0_NS),
            "status": "reference",
            "reason": "first frame",
            "reference_stamp_ns": str(T0_NS),
        }
    ] + [
        {
            "index": str(k + 1),
            "stamp_ns": r["stamp_ns"],
            "status": "aligned",
            "reference_stamp_ns": r["reference_stamp_ns"],
            "inliers": "700",
            "rms_px": "0.01",
            "rms_along_px": "0.012",
            "rms_cross_px": "0.007",
            "tracked": "1",
        }
        for k, r in enumerate(shifts)
    ]
    _write_csv(folder / "frames.csv", frames)
    tel = [
        {
            "t_s": f"{T0_NS * 1e-9 + tel_offset_s + 0.1 * k:.3f}",
            "lat_deg": f"{41.0 + 1e-6 * k:.7f}",
            "lon_deg": f"{-83.0 + 1e-6 * k:.7f}",
        }
        for k, _ in enumerate(range(28))
    ]
    _write_csv(folder / "telemetry.csv", tel)


def test_telemetry_beside_the_frames_times_is_said_so_not_no_telemetry(tmp_path, figures):
    shifts = _converged_rows(expected=False)
    _flight_tables(tmp_path, shifts, 3600.0)
    report_sections.per_frame_sections(tmp_path, [], {}, T0_NS * 1e-9, True)
    bottom = figures[0].axes[1]
    said = _texts(bottom)
    assert "telemetry does not cover the frames' times" in said, said
    assert "no telemetry" not in said


def test_the_gps_track_marks_the_frames_or_says_none_falls_on_it(tmp_path, figures):
    shifts = _converged_rows()
    _flight_tables(tmp_path, shifts, -0.5)  # the track covers the frames
    html = report_sections.mosaic_section(tmp_path, {"written": False})["mosaic"]
    ax = figures[-1].axes[0]
    labels = [ln.get_label() for ln in ax.get_lines()]
    assert "while frames were taken" in labels and "frame positions" in labels
    dots = next(ln for ln in ax.get_lines() if ln.get_label() == "frame positions")
    assert len(dots.get_xdata()) == len(shifts) + 1  # every frame (the reference too)
    assert "no frame" not in html

    _flight_tables(tmp_path, shifts, 3600.0)
    html = report_sections.mosaic_section(tmp_path, {"written": False})["mosaic"]
    ax = figures[-1].axes[0]
    assert "frame positions" not in [ln.get_label() for ln in ax.get_lines()]
    assert "no frame was taken within the GPS track's time" in _texts(ax)
    assert "no frame was taken within the GPS track's time" in html


# --- 3, 4. legends beside the data, labels inside the figure ---------------------------------


def _overlaps(a, b) -> bool:
    return a.x0 < b.x1 and b.x0 < a.x1 and a.y0 < b.y1 and b.y0 < a.y1


@pytest.mark.parametrize("which", ["shifts", "registration"])
def test_legends_cover_no_data_and_labels_fit(tmp_path, figures, which):
    shifts = _converged_rows()
    for k, r in enumerate(shifts):  # wide tick labels on the residual axis (-0.0015)
        r["u_residual_px"] = f"{-0.0011 + 0.00025 * k:.5f}"
    _flight_tables(tmp_path, shifts, -0.5)
    report_sections.per_frame_sections(tmp_path, [], {}, T0_NS * 1e-9, True)
    fig = figures[0 if which == "shifts" else 1]
    renderer = fig.canvas.get_renderer()
    width, height = fig.canvas.get_width_height()
    legends = list(fig.legends) + [ax.get_legend() for ax in fig.axes if ax.get_legend()]
    assert legends
    for lg in legends:
        box = lg.get_window_extent(renderer)
        assert not any(_overlaps(box, ax.get_window_extent(renderer)) for ax in fig.axes)
    for ax in fig.axes:
        lo, hi = sorted(ax.get_ylim())
        shown = [t.label1 for t in ax.yaxis.get_major_ticks() if lo <= t.get_loc() <= hi]
        for text in [ax.yaxis.label, ax.xaxis.label, *shown]:
            if text.get_text():
                box = text.get_window_extent(renderer)
                assert box.x0 >= 0 and box.x1 <= width and box.y0 >= 0 and box.y1 <= height, (
                    text.get_text()
                )


# --- 5. reasons shown in full ---------------------------------------------------------------


def test_dropped_reasons_are_shown_in_full_never_masked():
    frames = [
        {
            "status": "dropped",
            "reason": "undecodable image: bgr8 image data too short: 301056 bytes",
        },
        {"status": "dropped", "reason": "undecodable image: bgr8 image data too short: 9 bytes"},
        {"status": "dropped", "reason": "unknown image encoding 'yuv422_weird'"},
    ]
    reasons = {
        "undecodable image: bgr# image data too short: # bytes": 2,
        "unknown image encoding 'yuv#_weird'": 1,
        "a reason no row quotes: # bytes": 1,
    }
    rows = report._reason_rows(reasons, frames, "dropped")
    text = " ".join(str(c) for r in rows for c in r)
    assert "#" not in text
    assert [r[1] for r in rows] == [2, 1, 1]
    assert rows[0][0].startswith("undecodable image: bgr8 image data too short: 301056 bytes")
    assert "first of 2" in rows[0][0]
    assert "'yuv422_weird'" in text


# --- 6, 8. registration: lines, markers, fallbacks --------------------------------------------


def test_registration_lines_break_at_references_and_drops_and_fallbacks_agree(figures):
    frames = [{"status": "reference", "stamp_ns": str(T0_NS), "reference_stamp_ns": str(T0_NS)}]
    ref2 = T0_NS + 4 * 10**8
    for k in range(1, 9):
        stamp = T0_NS + k * 10**8
        status = "reference" if stamp == ref2 else ("dropped" if k == 6 else "aligned")
        frames.append(
            {
                "index": str(k),
                "stamp_ns": str(stamp),
                "status": status,
                "reference_stamp_ns": str(T0_NS if stamp < ref2 else ref2),
                "inliers": str(700 + k),
                "rms_px": "0.01",
                "rms_along_px": "" if k in (1, 5) else "0.012",  # baseline < 1 px
                "rms_cross_px": "" if k in (1, 5) else "0.007",
                "tracked": "0" if k in (2, 7) else "1",
            }
        )
    refs = [{"stamp_ns": T0_NS, "reason": "first frame"}, {"stamp_ns": ref2, "reason": "x"}]
    stages = {
        "registration_node": {
            "fallbacks": 3,
            "last_tracking_fallback": "tracking lost: 10 of 548 tie points consistent",
        }
    }
    html = report_sections._section_registration(frames, refs, stages, T0_NS * 1e-9)
    top, bottom = figures[0].axes
    inliers = top.get_lines()[0]
    y = np.asarray(inliers.get_ydata(), dtype=float)
    # aligned: 1 2 3 | (reference 4) 5 | (dropped 6) 7 8: two breaks
    assert np.isnan(y).sum() == 2 and inliers.get_marker() == "o"
    assert all(ln.get_marker() not in (None, "", "None") for ln in bottom.get_lines()[:3])
    assert "at least 1 px" in html
    assert "Tracking fallbacks: 3. 2 drawn" in html
    assert "1 on a frame that then failed to register or started a new reference" in html
    assert "tracking lost: 10 of 548 tie points consistent" in html
    dashed = [ln for ln in top.get_lines() if ln.get_linestyle() == "--"]
    assert len(dashed) == 2
    assert "2 references started" in html


# --- 7. crops ---------------------------------------------------------------------------------


def test_crop_caption_gives_rows_and_columns_and_shows_the_mtf_edge(tmp_path):
    rng = np.random.default_rng(3)
    img = rng.integers(0, 256, (600, 600, 3), dtype=np.uint8)
    roi = [200, 230, 64, 26]  # x, y, w, h in input px (factor 2: output 400.., 460..)
    entry = {
        "reference_stamp_ns": T0_NS,
        "frames": 8,
        "method": "map",
        "superres": "superres/1.png",
        "bicubic": "bicubic/1.png",
        "members": [],
        "edges": [
            {
                "roi": roi,
                "angle_deg": 5.0,
                "mtf50_bicubic": 0.3,
                "mtf50_sr": 0.6,
                "mtf30_bicubic": 0.4,
                "mtf30_sr": 0.7,
            }
        ],
    }
    import cv2

    (tmp_path / "superres").mkdir()
    (tmp_path / "bicubic").mkdir()
    cv2.imwrite(str(tmp_path / "superres/1.png"), img)
    cv2.imwrite(str(tmp_path / "bicubic/1.png"), img)
    kept = report_sections.SetCrop(0, 0, 192, img[:192, :192], img[:192, :192])  # elsewhere
    html = report_sections._section_sets(
        tmp_path, [entry], 2, T0_NS * 1e-9, {entry["superres"]: kept}
    )
    m = re.search(r"output px rows (\d+)\.\.(\d+), columns (\d+)\.\.(\d+)", html)
    assert m, html[:200]
    r0, r1, c0, c1 = map(int, m.groups())
    assert r0 <= 460 and 460 + 52 <= r1 and c0 <= 400 and 400 + 128 <= c1
    assert r1 - r0 == c1 - c0 == 192  # the crops' usual side: the same scale as other sets
    assert html.count('class="roi"') == 2  # outlined on both images
    assert "the edge measured for the MTF (rows 460..512, columns 400..528)" in html
    assert "MTF at 1 straight edge of the scene" in html


# --- 9. parameters in effect ------------------------------------------------------------------


def test_parameters_table_shows_the_values_in_effect_and_marks_the_given_ones():
    html = report._parameters({"registration_node": {"focal_length_mm": 4.3, "p": 3.0}})
    rows = re.findall(r"<tr><td>(.*?)</td><td>(.*?)</td><td>(.*?)</td><td>(.*?)</td></tr>", html)
    by = {(r[0], r[1]): (r[2], r[3]) for r in rows}
    assert by[("registration_node", "pixel_pitch_um")] == ("1.54", "default")
    assert by[("registration_node", "p")] == ("3.0", "given (default 2.0)")
    assert ("reconstruction_node", "factor") in by and ("shift_node", "max_std_px") in by
    assert not any(k == "max_cpu_cores" or k == "queue_size" for _, k in by)  # not in effect
    assert "2 values given" in html
    assert "pixel_pitch_um" in report._parameters({})


def test_parameters_table_shows_what_the_run_recorded_not_todays_defaults():
    """summary.json's parameters_in_effect: a report drawn by another version shows the run's."""
    used = {"registration_node": {"p": 3.0, "max_frames_per_reference": 11, "tracking": True}}
    html = report._parameters({"registration_node": {"p": 3.0}}, used)
    rows = re.findall(r"<tr><td>(.*?)</td><td>(.*?)</td><td>(.*?)</td><td>(.*?)</td></tr>", html)
    by = {(r[0], r[1]): (r[2], r[3]) for r in rows}
    assert by[("registration_node", "max_frames_per_reference")] == ("11", "default")
    assert by[("registration_node", "p")] == ("3.0", "given (default 2.0)")
    assert "the stage's own value in the run" in html


# --- 10. stage times --------------------------------------------------------------------------


def test_stage_times_include_the_mosaic_and_no_p99_from_few_calls():
    timing = {
        "stages": {
            "registration": {"calls": 24, "median_ms": 70.0, "p99_ms": 260.0, "max_ms": 300.0},
            "reconstruction": {"calls": 3, "median_ms": 300.0, "p99_ms": 350.0, "max_ms": 416},
        },
        "stage_stats_ms": {"mosaic_node": {"times": {"n": 9, "p50": 112.7, "max": 198.0}}},
        "frames": 24,
        "frame_ms": {"median": 96.0, "p99": 317.4, "max": 355.9},
    }
    html = report_sections._section_timing(timing)
    rows = [re.findall(r"<td>(.*?)</td>", r) for r in re.findall(r"<tr>(<td>.*?)</tr>", html)]
    cells = {r[0]: r for r in rows}
    assert cells["mosaic (own thread)"][1:3] == ["9", "112.7"]
    assert cells["mosaic (own thread)"][3].startswith("n too small")
    assert cells["reconstruction"][3].startswith("n too small") and "350" not in html
    assert cells["registration"][3] == "260.0"


# --- 11. numbers and words --------------------------------------------------------------------


def test_small_values_keep_significant_digits_and_counts_their_number():
    assert _sig(0.00034) == "0.000340" and _sig(0.0123) == "0.0123" and _sig(12.345) == "12.3"
    assert _sig(0) == "0" and _sig(None) == "n/a"
    assert _plural(1, "reference") == "1 reference" and _plural(3, "shift") == "3 shifts"
    assert "<th>" not in _table(None, [["bag", "x"]])


def test_header_words_one_frame_and_real_time():
    summary = {
        "flight": {"duration_s": 0.0},
        "frames": {"in": 1, "kept": 1, "references": 1, "aligned": 0, "shifts": 1},
        "telemetry": {"source": "topics", "samples": 1},
    }
    text = "".join(report._header(summary, {"wall_s": 0.5}))
    assert "1 reference," in text and "1 shift<" in text and "1 sample)" in text
    assert "a 1-frame flight has zero duration" in text and "no frames" not in text
    assert "<tr><th></th>" not in text
    text = "".join(report._header(summary, {"wall_s": 2.0, "realtime_factor": 0.28}))
    assert "0.28x real time: slower than the flight" in text


def test_shift_residual_rms_is_never_rounded_to_zero(figures):
    html = report_sections._section_shifts(_converged_rows(), T0_NS * 1e-9, True)
    assert "RMS u 0.000100 px, v 0.000340 px over 8 frames" in html


def test_a_long_edge_keeps_the_crops_scale_and_is_outlined_in_part():
    img = np.zeros((600, 600), dtype=np.uint8)
    crop = report_sections.edge_crop(img, img, 2, [20, 100, 150, 20])  # 300 output px long
    assert crop.side == 192 and crop.bicubic.shape == (192, 192)
    box, said = report_sections._edge_outline(crop, [{"roi": [20, 100, 150, 20]}], 2, 2)
    assert box is not None and box[3] == 192 * 2 and "in part beyond the crop" in said
    _, said = report_sections._edge_outline(crop, [{"roi": [250, 250, 20, 20]}], 2, 2)
    assert "elsewhere (rows 500..540, columns 500..540)" in said


def test_the_track_follows_the_runs_telemetry_time_offset(tmp_path, figures):
    """The report's coverage is the flight's rule (summary.frames_covered), offset included.

    Telemetry an hour after the frames, processed with ``telemetry_time_offset_s`` 3600: the
    flight counts every frame covered, so the track marks them too.
    """
    shifts = _converged_rows()
    _flight_tables(tmp_path, shifts, 3600.0)
    html = report_sections.mosaic_section(tmp_path, {"written": False}, (3600.0, 1.0))["mosaic"]
    labels = [ln.get_label() for ln in figures[-1].axes[0].get_lines()]
    assert "frame positions" in labels and "no frame" not in html
    _flight_tables(tmp_path, _converged_rows(expected=False), 3600.0)
    n = len(figures)
    report_sections.per_frame_sections(tmp_path, [], {}, T0_NS * 1e-9, True)
    assert "does not cover" in _texts(figures[n].axes[1])  # without the offset: an hour apart
    n = len(figures)
    report_sections.per_frame_sections(tmp_path, [], {}, T0_NS * 1e-9, True, (3600.0, 1.0))
    assert "does not cover" not in _texts(figures[n].axes[1])
