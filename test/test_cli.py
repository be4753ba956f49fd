"""The `subpix` tool: every subcommand is installed, and errors are one line."""

import importlib
import subprocess

import pytest
from conftest import subpix_cmd

from subpix_ros.cli import MODULES, build_parser


@pytest.mark.parametrize("name", MODULES)
def test_every_subcommand_module_exists(name):
    importlib.import_module(f"subpix_ros.cli.{name}")


def test_help_lists_every_subcommand():
    text = build_parser().format_help()
    for name in MODULES:
        assert name in text


def test_demo_without_sample_bags_is_a_one_line_error(tmp_path):
    r = subprocess.run(
        subpix_cmd("demo", "--bags", str(tmp_path), "--out", str(tmp_path / "o")),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode != 0
    assert r.stderr.strip().count("\n") == 0 and "make sample" in r.stderr


def test_console_scripts_point_at_real_mains():
    import re
    from pathlib import Path

    setup = (Path(__file__).resolve().parents[1] / "setup.py").read_text()
    targets = re.findall(r'"(\w+)": "([\w.]+):main"', setup)
    assert {t for t, _ in targets} == {
        "telemetry_node",
        "registration_node",
        "shift_node",
        "reconstruction_node",
        "mosaic_node",
        "pipeline",
        "monitor_node",
    }
    for _, module in targets:
        assert callable(importlib.import_module(module).main)
