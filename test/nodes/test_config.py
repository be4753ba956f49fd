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
        for node, body in yaml.safe_load(f.read_text()).items():
            for key, value in body["ros__parameters"].items():
                p = declared[node].get(key)
                assert p is not None, f"{f.name}: {node} has no parameter {key}"
                assert p.check(value) is None, f"{f.name}: {p.check(value)}"
