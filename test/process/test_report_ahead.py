"""The report's per-frame sections drawn in a helper process (`subpix process`, one job).

The helper must change when the report is drawn, never what it shows: the report of a flight
processed with it is the one drawn afterwards from the products alone, and a helper that is gone
leaves the report to the command (the same bytes).
"""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path

import pytest

from subpix_ros.process import build_report, load_params, process_bag
from subpix_ros.process.report_ahead import SectionsAhead
from subpix_ros.process.report_sections import per_frame_sections

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def ahead_run(sample_bags, tmp_path_factory):
    """Return the product folder of the subpixel sample flight processed with a helper."""
    out = tmp_path_factory.mktemp("ahead")
    ahead = SectionsAhead()
    try:
        res = process_bag(
            sample_bags / "subpixel",
            out,
            load_params(ROOT / "config" / "demo.yaml"),
            sections_ahead=ahead,
        )
    finally:
        ahead.close()
    assert res.status in ("ok", "partial"), res.line
    return Path(res.out)


def test_the_helper_draws_the_sections_the_report_would_draw(ahead_run):
    timing = json.loads((ahead_run / "timing.json").read_text())
    # the helper's sections and every set's offsets figure went into it (the command drew none)
    assert timing["report_sections_ahead"] == ["mosaic", "registration", "shifts"]
    n_sets = len(json.loads((ahead_run / "summary.json").read_text())["sets"])
    assert n_sets >= 1 and timing["report_offsets_ahead"] == n_sets
    text = (ahead_run / "report.html").read_text()
    assert "<h2>Shift trajectory</h2>" in text and "registration quality" in text
    assert "mosaic and GPS track" in text
    # drawn again in this process from the products alone: the same document
    assert build_report(ahead_run) == text


def test_a_helper_that_died_leaves_the_sections_to_the_command(sample_bags, tmp_path):
    ahead = SectionsAhead()
    os.kill(ahead._proc.pid, signal.SIGKILL)
    ahead._proc.wait(timeout=10)
    res = process_bag(
        sample_bags / "subpixel",
        tmp_path,
        load_params(ROOT / "config" / "demo.yaml"),
        sections_ahead=ahead,
    )
    ahead.close()
    folder = Path(res.out)
    timing = json.loads((folder / "timing.json").read_text())
    assert timing["report_sections_ahead"] == [] and timing["report_offsets_ahead"] == 0
    assert not res.problems or all("report" not in p for p in res.problems)
    assert build_report(folder) == (folder / "report.html").read_text()


def test_each_answer_goes_to_its_own_request(ahead_run):
    summary = json.loads((ahead_run / "summary.json").read_text())
    t0 = summary["flight"]["first_stamp_ns"] * 1e-9
    refs, stages = summary["references"], summary["stages"]
    ahead = SectionsAhead()
    try:
        first = ahead.submit("per_frame_sections", ahead_run, refs, stages, t0, False)
        second = ahead.submit("per_frame_sections", ahead_run, refs, stages, t0, True)
        assert first is not None and second is not None and first != second
        got_second, got_first = ahead.result(second), ahead.result(first)
    finally:
        ahead.close()
    assert got_second == per_frame_sections(ahead_run, refs, stages, t0, True)
    assert got_first == per_frame_sections(ahead_run, refs, stages, t0, False) != got_second


def test_the_helper_ignores_ctrl_c_and_ends_with_its_pipe(tmp_path):
    ahead = SectionsAhead()
    proc = ahead._proc
    # an answer means its start-up (SIGINT ignored from there on) is done
    got = ahead.result(ahead.submit("per_frame_sections", tmp_path, [], {}, None, False))
    assert "no shift to show" in got["shifts"]
    proc.send_signal(signal.SIGINT)  # a terminal's Ctrl-C reaches the whole process group
    time.sleep(0.5)
    assert proc.poll() is None
    proc.stdin.close()  # the command closes the pipe: the helper ends by itself
    assert proc.wait(timeout=30) == 0
    ahead.close()
