"""The node processes' console entry points (nodes/entry.py)."""

import ast
import subprocess
import sys
from pathlib import Path

import pytest

from subpix_ros.nodes import entry

ROOT = Path(__file__).resolve().parents[2]

# A Ctrl-C that arrives while the node module is importing rclpy: a finder raises SIGINT in the
# process at the moment rclpy is looked up, so the KeyboardInterrupt comes out of a real import.
_INTERRUPT_AT_RCLPY = """
import os, signal, sys

class Interrupt:
    def find_spec(self, name, path=None, target=None):
        if name == "rclpy":
            sys.meta_path.remove(self)
            os.kill(os.getpid(), signal.SIGINT)
        return None

sys.meta_path.insert(0, Interrupt())
"""


def _setup_entry_points() -> dict[str, str]:
    tree = ast.parse((ROOT / "setup.py").read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign) and getattr(node.targets[0], "id", "") == "NODES":
            return ast.literal_eval(node.value)
    raise AssertionError("setup.py has no NODES")


def test_every_console_entry_point_is_a_guarded_start_of_its_own_module():
    points = _setup_entry_points()
    assert set(points) == set(entry.NODE_MODULES)
    for name, target in points.items():
        assert target == f"subpix_ros.nodes.entry:{name}"
        assert callable(getattr(entry, name))


@pytest.mark.parametrize("module", ["shift_node", "pipeline"])
def test_ctrl_c_while_a_node_is_importing_is_one_line_and_status_130(module):
    code = (
        _INTERRUPT_AT_RCLPY + f"from subpix_ros.nodes.entry import {module}\nsys.exit({module}())\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 130, proc.stderr
    assert proc.stderr.strip() == f"{module}: interrupted while starting"
    assert "Traceback" not in proc.stderr


def test_the_unguarded_import_would_print_a_traceback():
    # the check above can fail: the same interrupt reaching the module import directly
    code = _INTERRUPT_AT_RCLPY + "from subpix_ros.nodes.shift_node import main\n"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert proc.returncode != 0
    assert "Traceback" in proc.stderr and "KeyboardInterrupt" in proc.stderr


def test_an_unknown_module_is_refused():
    with pytest.raises(ValueError, match="no node module"):
        entry.start("nonexistent_node")
