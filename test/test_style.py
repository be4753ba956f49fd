"""Style, the ROS way (ros2/examples ship test_flake8.py and test_pep257.py).

ruff over the package, tests, benchmarks and scripts, with the settings in ruff.toml (100
columns, pycodestyle, pyflakes, pydocstyle with the numpy convention, import order, the
formatter's layout).
"""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PATHS = ["subpix_ros", "test", "benchmarks", "scripts"]


def _ruff() -> list[str]:
    exe = Path(sys.executable).with_name("ruff")
    if exe.is_file():
        return [str(exe)]
    found = shutil.which("ruff")
    if found is None:
        pytest.fail("ruff is not installed (requirements.txt lists it): pip install ruff")
    return [found]


def test_ruff_check():
    r = subprocess.run(_ruff() + ["check", *PATHS], cwd=ROOT, capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr


def test_ruff_format():
    r = subprocess.run(
        _ruff() + ["format", "--check", "--diff", *PATHS], cwd=ROOT, capture_output=True, text=True
    )
    assert r.returncode == 0, (r.stdout + r.stderr)[-4000:]
