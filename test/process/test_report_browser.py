"""The flight report as a person sees it: the sample flight's report.html in real headless Chromium.

Chromium is Debian's package (`make test` installs it when missing: Makefile target
`browser`). The page is loaded from a copy of report.html with a probe script appended
that writes, after the load event, how many images there are and how many did not
decode; `--dump-dom` returns the DOM with that line. Console messages (errors included)
appear on Chromium's stderr as `:CONSOLE` log lines with `--enable-logging=stderr`; the
report has no script, so any console line is a failure. The screenshot is kept in
out/test-artefacts/.
"""

import shutil
import subprocess
from pathlib import Path

import cv2
import pytest

ROOT = Path(__file__).resolve().parents[2]
ARTEFACTS = ROOT / "out" / "test-artefacts"
FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]
PROBE = """<script>
window.addEventListener('load', function () {
  var imgs = Array.prototype.slice.call(document.images);
  var bad = imgs.filter(function (i) { return !(i.complete && i.naturalWidth > 0); }).length;
  var d = document.createElement('pre');
  d.id = 'subpix-probe';
  d.textContent = 'IMAGES ' + imgs.length + ' BROKEN ' + bad;
  document.body.appendChild(d);
});
</script>"""


@pytest.fixture(scope="module")
def chromium():
    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    assert exe, (
        "chromium not found: `make test` installs Debian's chromium (Makefile target `browser`)"
    )
    return exe


def _browse(exe, url, profile, *extra, timeout=120):
    return subprocess.run(
        [exe, *FLAGS, f"--user-data-dir={profile}", *extra, url],
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def test_sample_flight_report_renders_in_chromium(processed, chromium, tmp_path):
    report = processed[0] / "subpixel" / "report.html"
    text = report.read_text()
    n_img = text.count("<img ")
    assert n_img >= 6 and "<script" not in text
    probed = tmp_path / "report_probe.html"
    probed.write_text(text.replace("</body>", PROBE + "</body>"))
    r = _browse(
        chromium,
        probed.as_uri(),
        tmp_path / "profile",
        "--enable-logging=stderr",
        "--v=0",
        "--virtual-time-budget=10000",
        "--dump-dom",
    )
    assert r.returncode == 0, r.stderr[-2000:]
    assert f"IMAGES {n_img} BROKEN 0" in r.stdout, r.stdout[-500:]
    console = [ln for ln in r.stderr.splitlines() if ":CONSOLE" in ln]
    assert console == [], console

    ARTEFACTS.mkdir(parents=True, exist_ok=True)
    shot = ARTEFACTS / "report_subpixel.png"
    shot.unlink(missing_ok=True)
    r = _browse(
        chromium,
        report.as_uri(),
        tmp_path / "profile2",
        "--hide-scrollbars",
        "--window-size=1200,5200",
        "--virtual-time-budget=10000",
        f"--screenshot={shot}",
    )
    assert r.returncode == 0 and shot.is_file(), r.stderr[-2000:]
    img = cv2.imread(str(shot))
    assert img is not None and img.shape[:2] == (5200, 1200)
    assert float(img[:4000].std()) > 20.0  # plots and pictures, not a blank page


def test_probe_detects_a_broken_image_and_a_console_error(chromium, tmp_path):
    """The check above can fail: a page with an undecodable image and a script error is caught."""
    page = tmp_path / "bad.html"
    page.write_text(
        "<html><body><img src='data:image/png;base64,AAAA'><script>nothere();</script>"
        + PROBE
        + "</body></html>"
    )
    r = _browse(
        chromium,
        page.as_uri(),
        tmp_path / "profile",
        "--enable-logging=stderr",
        "--v=0",
        "--virtual-time-budget=5000",
        "--dump-dom",
    )
    assert "IMAGES 1 BROKEN 1" in r.stdout
    assert any(":CONSOLE" in ln and "nothere" in ln for ln in r.stderr.splitlines())
