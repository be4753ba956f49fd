"""Fixtures of the `subpix process` tests: the bundled sample flights processed once per session."""
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def process_cmd(*args: str) -> list[str]:
    return [sys.executable, "-m", "subpix_ros.cli", "process", *args]


@pytest.fixture(scope="session")
def processed(sample_bags, tmp_path_factory):
    """`subpix process` of both sample flights with --jobs 2 (demo parameters): (outdir, result)."""
    out = tmp_path_factory.mktemp("processed")
    r = subprocess.run(process_cmd(str(sample_bags / "subpixel"), str(sample_bags / "seneca"), "-o", str(out),
                                   "--params", str(ROOT / "config" / "demo.yaml"), "--jobs", "2"),
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    return out, r
