"""config/*.yaml are the nodes' declared defaults, and every params file names real parameters."""

import sys
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "scripts"))
import gen_config  # noqa: E402


def test_default_configs_match_declarations():
    for name in gen_config.NODES:
        assert (ROOT / "config" / f"{name}.yaml").read_text() == gen_config.render(name), (
            f"config/{name}.yaml is stale: run scripts/gen_config.py"
        )


def test_every_params_file_uses_declared_names_and_types():
    import importlib

    declared = {}
    for name, target in gen_config.NODES.items():
        module, cls = target.split(":")
        declared[name] = {p.name: p for p in getattr(importlib.import_module(module), cls).PARAMS}
    for f in (ROOT / "config").glob("*.yaml"):
        for section, body in yaml.safe_load(f.read_text()).items():
            assert section.startswith("/**/"), (
                f"{f.name}: {section} applies in the root namespace only"
            )
            node = section.removeprefix("/**/")
            for key, value in body["ros__parameters"].items():
                p = declared[node].get(key)
                assert p is not None, f"{f.name}: {node} has no parameter {key}"
                assert p.check(value) is None, f"{f.name}: {p.check(value)}"


def test_the_shipped_params_files_apply_to_nodes_in_a_namespace(ctx):
    """A node started in /drone1 with a shipped params file takes its values.

    (Was: the files' keys named the root-namespace node, so under ``-r __ns:=/drone1`` every
    value was silently left at its default: pixel_pitch_um 1.54 instead of the file's 3.08.)
    """
    from subpix_ros.nodes.registration_node import RegistrationNode
    from subpix_ros.nodes.shift_node import ShiftNode

    for cls, key, file_value in (
        (RegistrationNode, "pixel_pitch_um", 3.08),
        (ShiftNode, "queue_size", 30),
    ):
        args = [
            "--ros-args",
            "-r",
            "__ns:=/drone1",
            "--params-file",
            str(ROOT / "config" / "demo.yaml"),
        ]
        node = cls(cli_args=args)
        try:
            assert node.get_fully_qualified_name().startswith("/drone1/")
            assert node.get_parameter(key).value == file_value
            assert cls.PARAMS and {p.name: p for p in cls.PARAMS}[key].default != file_value
        finally:
            node.close()
            node.destroy_node()
