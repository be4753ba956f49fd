"""`subpix demo` (the README's quick start: `make demo`) end to end on the bundled flights.

Nodes in separate processes over DDS, then `subpix process` of both flights with its report.
"""

import json
import os
import re
import signal
import subprocess
import sys
import time

import pytest
from conftest import child_processes, process_alive, subpix_cmd


def test_demo_runs_to_its_flight_report(sample_bags, tmp_path):
    out = tmp_path / "demo"
    r = subprocess.run(
        subpix_cmd("demo", "--out", str(out)), capture_output=True, text=True, timeout=900
    )
    assert r.returncode == 0, (r.stdout + r.stderr)[-3000:]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["mosaic_px"] and (out / "superres.png").is_file()
    shifts = re.search(r"(\d+) shifts out, shift RMSE vs truth ([0-9.]+) px", r.stdout)
    assert shifts and int(shifts.group(1)) >= 18 and float(shifts.group(2)) < 0.01, r.stdout
    gains = [float(g) for g in re.findall(r"([+-][0-9.]+) dB \(", r.stdout)]
    assert gains and min(gains) > 1.0, r.stdout
    # the field flight shows no straight edge: the blur used, and where a measured one comes from
    assert "optics blur used: 0.200 px (fallback: no usable edge" in r.stdout, r.stdout
    assert "measure the camera once with `subpix blur`" in r.stdout, r.stdout
    # demo.yaml's camera fits the frames: the live check over DDS says so
    check = re.search(
        r"telemetry vs frames \(registration node\): agrees: the frames moved ([0-9.]+)x", r.stdout
    )
    assert check and abs(float(check.group(1)) - 1.0) < 0.01, r.stdout
    report = re.search(r"flight report: (\S+)", r.stdout)
    assert report, r.stdout
    html = open(report.group(1)).read()
    assert "<img" in html and "Traceback" not in html


def _tall_strip_collector(stamp_ns, frames_added):
    """Return a demo collector that has heard the Seneca strip's tall (1786 x 687 px) mosaic."""
    import numpy as np

    from subpix_ros.cli import _demo_flights as demo

    col = demo._Collector.__new__(demo._Collector)
    col.mosaic = np.zeros((1786, 687, 3), np.uint8)
    col.mosaic_stamp_ns = stamp_ns
    col.diag = {"mosaic_node": {"frames_added": str(frames_added)}}
    return col


def test_seneca_flight_done_once_its_tall_mosaic_holds_every_frame(sample_bags, monkeypatch):
    """The demo's wait for the strip ends when the mosaic holds all frames, whatever its shape."""
    import argparse

    from subpix_ros.cli import _demo_flights as demo
    from subpix_ros.io import cdr
    from subpix_ros.io.bags import read_messages

    camera = read_messages(sample_bags / "seneca", ["/camera/image_raw"])
    sent = [cdr.header_to_ns(cdr.cdr_to_image_msg(m.raw).header) for m in camera]
    assert len(sent) == 9
    waited = []

    def spin_until(node, cond, timeout, procs=()):
        waited.append((timeout, cond()))
        return waited[-1][1]

    class Replayed:  # `subpix replay` of the strip, done
        returncode = 0

        def __init__(self, *a, **k):
            pass

        def poll(self):
            return 0

    monkeypatch.setattr(demo, "_spin_until", spin_until)
    monkeypatch.setattr(demo.subprocess, "Popen", Replayed)
    monkeypatch.setattr(demo.time, "sleep", lambda s: None)
    args = argparse.Namespace(seneca_rate=4.0, timeout=240.0)
    col = _tall_strip_collector(sent[-1], 9)
    demo._seneca_flight(None, col, sample_bags, args, {}, [None], {})
    assert [w for w in waited if w[0] == 60.0] == [(60.0, True)], waited  # ends at once


def test_mosaic_complete_needs_the_last_frame_and_every_frame_added():
    from subpix_ros.cli._demo_flights import mosaic_complete

    sent = [10, 20, 30]
    assert mosaic_complete(30, {"frames_added": "3"}, sent)
    assert not mosaic_complete(20, {"frames_added": "3"}, sent)  # the last frame not drawn yet
    assert not mosaic_complete(30, {"frames_added": "2"}, sent)  # the count not published yet
    assert not mosaic_complete(None, {}, sent)
    assert not mosaic_complete(30, {"frames_added": "3"}, [])


def test_demo_lists_the_files_it_writes(sample_bags, tmp_path, monkeypatch, capsys):
    """The summary's "outputs in" line names each file the demo wrote, summary.txt included."""
    import argparse

    import numpy as np

    from subpix_ros.cli import demo
    from subpix_ros.cli._demo_flights import Captured
    from subpix_ros.core.superres import bicubic_upscale
    from subpix_ros.io import cdr
    from subpix_ros.io.bags import read_messages

    first = next(iter(read_messages(sample_bags / "subpixel", ["/camera/image_raw"])))
    ref = cdr.cdr_to_image(first.raw)[0]
    sr = np.dstack([bicubic_upscale(ref[..., c].astype(float), 2) for c in range(3)])
    heard = Captured(  # what the pipeline would have published (no DDS here)
        shifts=[],
        srs=[(first.timestamp_ns, np.clip(sr, 0, 255).astype(np.uint8))],
        refs=[first.timestamp_ns],
        diag_subpixel={},
        diag={},
        mosaic=np.zeros((1786, 687, 3), np.uint8),
    )
    monkeypatch.setattr(demo, "run_flights", lambda *a: heard)
    monkeypatch.setattr(demo, "_flight_report", lambda *a: None)
    out = tmp_path / "demo"
    args = argparse.Namespace(out=str(out), bags=str(sample_bags))
    assert demo.run(args) == 0
    listed = re.search(r"outputs in (\S+)/: (.+)", capsys.readouterr().out)
    assert listed and listed.group(1) == str(out), listed
    assert sorted(listed.group(2).split(", ")) == sorted(p.name for p in out.iterdir())


@pytest.mark.skipif(sys.platform != "linux", reason="reads /proc")
@pytest.mark.parametrize("how", ["SIGTERM", "SIGHUP", "Ctrl-C"])
def test_demo_interrupted_says_so_and_stops_its_processes(sample_bags, tmp_path, how):
    """SIGTERM or SIGHUP to the demo, or Ctrl-C on its terminal, while it replays a flight.

    One line "subpix demo: interrupted" and status 130 (no traceback of rclpy's
    ExternalShutdownException), and the pipeline and replay it started are gone.
    """
    err_path = tmp_path / "stderr.txt"
    with open(tmp_path / "stdout.txt", "w") as out, open(err_path, "w") as err:
        demo = subprocess.Popen(
            subpix_cmd("demo", "--out", str(tmp_path / "demo")),
            stdout=out,
            stderr=err,
            start_new_session=True,  # a process group of its own, as a terminal's job
        )
    try:
        deadline = time.monotonic() + 120
        kids = {}
        while time.monotonic() < deadline and demo.poll() is None:
            kids = child_processes(demo.pid)
            if any(" replay " in cmd for cmd in kids.values()):  # DDS up, a flight replayed
                break
            time.sleep(0.1)
        assert any(" replay " in cmd for cmd in kids.values()), (kids, err_path.read_text())
        time.sleep(1.0)  # into the replay
        if how != "Ctrl-C":
            os.kill(demo.pid, getattr(signal, how))
        else:  # the terminal sends SIGINT to every process of its foreground job
            os.killpg(demo.pid, signal.SIGINT)
        rc = demo.wait(60)
    finally:
        if demo.poll() is None:
            os.killpg(demo.pid, signal.SIGKILL)
            demo.wait()
        left = [pid for pid in kids if process_alive(pid)]
        for pid in left:  # whatever failed: no pipeline left running for the later tests
            os.kill(pid, signal.SIGKILL)
    err_text = err_path.read_text()
    assert rc == 130, err_text
    assert "Traceback" not in err_text and "error" not in err_text, err_text
    assert err_text.strip().splitlines()[-1] == "subpix demo: interrupted", err_text
    assert err_text.count("subpix demo: interrupted") == 1, err_text
    assert not left, (kids, err_text)


@pytest.mark.skipif(sys.platform != "linux", reason="reads /proc")
def test_demo_killed_leaves_no_pipeline_or_replay_running(sample_bags, tmp_path):
    """SIGKILL of the demo (it cannot stop anything itself): its pipeline and replay end too.

    (Was: they ran on, in sessions of their own, holding the DDS domain.) The kernel sends
    them SIGTERM when the demo dies (``SUBPIX_DIE_WITH_PARENT``), and they stop cleanly.
    """
    with open(tmp_path / "stderr.txt", "w") as err:
        demo = subprocess.Popen(
            subpix_cmd("demo", "--out", str(tmp_path / "demo")),
            stdout=subprocess.DEVNULL,
            stderr=err,
            start_new_session=True,
        )
    kids = {}
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and demo.poll() is None:
            kids = child_processes(demo.pid)
            if any(" replay " in cmd for cmd in kids.values()):
                break
            time.sleep(0.1)
        assert any(" replay " in cmd for cmd in kids.values()), kids
        time.sleep(1.0)
        demo.kill()
        demo.wait(30)
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and any(process_alive(pid) for pid in kids):
            time.sleep(0.2)
        left = {pid: cmd for pid, cmd in kids.items() if process_alive(pid)}
    finally:
        for pid in kids:
            if process_alive(pid):
                os.kill(pid, signal.SIGKILL)
    assert left == {}, left
