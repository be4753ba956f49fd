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
from subpix_ros.process.report_ahead import SectionsAhead, per_frame_sections

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def ahead_run(sample_bags, tmp_path_factory):
    """Return the product folder of the seneca sample flight processed with a helper."""
    out = tmp_path_factory.mktemp("ahead")
    ahead = SectionsAhead()
    try:
        res = process_bag(
            sample_bags / "seneca",
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
    assert timing["report_sections_ahead"] is True  # the helper's sections went into it
    text = (ahead_run / "report.html").read_text()
    assert "<h2>Shift trajectory</h2>" in text and "registration quality" in text
    # drawn again in this process from the products alone: the same document
    assert build_report(ahead_run) == text


def test_a_helper_that_died_leaves_the_sections_to_the_command(sample_bags, tmp_path):
    ahead = SectionsAhead()
    os.kill(ahead._proc.pid, signal.SIGKILL)
    ahead._proc.wait(timeout=10)
    res = process_bag(
        sample_bags / "seneca",
        tmp_path,
        load_params(ROOT / "config" / "demo.yaml"),
        sections_ahead=ahead,
    )
    ahead.close()
    folder = Path(res.out)
    assert json.loads((folder / "timing.json").read_text())["report_sections_ahead"] is False
    assert not res.problems or all("report" not in p for p in res.problems)
    assert build_report(folder) == (folder / "report.html").read_text()


def test_answers_to_earlier_requests_are_skipped(ahead_run):
    summary = json.loads((ahead_run / "summary.json").read_text())
    t0 = summary["flight"]["first_stamp_ns"] * 1e-9
    refs, stages = summary["references"], summary["stages"]
    ahead = SectionsAhead()
    try:
        first = ahead.submit(ahead_run, refs, stages, t0, False)  # never collected
        second = ahead.submit(ahead_run, refs, stages, t0, True)
        assert first is not None and second is not None and first != second
        got = ahead.result(second)
    finally:
        ahead.close()
    assert got == per_frame_sections(ahead_run, refs, stages, t0, True)
    assert got != per_frame_sections(ahead_run, refs, stages, t0, False)


def test_the_helper_ignores_ctrl_c_and_ends_with_its_pipe(tmp_path):
    ahead = SectionsAhead()
    proc = ahead._proc
    # an answer means its start-up (SIGINT ignored from there on) is done
    assert ahead.result(ahead.submit(tmp_path, [], {}, None, False))["shifts"].startswith("<p>No")
    proc.send_signal(signal.SIGINT)  # a terminal's Ctrl-C reaches the whole process group
    time.sleep(0.5)
    assert proc.poll() is None
    proc.stdin.close()  # the command closes the pipe: the helper ends by itself
    assert proc.wait(timeout=30) == 0
    ahead._proc = None
