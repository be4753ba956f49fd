"""`subpix demo` (the README's quick start: `make demo`) end to end on the bundled flights.

Nodes in separate processes over DDS, then `subpix process` of both flights with its report.
"""

import json
import re
import subprocess

from conftest import subpix_cmd


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
