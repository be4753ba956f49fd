"""`subpix process` / `subpix report` on real rosbag2 files.

`subpix process` / `subpix report` on real rosbag2 files: products, determinism, re-runs,
interruption, and bad input (no images, no telemetry, a corrupt chunk, mixed frame sizes).
"""

import filecmp
import json
import os
import re
import shutil
import signal
import struct
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
from conftest import child_processes, process_alive

from subpix_ros.io.bags import BagWriter, bag_topics, read_messages
from subpix_ros.io.cdr import (
    cdr_to_compressed,
    cdr_to_compressed_msg,
    cdr_to_image,
    compressed_to_cdr,
    header_to_ns,
    image_to_cdr,
)
from subpix_ros.process.products import DETERMINISTIC, read_csv

ROOT = Path(__file__).resolve().parents[2]
DEMO = str(ROOT / "config" / "demo.yaml")


def process_cmd(*args: str) -> list[str]:
    return [sys.executable, "-m", "subpix_ros.cli", "process", *args]


def _run(*args, timeout=600):
    return subprocess.run(process_cmd(*args), capture_output=True, text=True, timeout=timeout)


def _sample(sample_bags):
    msgs = list(read_messages(sample_bags / "subpixel"))
    frames = [m for m in msgs if m.topic == "/camera/image_raw"]
    tel = [m for m in msgs if m.topic.startswith("/telemetry/")]
    return msgs, frames, tel


def _write(path, msgs, storage="mcap"):
    with BagWriter(path, storage=storage) as w:
        for m in msgs:
            w.write(m.topic, m.msgtype, m.timestamp_ns, m.raw)
    return path


def _summary(folder):
    return json.loads((folder / "summary.json").read_text())


def _deterministic_files(folder):
    out = []
    for name in DETERMINISTIC:
        p = folder / name
        if p.is_dir():
            out += sorted(q.relative_to(folder) for q in p.rglob("*") if q.is_file())
        elif p.is_file():
            out.append(p.relative_to(folder))
    return out


# --------------------------------------------------------------------------- the sample flights
def test_sample_flight_products(processed, sample_bags):
    out, r = processed
    d = out / "subpixel"
    for name in (
        "results.mcap",
        "mosaic.png",
        "shifts.csv",
        "frames.csv",
        "telemetry.csv",
        "summary.json",
        "timing.json",
        "report.html",
    ):
        assert (d / name).is_file(), name
    assert not [p for p in out.iterdir() if p.name.startswith(".")], "temporary folders left behind"
    s = _summary(d)
    truth = json.loads((sample_bags / "subpixel" / "truth.json").read_text())
    true = {f["stamp_ns"]: np.array([f["u"], f["v"]]) for f in truth["frames"]}
    assert s["status"] == "ok" and s["problems"] == []
    assert s["frames"]["in"] == len(true) and s["frames"]["dropped"] == 0
    assert s["telemetry"]["source"] == "topics" and s["telemetry"]["samples"] > 20
    rows = read_csv(d / "shifts.csv")
    conv = [row for row in rows if row["converged"] == "1"]
    assert len(conv) >= 18
    for row in conv:
        ref = int(row["reference_stamp_ns"])
        t = true[int(row["stamp_ns"])] - true[ref]
        measured = np.array([float(row["u_total_px"]), float(row["v_total_px"])])
        expected = np.array([float(row["u_expected_px"]), float(row["v_expected_px"])])
        assert np.abs(measured - t).max() < 0.02, (
            row
        )  # whole + sub-pixel shift against the rendered truth
        assert np.abs(expected - t).max() < 0.02, row  # METHODS eq. 1 from the bag's telemetry
        assert float(row["u_std_px"]) > 0 and float(row["v_std_px"]) > 0
    assert len(s["sets"]) >= 2
    for st in s["sets"]:
        sr = cv2.imread(str(d / st["superres"]), cv2.IMREAD_UNCHANGED)
        bic = cv2.imread(str(d / st["bicubic"]), cv2.IMREAD_UNCHANGED)
        assert sr.dtype == np.uint8 and sr.shape == bic.shape == (896, 896, 3)
        assert st["gain_db"] > 3.0, st  # PSNR against truth_hr.png, beside the bicubic reference
        assert st["blur_source"] == "fallback" and st["blur_reason"].startswith("no usable edge")
    # a field crop without a straight edge: said per set, for the flight, and in its line
    assert s["blur"]["sets_by_source"] == {"fallback": len(s["sets"])}
    assert s["blur"]["note"].startswith("no usable straight edge in this flight")
    assert "optics blur: fallback 0.20 px, no straight edge" in r.stdout
    html = (d / "report.html").read_text()
    assert "Optics blur 0.200 px (fallback: no usable edge" in html
    assert "<td>optics blur</td><td>no usable straight edge" in html
    # the frames moved as METHODS eq. 1 says with demo.yaml's camera (2x downscaled Seneca)
    check = s["telemetry"]["check"]
    assert check["agrees"] is True and abs(check["scale"] - 1.0) < 0.01, check
    assert abs(check["rotation_deg"]) < 0.5 and check["pairs"] >= 18, check
    assert "<td>telemetry vs frames</td><td>agrees: the frames moved 1.000x" in html
    assert (out / "seneca" / "mosaic.png").is_file()
    sen = _summary(out / "seneca")
    mos = sen["mosaic"]
    assert mos["written"] and len(mos["footprints"]) == 9
    # the real strip (frames 4 s apart, for the mosaic): why no set and no shift, said
    assert re.match(
        r"no super-resolved image: no set reached min_frames \(\d+ frames aligned to \d+ "
        r"references, started by: .*predicted overlap",
        sen["problems"][0],
    ), sen["problems"]
    assert any(
        re.match(r"(\d+) of \1 aligned frames have no sub-pixel shift: ", p)
        for p in sen["problems"]
    )
    # ... yet the registration's displacement of every aligned frame is in shifts.csv
    sen_rows = read_csv(out / "seneca" / "shifts.csv")
    assert sen_rows and all(row["u_total_px"] == "" for row in sen_rows)
    assert all(float(row["u_registration_px"]) > 100 for row in sen_rows), sen_rows
    assert all(row["v_registration_px"] != "" for row in sen_rows), sen_rows
    assert "report: " in r.stdout


def test_results_mcap_messages_carry_their_source_frames(processed):
    d = processed[0] / "subpixel"
    s = _summary(d)
    topics = {t.name: t for t in bag_topics(d / "results.mcap")}
    for name in (
        "/shift",
        "/shift/std",
        "/homography",
        "/super_resolved/compressed",
        "/mosaic/compressed",
        "/telemetry/frame_interval",
        "/diagnostics",
        "/aligned/reference_stamp",
    ):
        assert name in topics, name
    frames = {int(r["stamp_ns"]) for r in read_csv(d / "frames.csv")}
    conv = {int(r["stamp_ns"]) for r in read_csv(d / "shifts.csv") if r["converged"] == "1"}
    shifts = list(read_messages(d / "results.mcap", ["/shift"]))
    from subpix_ros.io.cdr import cdr_to_vector3_stamped

    assert {m.timestamp_ns for m in shifts} == conv
    for m in shifts:
        assert header_to_ns(cdr_to_vector3_stamped(m.raw)[1]) == m.timestamp_ns
    # their standard errors, as shift_node publishes them, equal shifts.csv's
    rows = {int(r["stamp_ns"]): r for r in read_csv(d / "shifts.csv")}
    stds = list(read_messages(d / "results.mcap", ["/shift/std"]))
    assert {m.timestamp_ns for m in stds} == conv
    for m in stds:
        vec, header = cdr_to_vector3_stamped(m.raw)
        row = rows[m.timestamp_ns]
        assert header_to_ns(header) == m.timestamp_ns and 0 < vec[0] <= 0.1 and 0 < vec[1] <= 0.1
        assert (vec[0], vec[1]) == (float(row["u_std_px"]), float(row["v_std_px"]))
    # the super-resolved images and the mosaic: the PNG files' own bytes, lossless
    srs = list(read_messages(d / "results.mcap", ["/super_resolved/compressed"]))
    assert [m.timestamp_ns for m in srs] == [st["reference_stamp_ns"] for st in s["sets"]]
    for m, st in zip(srs, s["sets"]):
        msg = cdr_to_compressed_msg(m.raw)
        assert bytes(msg.data) == (d / st["superres"]).read_bytes()
        assert msg.format == "bgr8; png compressed bgr8"
        assert header_to_ns(msg.header) == m.timestamp_ns
    img, _ = cdr_to_compressed(srs[0].raw)
    ref_png = cv2.imread(str(d / s["sets"][0]["superres"]), cv2.IMREAD_UNCHANGED)
    assert np.array_equal(img, ref_png)
    (mos,) = read_messages(d / "results.mcap", ["/mosaic/compressed"])
    assert bytes(cdr_to_compressed_msg(mos.raw).data) == (d / "mosaic.png").read_bytes()
    for topic in ("/homography", "/telemetry/frame_interval", "/aligned/reference_stamp"):
        assert {m.timestamp_ns for m in read_messages(d / "results.mcap", [topic])} <= frames, topic


def test_results_mcap_replays(processed):
    d = processed[0] / "subpixel"
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "subpix_ros.cli",
            "replay",
            str(d / "results.mcap"),
            "--rate",
            "20",
            "--delay",
            "0",
            "--ack-timeout",
            "0",
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stderr
    n = sum(t.count for t in bag_topics(d / "results.mcap"))
    assert f"replayed {n} messages" in r.stdout


def test_deterministic_and_rerun_skips(processed, sample_bags, tmp_path):
    """Process the same bag with one job instead of two: byte-identical products.

    Same bag and parameters, one job instead of two: byte-identical products.
    A re-run skips, --force redoes.
    """
    out, _ = processed
    r = _run(str(sample_bags / "subpixel"), "-o", str(tmp_path), "--params", DEMO, "--quiet")
    assert r.returncode == 0, r.stderr
    a, b = out / "subpixel", tmp_path / "subpixel"
    files = _deterministic_files(a)
    assert len(files) >= 10 and files == _deterministic_files(b)
    match, mismatch, errors = filecmp.cmpfiles(a, b, [str(f) for f in files], shallow=False)
    assert mismatch == [] and errors == []
    before = (b / "summary.json").stat().st_mtime_ns
    r = _run(str(sample_bags / "subpixel"), "-o", str(tmp_path), "--params", DEMO)
    assert r.returncode == 0 and "skipped" in r.stdout
    assert (b / "summary.json").stat().st_mtime_ns == before
    r = _run(
        str(sample_bags / "subpixel"), "-o", str(tmp_path), "--params", DEMO, "--force", "--quiet"
    )
    assert r.returncode == 0, r.stderr
    assert (b / "summary.json").stat().st_mtime_ns != before
    assert filecmp.cmp(a / "shifts.csv", b / "shifts.csv", shallow=False)
    # with one job the report's figures were drawn by the helper process, and are the ones
    # drawn in this process from the products
    timing = json.loads((b / "timing.json").read_text())
    n_sets = len(json.loads((b / "summary.json").read_text())["sets"])
    assert timing["report_sections_ahead"] == ["mosaic", "registration", "shifts"]
    assert n_sets >= 1 and timing["report_offsets_ahead"] == n_sets
    from subpix_ros.process import build_report

    assert build_report(b) == (b / "report.html").read_text()


def test_a_rerun_redoes_what_changed_and_keeps_what_went_wrong(sample_bags, tmp_path):
    """A re-run skips only products made from the same bag and parameters, and keeps their status.

    A partial flight skipped on a re-run still exits 1 and says why; other parameters or a
    changed bag redo the products; a folder missing a product is redone, not an error; the
    temporary folder of a killed run is removed.
    """
    _, _, tel = _sample(sample_bags)
    (tmp_path / "bags").mkdir()
    bag = _write(tmp_path / "bags" / "no_images", tel)
    out = tmp_path / "out"
    args = (str(bag), "-o", str(out), "--quiet")
    r = _run(*args)
    assert r.returncode == 1 and _summary(out / "no_images")["status"] == "partial", r.stderr
    # the same bag and parameters: skipped, and still the partial flight it was
    r = _run(*args[:-1])
    assert r.returncode == 1, r.stdout + r.stderr
    assert "skipped, products up to date" in r.stdout and "the flight was partial" in r.stdout
    assert "no images" in r.stdout
    batch = json.loads((out / "batch_summary.json").read_text())
    assert (batch[0]["status"], batch[0]["previous_status"]) == ("skipped", "partial")
    # other parameters: redone, and said
    r = _run(*args[:-1], "--params", DEMO)
    assert "up to date" not in r.stdout, r.stdout
    assert "products redone: parameters changed since the last run" in r.stdout, r.stdout
    # a product deleted by hand: redone (it was an error: "appeared while processing")
    (out / "no_images" / "shifts.csv").unlink()
    r = _run(*args[:-1], "--params", DEMO)
    assert "Error" not in r.stdout + r.stderr, r.stdout + r.stderr
    assert "products redone: shifts.csv missing" in r.stdout, r.stdout
    assert (out / "no_images" / "shifts.csv").is_file()
    # a changed bag (another recording under the same name): redone
    shutil.rmtree(bag)
    _write(bag, tel[: len(tel) // 2])
    leftover = out / ".no_images.partial-999999999"  # a run killed with SIGKILL left it
    leftover.mkdir()
    r = _run(*args[:-1], "--params", DEMO)
    assert "products redone: file " in r.stdout and "changed since" in r.stdout, r.stdout
    assert "removed .no_images.partial-999999999" in r.stdout and not leftover.exists()


def _report_helpers(parent: int) -> list[int]:
    """PIDs of the report helper processes (``subpix_ros.process.report_ahead``) of ``parent``."""
    return [
        pid
        for pid, cmd in child_processes(parent).items()
        if "subpix_ros.process.report_ahead" in cmd
    ]


def test_ctrl_c_leaves_nothing_that_looks_complete(sample_bags, tmp_path):
    p = subprocess.Popen(
        process_cmd(str(sample_bags / "subpixel"), "-o", str(tmp_path), "--params", DEMO),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    line = p.stderr.readline()  # the first progress line: processing has started
    assert "frames" in line, line
    helpers = _report_helpers(p.pid)
    assert len(helpers) == 1  # the report's helper process (one job)
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=120)
    assert p.returncode == 130 and "subpix process: interrupted" in err, err
    assert not Path(f"/proc/{helpers[0]}").exists()  # stopped with the command
    assert "Traceback" not in err
    assert list(tmp_path.iterdir()) == [] or not (tmp_path / "subpixel").exists()
    assert not [q for q in tmp_path.iterdir() if q.name.startswith(".")]


def _two_bags_two_jobs(sample_bags, out):
    """Start `subpix process` of both sample flights with --jobs 2 into ``out`` (pipes)."""
    return subprocess.Popen(
        process_cmd(
            str(sample_bags / "subpixel"),
            str(sample_bags / "seneca"),
            "-o",
            str(out),
            "--params",
            DEMO,
            "--jobs",
            "2",
        ),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def test_kill_with_jobs_stops_the_workers_and_removes_their_folders(sample_bags, tmp_path):
    p = _two_bags_two_jobs(sample_bags, tmp_path)
    try:
        line = p.stderr.readline()
        assert "frames" in line, line
        p.send_signal(signal.SIGTERM)  # to the parent alone: it must stop its workers itself
        _, err = p.communicate(timeout=120)
    finally:  # a hung parent must not outlive the test (it did once: see batch._run_parallel)
        if p.poll() is None:
            p.kill()
    assert p.returncode == 130, err
    assert "Traceback" not in err
    time.sleep(1.0)
    assert [q.name for q in tmp_path.iterdir()] == []


def test_sigkill_with_jobs_leaves_no_process_behind(sample_bags, tmp_path):
    """SIGKILL of `subpix process --jobs 2` leaves none of its processes behind.

    Its workers, the progress queue's manager and multiprocessing's resource tracker all end
    (was: the manager and the tracker lived on, holding the command's pipes open).
    """
    p = _two_bags_two_jobs(sample_bags, tmp_path)
    try:
        assert "frames" in p.stderr.readline()
        children = list(child_processes(p.pid))
        assert len(children) >= 3, children  # two workers, the manager, the resource tracker
    finally:
        p.kill()
        p.wait(timeout=60)
        p.stdout.close()  # not communicate(): a child left behind holds the pipes open
        p.stderr.close()
    deadline = time.monotonic() + 20.0
    while time.monotonic() < deadline and any(process_alive(c) for c in children):
        time.sleep(0.2)
    left = {c: Path(f"/proc/{c}/cmdline").read_bytes()[:120] for c in children if process_alive(c)}
    for c in left:
        os.kill(c, signal.SIGKILL)
    assert left == {}


# --------------------------------------------------------------------------- bad input
def test_bad_bags_get_one_line_each_and_the_rest_is_processed(sample_bags, tmp_path):
    msgs, frames, tel = _sample(sample_bags)
    bags = tmp_path / "bags"
    bags.mkdir()
    _write(bags / "no_images", tel)
    _write(bags / "no_telemetry", frames)
    mixed = []
    for k, m in enumerate(frames):
        if 9 <= k <= 11:
            img, h = cdr_to_image(m.raw)
            m = type(m)(
                m.topic,
                m.msgtype,
                m.timestamp_ns,
                image_to_cdr(
                    np.ascontiguousarray(img[:320, :300]), "bgr8", m.timestamp_ns, "camera"
                ),
            )
        mixed.append(m)
    _write(bags / "mixed_sizes", sorted(mixed + tel, key=lambda m: m.timestamp_ns))
    corrupt = _write(bags / "corrupt.mcap", msgs)
    data = bytearray(corrupt.read_bytes())
    i, chunks = 8, []
    while (
        data[i] != 0x0F
    ):  # top-level records up to the data end: damage a record inside the middle chunk
        op, n = data[i], struct.unpack_from("<Q", data, i + 1)[0]
        if op == 0x06:
            chunks.append(i)
        i += 9 + n
    c = chunks[len(chunks) // 2]
    j = c + 9 + 28
    j += 4 + struct.unpack_from("<I", data, j)[0] + 8
    data[j : j + 9] = b"\x05" + struct.pack("<Q", 2**40)
    corrupt.write_bytes(bytes(data))
    (bags / "not_a_bag").mkdir()
    out = tmp_path / "out"
    names = ["no_images", "no_telemetry", "mixed_sizes", "corrupt.mcap", "not_a_bag"]
    r = _run(*[str(bags / n) for n in names], "-o", str(out), "--params", DEMO, "--jobs", "2")
    assert r.returncode == 1
    assert "Traceback" not in r.stderr + r.stdout
    batch = {b["name"]: b for b in json.loads((out / "batch_summary.json").read_text())}
    assert set(batch) == {"no_images", "no_telemetry", "mixed_sizes", "corrupt", "not_a_bag"}
    for b in batch.values():
        assert "\n" not in b["line"]
    assert batch["not_a_bag"]["status"] == "failed" and not (out / "not_a_bag").exists()

    s = _summary(out / "no_images")
    assert s["status"] == "partial" and "no images" in batch["no_images"]["line"]
    assert any("no images" in p for p in s["problems"])
    assert "no images" in (out / "no_images" / "report.html").read_text()
    assert "(no flight time: no frames)" in (out / "no_images" / "report.html").read_text()

    s = _summary(out / "no_telemetry")
    assert batch["no_telemetry"]["status"] == "ok"
    assert s["telemetry"]["source"] == "none" and any("no telemetry" in p for p in s["problems"])
    assert (
        len(s["sets"]) >= 2
        and (out / "no_telemetry" / "superres" / s["sets"][0]["superres"].split("/")[1]).is_file()
    )
    rows = read_csv(out / "no_telemetry" / "shifts.csv")
    assert rows and all(row["u_expected_px"] == "" for row in rows)
    assert "no telemetry" in (out / "no_telemetry" / "report.html").read_text()

    s = _summary(out / "mixed_sizes")
    assert s["status"] == "partial" and s["frames"]["dropped"] == 3
    assert any(
        "frame size 300x320x3 uint8 differs from the flight's 448x448x3 uint8" in p
        for p in s["problems"]
    )
    assert len(s["sets"]) >= 1
    fr = read_csv(out / "mixed_sizes" / "frames.csv")
    assert [row["status"] for row in fr[9:12]] == ["dropped"] * 3

    s = _summary(out / "corrupt")
    assert s["status"] == "partial" and "breaks off" in batch["corrupt"]["line"]
    assert 0 < s["frames"]["in"] < len(frames)
    assert "is corrupt at byte offset" in (out / "corrupt" / "report.html").read_text()
    corrupt_said = [p for p in s["problems"] if "corrupt" in p]
    assert len(corrupt_said) == 1 and "(--skip-corrupt reads on past the damage)" in corrupt_said[0]
    # --skip-corrupt: the frames after the damaged chunk are processed too, and it is said
    r = _run(
        str(bags / "corrupt.mcap"),
        "-o",
        str(tmp_path / "out2"),
        "--params",
        DEMO,
        "--skip-corrupt",
        "--quiet",
    )
    assert r.returncode == 1 and "Traceback" not in r.stderr + r.stdout
    s2 = _summary(tmp_path / "out2" / "corrupt")
    assert s2["status"] == "partial" and s["frames"]["in"] < s2["frames"]["in"] < len(frames)
    assert any(
        "corrupt bag read past its damage: skipped 1 corrupt record" in p
        and p.endswith(f"; {s2['frames']['in']} of {len(frames)} frames read")
        for p in s2["problems"]
    ), s2["problems"]


def test_a_truncated_bag_is_one_statement_of_what_was_read_and_lost(sample_bags, tmp_path):
    """The sample flight's mcap cut in half: read up to the cut, with or without --skip-corrupt.

    One corrupt-bag problem either way, the frames read of the bag's count in it, and no
    suggestion of --skip-corrupt: nothing lies past the end of a truncated file.
    """
    msgs, frames, _ = _sample(sample_bags)
    bag = _write(tmp_path / "cut.mcap", msgs)
    data = bag.read_bytes()
    bag.write_bytes(data[: len(data) // 2])
    said = {}
    for extra in ((), ("--skip-corrupt",)):
        out = tmp_path / ("out" + "".join(extra))
        r = _run(str(bag), "-o", str(out), "--params", DEMO, "--quiet", *extra)
        assert r.returncode == 1 and "Traceback" not in r.stderr + r.stdout
        s = _summary(out / "cut")
        assert s["status"] == "partial" and 0 < s["frames"]["in"] < len(frames)
        corrupt = [p for p in s["problems"] if "corrupt" in p]
        assert len(corrupt) == 1, s["problems"]
        assert "--skip-corrupt" not in corrupt[0], corrupt[0]
        said[extra] = (s["frames"]["in"], s["frames"]["total_in_bag"], corrupt[0])
    (n, total, broke), (n_skip, _, read) = said.values()
    assert n_skip == n  # reading on gains nothing past the end of the file
    assert broke.startswith(f"bag breaks off after {n} of {total} frames: "), broke
    assert read.startswith("corrupt bag read up to its damage (nothing readable after it): ")
    assert read.endswith(f"; {n} of {total} frames read"), read


def test_sqlite3_compressed_images_with_tlog_telemetry(sample_bags, tmp_path):
    """CompressedImage (lossless PNG) in a sqlite3 bag, telemetry from the .tlog beside it."""
    _, frames, _ = _sample(sample_bags)
    comp = []
    for m in frames:
        img, h = cdr_to_image(m.raw)
        comp.append(
            type(m)(
                "/cam/compressed",
                "sensor_msgs/msg/CompressedImage",
                m.timestamp_ns,
                compressed_to_cdr(np.ascontiguousarray(img), m.timestamp_ns, "camera", "png"),
            )
        )
    bag = _write(tmp_path / "flight", comp, storage="sqlite3")
    (tmp_path / "flight.tlog").write_bytes((sample_bags / "subpixel.tlog").read_bytes())
    r = _run(
        str(bag), "-o", str(tmp_path / "out"), "--params", DEMO, "--telemetry", "tlog", "--quiet"
    )
    assert r.returncode == 0, r.stderr
    s = _summary(tmp_path / "out" / "flight")
    assert (
        s["camera"]["topic"] == "/cam/compressed" and s["telemetry"]["source"] == "tlog flight.tlog"
    )
    truth = json.loads((sample_bags / "subpixel" / "truth.json").read_text())
    true = {f["stamp_ns"]: np.array([f["u"], f["v"]]) for f in truth["frames"]}
    rows = [
        row
        for row in read_csv(tmp_path / "out" / "flight" / "shifts.csv")
        if row["converged"] == "1"
    ]
    assert len(rows) >= 18
    for row in rows:
        t = true[int(row["stamp_ns"])] - true[int(row["reference_stamp_ns"])]
        # MAVLink carries the velocity in cm/s: 1 cm/s of the 0.59 m/s drift is 1.7 % of the shift
        exp = np.array([float(row["u_expected_px"]), float(row["v_expected_px"])])
        assert np.all(np.abs(exp - t) < 0.01 + 0.03 * np.abs(t)), (exp, t)


def test_missing_sources_are_one_line_errors(sample_bags, tmp_path):
    r = _run(str(sample_bags / "seneca"), "-o", str(tmp_path), "--camera-topic", "/nope", "--quiet")
    assert (
        r.returncode == 1
        and "camera topic /nope not in bag" in (tmp_path / "batch_summary.json").read_text()
    )
    r = _run(str(sample_bags / "subpixel"), str(sample_bags / "subpixel"), "-o", str(tmp_path))
    assert r.returncode == 1 and r.stderr.count("\n") == 1 and "would both write" in r.stderr
    r = _run(
        str(sample_bags / "subpixel"), "-o", str(tmp_path), "--params", str(tmp_path / "none.yaml")
    )
    assert r.returncode == 1 and r.stderr.count("\n") == 1 and "cannot read parameters" in r.stderr
    r = _run(str(sample_bags / "subpixel"), "-o", str(tmp_path), "--serve", "99999")
    assert r.returncode == 2 and "port 99999 is not in 1..65535" in r.stderr, r.stderr


def test_params_that_cannot_apply_stop_the_command_before_any_bag(sample_bags, tmp_path):
    """A misspelt key or node: one line naming the file, node and key, exit status 2."""
    cases = {
        "key.yaml": (
            "registration_node:\n  ros__parameters:\n    focal_lenght_mm: 9.9\n",
            "registration_node has no parameter focal_lenght_mm (did you mean focal_length_mm?)",
        ),
        "node.yaml": (
            "registraton_node:\n  ros__parameters:\n    pixel_pitch_um: 3.08\n",
            "no node registraton_node in subpix process (did you mean registration_node?)",
        ),
    }
    for name, (text, message) in cases.items():
        cfg = tmp_path / name
        cfg.write_text(text)
        out = tmp_path / f"out_{cfg.stem}"
        r = _run(
            str(sample_bags / "subpixel"), "-o", str(out), "--params", DEMO, "--params", str(cfg)
        )
        assert r.returncode == 2, (r.returncode, r.stderr)
        assert r.stderr == f"subpix process: error: parameters {cfg}: {message}\n", r.stderr
        assert not out.exists()  # nothing processed, nothing written


def test_wildcard_params_apply_and_another_program_s_node_is_a_warning(sample_bags, tmp_path):
    """A shared stack file: ``/**`` sets the pixel pitch, the camera driver's section is not ours.

    The sample flight needs 3.08 um pixels (the default 1.54 expects twice the motion): given
    by ``/**`` alone, it reaches the registration stage, the telemetry agrees and
    ``summary.json`` shows it; the foreign node is named on one warning line and the run goes on.
    """
    cfg = tmp_path / "stack.yaml"
    cfg.write_text(
        "camera_driver:\n  ros__parameters:\n    fps: 10\n"
        "/**:\n  ros__parameters:\n    pixel_pitch_um: 3.08\n    use_sim_time: false\n"
    )
    out = tmp_path / "out"
    r = _run(str(sample_bags / "subpixel"), "-o", str(out), "--params", str(cfg), "--quiet")
    assert r.returncode == 0, r.stderr
    warning = (
        f"warning: parameters {cfg}: camera_driver is not a node of subpix_ros: its parameters "
        "are ignored"
    )
    assert r.stderr.splitlines() == [warning], r.stderr
    s = _summary(out / "subpixel")
    assert s["parameters"]["registration_node"] == {"pixel_pitch_um": 3.08}
    assert s["telemetry"]["check"]["agrees"] is True, s["telemetry"]["check"]
    assert not any(p.startswith("telemetry disagrees") for p in s["problems"]), s["problems"]


def test_report_command_rewrites_reports(processed, tmp_path):
    import shutil

    src = processed[0] / "seneca"
    d = tmp_path / "seneca"
    shutil.copytree(src, d)
    (d / "report.html").unlink()
    r = subprocess.run(
        [sys.executable, "-m", "subpix_ros.cli", "report", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stderr
    text = (d / "report.html").read_text()
    assert "Flight report: seneca" in text and "http" not in text.lower().replace("http-equiv", "")
    # the run cut its crops as the sets arrived; cut again from the PNGs they are the same
    assert text == (src / "report.html").read_text()
    r = subprocess.run(
        [sys.executable, "-m", "subpix_ros.cli", "report", str(tmp_path / "empty")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 1 and r.stderr.count("\n") == 1


def _report(folder, timeout=120):
    return subprocess.run(
        [sys.executable, "-m", "subpix_ros.cli", "report", str(folder)],
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def test_report_of_a_flight_whose_summary_is_corrupt_says_so(processed, tmp_path):
    """A truncated summary.json: "unreadable (why)", not "no summary.json"; not passed over.

    On a parent folder the other flights are reported, the corrupt one gets its line on
    stderr and the exit status is 1 (was: skipped without a word, exit 0).
    """
    for name in ("seneca", "subpixel"):
        shutil.copytree(processed[0] / name, tmp_path / name)
        (tmp_path / name / "report.html").unlink()
    corrupt = tmp_path / "seneca" / "summary.json"
    corrupt.write_text(corrupt.read_text()[:200])  # cut short, as by a full disk or a copy
    r = _report(tmp_path / "seneca")
    assert r.returncode == 1, r.stderr
    said = f"subpix report: error: cannot report {tmp_path / 'seneca'}: summary.json unreadable ("
    lines = r.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith(said) and lines[0].endswith(")"), r.stderr
    try:  # json's own why, wherever the cut fell
        json.loads(corrupt.read_text())
        raise AssertionError("the cut summary.json still reads")
    except ValueError as exc:
        why = str(exc)
    assert "no summary.json" not in r.stderr and f"unreadable ({why})" in r.stderr, r.stderr
    r = _report(tmp_path)
    assert r.returncode == 1, r.stderr
    assert r.stdout.split() == [str(tmp_path / "subpixel" / "report.html")], r.stdout
    lines = r.stderr.splitlines()
    assert len(lines) == 1 and f"{tmp_path / 'seneca'}: summary.json unreadable (" in lines[0]
    assert (tmp_path / "subpixel" / "report.html").is_file()
    assert not (tmp_path / "seneca" / "report.html").exists()


def test_report_of_a_flight_with_products_deleted_says_which(processed, tmp_path):
    """Products deleted after the run: the report's header and sections name them, stderr one line.

    Was: exit 0, "status ok" and "No aligned frame: no shift to show" beside 21 aligned
    frames, and only OpenCV's own imread warnings on stderr.
    """
    d = tmp_path / "subpixel"
    shutil.copytree(processed[0] / "subpixel", d)
    first_set = sorted((d / "superres").iterdir())[0].name
    gone = ["shifts.csv", "results.mcap", "mosaic.png", f"superres/{first_set}"]
    for name in gone:
        (d / name).unlink()
    r = _report(d)
    assert r.returncode == 1, r.stdout + r.stderr
    lines = r.stderr.splitlines()
    assert len(lines) == 1 and all(name in lines[0] for name in gone), r.stderr
    assert "WARN" not in r.stderr and "imread" not in r.stderr, r.stderr
    html = (d / "report.html").read_text()
    header = html[: html.index("<h2>Shift trajectory</h2>")]
    assert "missing since" in header and all(name in header for name in gone), header
    sections = dict(re.findall(r"<h2>([^<]+)</h2>(.*?)(?=<h2>|</body>)", html, re.S))
    assert "shifts.csv: no shift to show" in sections["Shift trajectory"]
    assert "No aligned frame" not in html
    assert f"superres/{first_set}: the set" in sections["Super-resolution"]
    assert "mosaic.png: not shown" in sections["Mosaic and track"]
    # the products all there: nothing said, exit 0
    shutil.copytree(processed[0] / "subpixel", tmp_path / "intact" / "subpixel")
    r = _report(tmp_path / "intact")
    assert r.returncode == 0 and not r.stderr, r.stderr


def test_mono16_flight_gives_16_bit_products(sample_bags, tmp_path):
    """A 16-bit camera: super-resolved and bicubic PNGs stay 16-bit, the mosaic preview is 8-bit."""
    _, frames, tel = _sample(sample_bags)
    mono = []
    for m in frames:
        img, _ = cdr_to_image(m.raw)
        y = cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_BGR2GRAY).astype(np.uint16) * 257
        mono.append(
            type(m)(
                m.topic,
                m.msgtype,
                m.timestamp_ns,
                image_to_cdr(y, "mono16", m.timestamp_ns, "camera"),
            )
        )
    bag = _write(tmp_path / "mono16", sorted(mono + tel, key=lambda m: m.timestamp_ns))
    r = _run(str(bag), "-o", str(tmp_path / "out"), "--params", DEMO, "--quiet")
    assert r.returncode == 0, r.stderr
    d = tmp_path / "out" / "mono16"
    s = _summary(d)
    assert s["camera"]["dtype"] == "uint16" and len(s["sets"]) >= 2
    for st in s["sets"]:
        sr = cv2.imread(str(d / st["superres"]), cv2.IMREAD_UNCHANGED)
        bic = cv2.imread(str(d / st["bicubic"]), cv2.IMREAD_UNCHANGED)
        assert sr.dtype == bic.dtype == np.uint16 and sr.shape == bic.shape == (896, 896)
        assert sr.max() > 255 * 4  # the 16-bit range is used, not 8-bit values in a 16-bit file
    mos = cv2.imread(str(d / "mosaic.png"), cv2.IMREAD_UNCHANGED)
    assert mos.dtype == np.uint8 and s["mosaic"]["written"]
    srs = list(read_messages(d / "results.mcap", ["/super_resolved/compressed"]))
    assert cdr_to_compressed_msg(srs[0].raw).format == "mono16; png compressed mono16"
    img, _ = cdr_to_compressed(srs[0].raw)
    assert img.dtype == np.uint16 and np.array_equal(
        img, cv2.imread(str(d / s["sets"][0]["superres"]), cv2.IMREAD_UNCHANGED)
    )


def test_progress_bars_on_a_terminal_plain_lines_otherwise():
    import io

    from subpix_ros.process.batch import Progress

    tty = io.StringIO()
    p = Progress(stream=tty, tty=True)
    for k in range(1, 11):
        p.update("flight", k, 10)
    p.finish("flight", "flight: ok")
    text = tty.getvalue()
    assert "flight" in text and "10/10" in text and "frame/s" in text and "\r" in text  # a tqdm bar
    plain = io.StringIO()
    p = Progress(stream=plain, tty=False)
    for k in range(1, 11):
        p.update("flight", k, 10)
    lines = plain.getvalue().splitlines()
    assert lines[0].startswith("flight: 1/10 frames") and lines[-1].startswith(
        "flight: 10/10 frames (100 %)"
    )
    assert len(lines) == 2 and "\r" not in plain.getvalue()  # first and last only (period 5 s)
    quiet = io.StringIO()
    p = Progress(stream=quiet, quiet=True)
    p.update("flight", 1, 10)
    p.finish("flight", "flight: ok")
    assert quiet.getvalue() == ""


def test_serve_shows_the_processing_live_to_a_foxglove_client(sample_bags, tmp_path):
    """Serve the processing live to a Foxglove client (`subpix process --serve`).

    `subpix process --serve`: a foxglove.sdk.v1 client connected while the bag is processed
    gets the camera, the GPS fix and the shifts, the same values as the products' shifts.csv.
    """
    import re
    import socket

    from subpix_ros.monitor.client import FoxgloveClient

    with socket.socket() as s:  # a port the user names, as they would (0 hid a double bind)
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    out = tmp_path / "out"
    proc = subprocess.Popen(
        process_cmd(
            str(sample_bags / "subpixel"),
            "-o",
            str(out),
            "--params",
            DEMO,
            "--quiet",
            "--serve",
            str(port),
        ),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    client = None
    try:
        line = proc.stderr.readline()
        m = re.search(r"ws://127\.0\.0\.1:(\d+)", line)
        assert m and int(m.group(1)) == port, line + proc.stderr.read()
        client = FoxgloveClient(f"ws://127.0.0.1:{m.group(1)}")
        assert client.wait(lambda: client.messages("/shift"), 120), "no shift served"
        assert client.wait(lambda: client.messages("/camera") and client.messages("/fix"), 30)

        def health_rows():
            msgs = client.messages("/health")
            nodes = client.decode("/health", msgs[-1].payload)["nodes"] if msgs else []
            return {n["name"]: n for n in nodes}

        # the stages' statuses (as results.mcap's /diagnostics) fill the operator's health table
        assert client.wait(lambda: "registration_node" in health_rows(), 30), health_rows()
        assert {"shift_node", "reconstruction_node"} <= set(health_rows())
        served = []
        for r in client.messages("/shift"):
            d = client.decode("/shift", r.payload)
            served.append((d["timestamp"]["sec"] * 10**9 + d["timestamp"]["nsec"], d["u"], d["v"]))
        _, err = proc.communicate(timeout=300)
    finally:
        if client is not None:
            client.close()
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    rows = {int(r["stamp_ns"]): r for r in read_csv(out / "subpixel" / "shifts.csv")}
    for stamp, u, v in served:  # served to 1e-5 px
        assert stamp in rows
        assert (
            abs(float(rows[stamp]["u_px"]) - u) <= 5.1e-6
            and abs(float(rows[stamp]["v_px"]) - v) <= 5.1e-6
        )


def test_serve_needs_one_job(sample_bags, tmp_path):
    r = _run(str(sample_bags / "subpixel"), "-o", str(tmp_path / "o"), "--jobs", "2", "--serve")
    assert r.returncode != 0 and "--serve shows one bag at a time" in r.stderr


def test_the_command_exits_quickly_with_its_output_and_status(processed, tmp_path):
    """`subpix report` / `process` end by os._exit (cli.console): output flushed, status kept.

    stdout is a pipe here (block-buffered): the report's path is printed only if the exit
    flushed it; a failing command still exits non-zero with its message.
    """
    out, _ = processed
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}  # as a user runs it

    def report(folder):
        return subprocess.run(
            [sys.executable, "-m", "subpix_ros.cli", "report", str(folder)],
            capture_output=True,
            text=True,
            timeout=300,
            env=env,
        )

    r = report(out / "subpixel")
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip().endswith("report.html"), r.stdout
    r = report(tmp_path / "nothing")
    assert r.returncode == 1 and "not a folder" in r.stderr, (r.returncode, r.stderr)


def test_sets_that_fell_back_are_said_in_the_line_and_not_counted_as_super_resolved(
    sample_bags, tmp_path
):
    """A budget nothing fits: every set is the bicubic reference, and the bag's line says so."""
    import yaml

    params = yaml.safe_load(Path(DEMO).read_text())
    rec = params.setdefault("/**/reconstruction_node", {}).setdefault("ros__parameters", {})
    rec["max_memory_mb"] = 1.0
    cfg = tmp_path / "tiny_budget.yaml"
    cfg.write_text(yaml.safe_dump(params))
    r = _run(str(sample_bags / "subpixel"), "-o", str(tmp_path / "out"), "--params", str(cfg))
    assert r.returncode == 0, r.stderr
    s = _summary(tmp_path / "out" / "subpixel")
    n = len(s["sets"])
    assert n >= 2 and all(st["fell_back"] for st in s["sets"])
    line = next(x.strip() for x in r.stdout.splitlines() if x.strip().startswith("subpixel: "))
    assert f"0 super-resolved and {n} bicubic fallbacks" in line, line
    assert f"{n} of {n} sets fell back to bicubic (bicubic upscale of the reference" in line, line


def test_a_measured_blur_given_in_a_second_params_file_is_used_and_said(
    processed, sample_bags, tmp_path
):
    """The `subpix blur` route: its parameter file after the flight's own, as with --params-file.

    The sample flight is rendered with 0.4 px and shows no straight edge: ``auto`` keeps the
    fallback (0.2 px); told 0.4 by a second file, every set uses it and gains more.
    """
    blur = tmp_path / "blur.yaml"  # the layout `subpix blur --yaml` writes
    blur.write_text('reconstruction_node:\n  ros__parameters:\n    blur_sigma: "0.400"\n')
    out = tmp_path / "out"
    r = _run(str(sample_bags / "subpixel"), "-o", str(out), "--params", DEMO, "--params", str(blur))
    assert r.returncode == 0, r.stderr
    s = _summary(out / "subpixel")
    rec = s["parameters"]["reconstruction_node"]
    assert rec["blur_sigma"] == "0.400" and rec["n_frames"] == 8  # demo.yaml's stay
    assert s["blur"]["note"].startswith("given as blur_sigma: 0.400 px")
    assert "(optics blur 0.400 px given)" in r.stdout
    auto = _summary(processed[0] / "subpixel")
    assert {st["blur_source"] for st in auto["sets"]} == {"fallback"}
    assert [st["blur_source"] for st in s["sets"]] == ["parameter"] * len(auto["sets"])
    given_gain = np.median([st["gain_db"] for st in s["sets"]])
    auto_gain = np.median([st["gain_db"] for st in auto["sets"]])
    assert given_gain > auto_gain + 2.0, (given_gain, auto_gain)


def test_camera_parameters_that_do_not_fit_the_frames_are_said_not_hidden(sample_bags, tmp_path):
    """Processed without the sample camera's parameters (a stream downscaled 2x, node defaults).

    METHODS eq. 1 with the defaults' 1.54 um pixels expects twice the motion the frames show:
    the products are made, the flight is partial (exit status 1: the telemetry's expected
    shifts are wrong), and the flight's line, ``summary.json`` and the report say which pixel
    pitch (or focal length in pixels) would fit.
    """
    out = tmp_path / "out"
    r = _run(str(sample_bags / "subpixel"), "-o", str(out))
    assert r.returncode == 1, r.stdout + r.stderr
    s = _summary(out / "subpixel")
    check = s["telemetry"]["check"]
    assert check["agrees"] is False and check["scale_off"] and not check["rotation_off"], check
    assert abs(check["scale"] - 0.5) < 0.01, check
    assert s["status"] == "partial" and s["sets"], "products are still made"
    assert s["problems"][0].startswith("telemetry disagrees: the frames moved 0.500x")
    assert "pixel_pitch_um 3.08" in s["problems"][0]
    line = next(x.strip() for x in r.stdout.splitlines() if x.strip().startswith("subpixel: "))
    assert line.startswith("subpixel: partial") and "telemetry disagrees" in line, line
    html = (out / "subpixel" / "report.html").read_text()
    assert "<li class='problem'>telemetry disagrees: the frames moved 0.500x" in html


def test_a_frozen_camera_is_said_not_advised_as_a_camera_parameter(sample_bags, tmp_path):
    """Every frame the flight's first image (a camera that froze), the telemetry as recorded."""
    _, frames, tel = _sample(sample_bags)
    first, _ = cdr_to_image(frames[0].raw)
    frozen = [
        type(m)(
            m.topic,
            m.msgtype,
            m.timestamp_ns,
            image_to_cdr(first, "bgr8", header_to_ns(cdr_to_image(m.raw)[1]), "camera"),
        )
        for m in frames
    ]
    bag = _write(tmp_path / "frozen", sorted(frozen + tel, key=lambda m: m.timestamp_ns))
    r = _run(str(bag), "-o", str(tmp_path / "out"), "--params", DEMO)
    assert r.returncode == 1, r.stdout + r.stderr
    s = _summary(tmp_path / "out" / "frozen")
    check = s["telemetry"]["check"]
    assert check["agrees"] is False and check["still"], check
    assert s["status"] == "partial", s["problems"]
    problem = next(p for p in s["problems"] if p.startswith("telemetry disagrees"))
    assert problem.startswith("telemetry disagrees: the frames did not move"), problem
    assert "a frozen camera or repeated frames?" in problem
    assert "yaw offset" not in problem and "f/a" not in problem
    line = next(x.strip() for x in r.stdout.splitlines() if x.strip().startswith("frozen: "))
    assert line.startswith("frozen: partial"), line


def test_telemetry_present_but_unusable_is_said_with_why(sample_bags, tmp_path):
    """The flight's telemetry with every height -3 m or NaN, or every velocity NaN."""
    from subpix_ros.io import cdr
    from subpix_ros.io.telemetry_msgs import TWIST, float64_cdr

    _, frames, tel = _sample(sample_bags)

    def spoilt(name, topic, raw):
        out = []
        for m in tel:
            if m.topic == topic:
                m = type(m)(m.topic, m.msgtype, m.timestamp_ns, raw(m.raw))
            out.append(m)
        return _write(tmp_path / name, sorted(frames + out, key=lambda m: m.timestamp_ns))

    def nan_velocity(raw):
        msg = cdr.deserialize(raw, TWIST)
        msg.twist.linear.x = msg.twist.linear.y = float("nan")
        return cdr.serialize(msg, TWIST)

    cases = {
        "below": ("/telemetry/height", lambda raw: float64_cdr(-3.0)),
        "nanheight": ("/telemetry/height", lambda raw: float64_cdr(float("nan"))),
        "nanvelocity": ("/telemetry/velocity", nan_velocity),
    }
    bags = [str(spoilt(name, *case)) for name, case in cases.items()]
    r = _run(*bags, "-o", str(tmp_path / "out"), "--params", DEMO)
    assert r.returncode == 1, r.stdout + r.stderr
    for name, what in (
        ("below", "have height -3 m (must be > 0)"),
        ("nanheight", "have height nan m (must be finite and > 0)"),
        ("nanvelocity", "have velocity nan m/s (must be finite)"),
    ):
        s = _summary(tmp_path / "out" / name)
        n = s["telemetry"]["samples"]  # a sample per velocity after the first height
        assert n >= len(frames), (name, n)
        said = f"telemetry unusable: {n} of {n} samples {what}"
        assert s["status"] == "partial", (name, s["problems"])
        assert s["problems"][0].startswith(said), (name, s["problems"])
        assert said in s["telemetry"]["note"]
        line = next(x.strip() for x in r.stdout.splitlines() if x.strip().startswith(name + ":"))
        assert line.startswith(f"{name}: partial") and said in line, line
        html = (tmp_path / "out" / name / "report.html").read_text()
        assert f"topics ({n} samples): {said}".replace(">", "&gt;") in html
        assert "no telemetry received" not in json.dumps(s["warnings"])


def test_frame_stamps_that_go_back_in_time_are_said(sample_bags, tmp_path):
    """Two flights: the second half stamped 1 s earlier, and every stamp in reverse order."""
    _, frames, tel = _sample(sample_bags)
    stamps = [header_to_ns(cdr_to_image(m.raw)[1]) for m in frames]

    def restamped(new):
        out = []
        for m, stamp in zip(frames, new):
            img, _ = cdr_to_image(m.raw)
            raw = image_to_cdr(img, "bgr8", stamp, "camera")
            out.append(type(m)(m.topic, m.msgtype, m.timestamp_ns, raw))
        return sorted(out + tel, key=lambda m: m.timestamp_ns)

    half = len(stamps) // 2
    jump = _write(tmp_path / "jump", restamped(stamps[:half] + [t - 10**9 for t in stamps[half:]]))
    rev = _write(tmp_path / "reversed", restamped(stamps[::-1]))
    r = _run(str(jump), str(rev), "-o", str(tmp_path / "out"), "--params", DEMO)
    assert r.returncode == 1, r.stdout + r.stderr
    for name, n, largest in (("jump", 1, "0.967 s"), ("reversed", len(stamps) - 1, "0.0333 s")):
        s = _summary(tmp_path / "out" / name)
        said = f"{n} time jump(s) back in the frames' stamps (largest {largest}): the pipeline"
        assert s["status"] == "partial", (name, s["problems"])
        assert any(p.startswith(said) for p in s["problems"]), (name, s["problems"])
        line = next(x.strip() for x in r.stdout.splitlines() if x.strip().startswith(name + ":"))
        assert line.startswith(f"{name}: partial"), line


def test_a_tlog_from_another_clock_is_said_not_silently_unused(sample_bags, tmp_path):
    """Images only in the bag, the .tlog beside it an hour off (a GCS clock, another flight)."""
    import struct

    from pymavlink import mavutil

    _, frames, _ = _sample(sample_bags)
    bag = _write(tmp_path / "flight", frames)
    log = mavutil.mavlink_connection(str(sample_bags / "subpixel.tlog"), dialect="common")
    with open(tmp_path / "flight.tlog", "wb") as out:
        while (msg := log.recv_match()) is not None:  # each record: >Q microseconds, the packet
            out.write(struct.pack(">Q", int((msg._timestamp + 3600.0) * 1e6)) + msg.get_msgbuf())
    r = _run(str(bag), "-o", str(tmp_path / "out"), "--params", DEMO)
    assert r.returncode == 1, r.stdout + r.stderr  # the telemetry could not be used: partial
    s = _summary(tmp_path / "out" / "flight")
    assert s["status"] == "partial", s["problems"]
    assert s["telemetry"]["source"] == "tlog flight.tlog" and s["telemetry"]["samples"] > 20
    problem = f"telemetry covers 0 of {len(frames)} frames"
    assert s["problems"][0].startswith(problem), s["problems"]
    assert "the telemetry starts 3598.2 s after the last frame" in s["problems"][0], s["problems"]
    assert s["telemetry"]["check"]["agrees"] is None  # no expected shift to check
    line = next(x.strip() for x in r.stdout.splitlines() if x.strip().startswith("flight: "))
    assert line.startswith("flight: partial") and problem in line, line
    html = (tmp_path / "out" / "flight" / "report.html").read_text()
    assert f"<li class='problem'>{problem}" in html


def test_a_flight_of_blank_frames_says_why_nothing_was_made(sample_bags, tmp_path):
    """The lens cap left on: dark noise frames with the flight's telemetry.

    No frame can be registered; the flight is partial (exit status 1) and its line says why no
    set was made, not only that none was.
    """
    _, frames, tel = _sample(sample_bags)
    rng = np.random.default_rng(0)
    dark = []
    for m in frames:
        img, _ = cdr_to_image(m.raw)
        noise = rng.normal(3.0, 1.0, img.shape).clip(0, 255).astype(np.uint8)
        raw = image_to_cdr(noise, "bgr8", m.timestamp_ns, "camera")
        dark.append(type(m)(m.topic, m.msgtype, m.timestamp_ns, raw))
    bag = _write(tmp_path / "capped", sorted(dark + tel, key=lambda m: m.timestamp_ns))
    r = _run(str(bag), "-o", str(tmp_path / "out"), "--params", DEMO)
    assert r.returncode == 1, r.stdout + r.stderr
    s = _summary(tmp_path / "out" / "capped")
    assert s["status"] == "partial" and s["frames"]["aligned"] == 0
    why = (
        f"no super-resolved image: no set reached min_frames (0 frames aligned to {len(frames)} "
        f"references, started by: {len(frames) - 1} x no texture: the reference frame is blank"
    )
    assert s["problems"][0].startswith(why), s["problems"]
    line = next(x.strip() for x in r.stdout.splitlines() if x.strip().startswith("capped: "))
    assert line.startswith("capped: partial") and why in line, line


def test_a_camera_that_does_not_stamp_its_images_is_said(sample_bags, tmp_path):
    """Every image stamped 0 (a driver that leaves the header empty), the telemetry as recorded."""
    _, frames, tel = _sample(sample_bags)
    unstamped = []
    for m in frames:
        img, _ = cdr_to_image(m.raw)
        raw = image_to_cdr(img, "bgr8", 0, "camera")
        unstamped.append(type(m)(m.topic, m.msgtype, m.timestamp_ns, raw))
    bag = _write(tmp_path / "nostamp", sorted(unstamped + tel, key=lambda m: m.timestamp_ns))
    r = _run(str(bag), "-o", str(tmp_path / "out"), "--params", DEMO)
    assert r.returncode == 1, r.stdout + r.stderr
    s = _summary(tmp_path / "out" / "nostamp")
    n = len(frames)
    first = f"{n - 1} of {n} frames left out: each repeats the stamp of the frame before it"
    assert s["status"] == "partial" and s["problems"][0].startswith(first), s["problems"]
    assert s["frames"]["skipped"] == n - 1 and s["frames"]["shifts"] == 0
    assert any(p.startswith("telemetry covers 0 of") for p in s["problems"])  # 1970 vs 2024
    line = next(x.strip() for x in r.stdout.splitlines() if x.strip().startswith("nostamp: "))
    assert first in line, line


def test_sets_too_small_to_reconstruct_are_said(sample_bags, tmp_path):
    """Sets too small to reconstruct are said in the line, ``summary.json`` and the report.

    References of 8 aligned frames against sets of 8 (with the reference): one frame of each
    reference is aligned and shifted, then let go in a set below min_frames.
    """
    params = tmp_path / "p.yaml"
    params.write_text(
        "registration_node:\n  ros__parameters:\n    pixel_pitch_um: 3.08\n"
        "    max_frames_per_reference: 8\n"
        "reconstruction_node:\n  ros__parameters:\n    n_frames: 8\n"
    )
    r = _run(str(sample_bags / "subpixel"), "-o", str(tmp_path / "out"), "--params", str(params))
    assert r.returncode == 0, r.stdout + r.stderr  # the products are what they are: ok
    s = _summary(tmp_path / "out" / "subpixel")
    rec = s["stages"]["reconstruction_node"]
    assert rec["sets_dropped"] >= 1, rec
    used = s["parameters_in_effect"]  # the run's values, given and default, for the report
    assert used["registration_node"]["max_frames_per_reference"] == 8
    assert (
        used["reconstruction_node"]["min_frames"] == 4 and "n_points" in used["registration_node"]
    )
    said = next(p for p in s["problems"] if "too small to reconstruct" in p)
    assert said.startswith(f"{rec['sets_dropped']} set") and "< min_frames 4" in said, said
    assert f"{rec['dropped']} aligned frame" in said, said
    html = (tmp_path / "out" / "subpixel" / "report.html").read_text()
    assert "too small to reconstruct" in html


def test_frames_lost_before_the_bag_are_said(sample_bags, tmp_path):
    """Frames lost before the bag are named in the flight's line; the products are made.

    Four frames missing from the middle of the camera's stream (a driver or recorder that could
    not keep up).
    """
    _, frames, tel = _sample(sample_bags)
    kept = frames[:10] + frames[14:]
    bag = _write(tmp_path / "gappy", sorted(kept + tel, key=lambda m: m.timestamp_ns))
    r = _run(str(bag), "-o", str(tmp_path / "out"), "--params", DEMO)
    assert r.returncode == 0, r.stdout + r.stderr
    s = _summary(tmp_path / "out" / "gappy")
    said = next(p for p in s["problems"] if "gap" in p)
    assert said.startswith("1 gap in the camera's stream (about 4 frames missing"), said
    assert s["sets"], "the products are made"
