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
    # setup.py's entry points are nodes/entry.py's guarded starts (test/nodes/test_entry.py);
    # each starts the ``main`` of the node module of its name
    from subpix_ros.nodes import entry

    assert len(entry.NODE_MODULES) == 7
    for name in entry.NODE_MODULES:
        assert callable(importlib.import_module(f"subpix_ros.nodes.{name}").main)
