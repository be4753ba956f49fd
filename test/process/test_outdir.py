"""`subpix process`'s output folder as it really is.

What it must never replace, a full disk, another run writing it, products deleted by hand, and
the command line around it.

Found by an outside trial (wave 2 session 23); each test fails on the code before.
"""

import fcntl
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from subpix_ros.io.bags import BagWriter, read_messages

ROOT = Path(__file__).resolve().parents[2]
DEMO = str(ROOT / "config" / "demo.yaml")


def _run(*args, timeout=600):
    cmd = [sys.executable, "-m", "subpix_ros.cli", "process", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)


def _tree(folder: Path) -> dict[str, int]:
    return {str(p.relative_to(folder)): p.stat().st_size for p in folder.rglob("*") if p.is_file()}


@pytest.fixture()
def quick_bag(sample_bags, tmp_path):
    """Return a bag of the sample flight's telemetry only (processed in a second: partial)."""
    msgs = [m for m in read_messages(sample_bags / "subpixel") if m.topic.startswith("/telemetry/")]
    bag = tmp_path / "bags" / "flight"
    bag.parent.mkdir()
    with BagWriter(bag, storage="mcap") as w:
        for m in msgs:
            w.write(m.topic, m.msgtype, m.timestamp_ns, m.raw)
    return bag


def test_the_bag_itself_is_never_replaced_by_its_products(sample_bags, tmp_path):
    """OUTDIR = the bag's own parent folder: OUTDIR/<name> is the bag (was: deleted, exit 0)."""
    bag = tmp_path / "flights" / "subpixel"
    shutil.copytree(sample_bags / "subpixel", bag)
    before = _tree(bag)
    for extra in ([], ["--force"]):
        r = _run(str(bag), "-o", str(bag.parent), "--params", DEMO, *extra)
        assert r.returncode == 1, r.stdout + r.stderr
        assert "would replace the bag itself" in r.stdout, r.stdout
        assert _tree(bag) == before


def test_a_folder_of_other_files_under_the_bag_s_name_is_not_replaced(quick_bag, tmp_path):
    """OUTDIR/<name> holding a user's files: refused, even with --force (was: deleted)."""
    out = tmp_path / "out"
    mine = out / "flight"
    mine.mkdir(parents=True)
    (mine / "IMPORTANT_notes.txt").write_text("keep me")
    for extra in ([], ["--force"]):
        r = _run(str(quick_bag), "-o", str(out), *extra)
        assert r.returncode == 1
        assert "holds files that subpix process did not write (IMPORTANT_notes.txt)" in r.stdout
        assert (mine / "IMPORTANT_notes.txt").read_text() == "keep me"
    # an empty folder of that name is no one's: the products take its place
    (mine / "IMPORTANT_notes.txt").unlink()
    r = _run(str(quick_bag), "-o", str(out))
    assert (mine / "summary.json").is_file(), r.stdout + r.stderr


def test_another_bag_of_the_same_name_needs_force(quick_bag, tmp_path):
    """day1/flight then day2/flight into one OUTDIR: not replaced without --force (was: silently)."""
    out = tmp_path / "out"
    r = _run(str(quick_bag), "-o", str(out))
    assert (out / "flight" / "summary.json").is_file(), r.stdout + r.stderr
    day2 = tmp_path / "day2" / "flight"
    day2.parent.mkdir()
    msgs = list(read_messages(quick_bag))
    with BagWriter(day2, storage="mcap") as w:
        for m in msgs[: len(msgs) // 2]:
            w.write(m.topic, m.msgtype, m.timestamp_ns, m.raw)
    r = _run(str(day2), "-o", str(out))
    assert r.returncode == 1
    assert f"holds the products of another bag, {quick_bag}" in r.stdout, r.stdout
    assert json.loads((out / "flight" / "inputs.json").read_text())["bag"] == str(quick_bag)
    r = _run(str(day2), "-o", str(out), "--force")
    assert json.loads((out / "flight" / "inputs.json").read_text())["bag"] == str(day2), r.stdout
    # the same bag moved elsewhere is the same inputs: up to date, not "another bag"
    moved = tmp_path / "moved" / "flight"
    shutil.copytree(day2, moved, copy_function=shutil.copy2)
    os.utime(moved, ns=(day2.stat().st_atime_ns, day2.stat().st_mtime_ns))
    r = _run(str(moved), "-o", str(out))
    assert "skipped, products up to date" in r.stdout, r.stdout


def test_outdir_the_bag_folder_skips_on_a_rerun(quick_bag):
    """-o BAG: batch_summary.json written into the bag is not an input (was: redone every run)."""
    r = _run(str(quick_bag), "-o", str(quick_bag))
    assert (quick_bag / "flight" / "summary.json").is_file(), r.stdout + r.stderr
    r = _run(str(quick_bag), "-o", str(quick_bag))
    assert "skipped, products up to date" in r.stdout, r.stdout


def test_products_deleted_by_hand_are_redone(sample_bags, tmp_path):
    """A super-resolved PNG, the mosaic or the report deleted: redone (was: skipped, exit 0)."""
    out = tmp_path / "out"
    args = (str(sample_bags / "subpixel"), "-o", str(out), "--params", DEMO)
    r = _run(*args, "--quiet")
    assert r.returncode == 0, r.stderr
    folder = out / "subpixel"
    sets = json.loads((folder / "summary.json").read_text())["sets"]
    for rel in (sets[0]["superres"], "mosaic.png", "report.html"):
        (folder / rel).unlink()
        r = _run(*args)
        assert f"products redone: {rel} missing" in r.stdout, r.stdout
        assert (folder / rel).is_file()
        if rel == "report.html":
            assert "report: " in r.stdout


def test_a_report_that_cannot_be_written_makes_the_flight_partial(
    sample_bags, tmp_path, monkeypatch
):
    """The report failing (a full disk): partial in the line and summary.json, no temporary file.

    (Was: "ok", exit 0, the missing report's path printed, and `.report.html.tmp` left in the
    folder; a re-run then skipped the flight as up to date.)
    """
    import errno

    from subpix_ros.process.flight import process_bag
    from subpix_ros.process.params import load_params_files

    real = Path.write_text

    def full_disk(self, text, *a, **k):
        if self.name == ".report.html.tmp":
            real(self, text[:1000], *a, **k)  # part of it written, then the disk is full
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(self, text, *a, **k)

    params = load_params_files([DEMO])
    monkeypatch.setattr(Path, "write_text", full_disk)
    res = process_bag(sample_bags / "subpixel", tmp_path, params)
    monkeypatch.undo()
    folder = tmp_path / "subpixel"
    assert res.status == "partial", res.line
    assert "report not written: OSError" in res.line and "No space left" in res.line
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["status"] == "partial"
    assert any("report not written" in p for p in summary["problems"])
    assert not (folder / "report.html").exists()
    assert not list(folder.glob(".*")), list(folder.glob(".*"))
    # a re-run redoes the flight (its report is missing)
    res = process_bag(sample_bags / "subpixel", tmp_path, params)
    assert res.status == "ok" and "products redone: report.html missing" in res.line, res.line
    assert (folder / "report.html").is_file()


def test_a_batch_summary_that_cannot_be_written_is_one_line(quick_bag, tmp_path):
    """batch_summary.json failing to write: one line and exit 1 (was: a traceback)."""
    out = tmp_path / "out"
    (out / ".batch_summary.json.tmp").mkdir(parents=True)  # what a write then fails on
    r = _run(str(quick_bag), "-o", str(out))
    assert r.returncode == 1
    assert "Traceback" not in r.stderr, r.stderr
    assert "cannot write" in r.stderr and "batch_summary.json" in r.stderr, r.stderr


def test_a_second_run_on_the_same_outdir_is_refused_while_the_first_runs(quick_bag, tmp_path):
    """Two runs on one OUTDIR: the second says so and writes nothing.

    (Was: one "failed" run whose batch_summary.json overwrote the other's.)
    """
    out = tmp_path / "out"
    out.mkdir()
    fd = os.open(out, os.O_RDONLY)  # as a running `subpix process` holds it
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        r = _run(str(quick_bag), "-o", str(out))
    finally:
        os.close(fd)
    assert r.returncode == 1
    assert f"another subpix process is writing {out}" in r.stderr, r.stderr
    assert list(out.iterdir()) == []
    r = _run(str(quick_bag), "-o", str(out))  # the lock went with the first run
    assert (out / "flight" / "summary.json").is_file(), r.stdout + r.stderr
    assert [p.name for p in out.iterdir() if p.name.startswith(".")] == []


def test_command_line_mistakes_are_one_line(quick_bag, tmp_path):
    """A binary params file, an empty -o, a misspelt option, --quiet on a failing bag."""
    png = tmp_path / "pic.png"
    png.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)))
    r = _run(str(quick_bag), "-o", str(tmp_path / "o"), "--params", str(png))
    assert r.returncode != 0 and "Traceback" not in r.stderr, r.stderr
    assert f"cannot read parameters {png}: not a YAML text file" in r.stderr
    r = _run(str(quick_bag), "-o", "")
    assert r.returncode != 0 and "-o/--out is empty" in r.stderr, r.stderr
    r = _run(str(quick_bag), "-o", str(tmp_path / "o"), "--forse")
    assert r.returncode == 2
    assert "usage: subpix process" in r.stderr and "unrecognized arguments: --forse" in r.stderr
    r = _run(str(png), "-o", str(tmp_path / "o"), "--quiet")
    assert r.returncode == 1
    assert "pic: failed: " in r.stderr, r.stderr  # the reason, not only the bag's name
