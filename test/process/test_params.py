"""subpix process's stage parameters: transport keys and live-only settings left out, said.

Params files are read with rclpy's rules (``/**``, a node's own section over it); what cannot
apply is an error or said.
"""

from pathlib import Path

import pytest

from subpix_ros.process.params import live_only_notes, pipeline_params
from subpix_ros.stages import Pipeline

ROOT = Path(__file__).resolve().parents[2]


def test_a_cpu_budget_is_left_out_of_a_batch_job_and_said():
    params = {
        "reconstruction_node": {"max_cpu_cores": 0.25, "n_frames": 6, "queue_size": 1},
        "shift_node": {"queue_size": 8},
    }
    pp = pipeline_params(params)
    assert pp["reconstruction_node"] == {"n_frames": 6} and pp["shift_node"] == {}
    assert Pipeline(pp, with_mosaic=False).reconstruction.param("max_cpu_cores") == 0.0
    (note,) = live_only_notes(params)
    assert note.startswith("reconstruction_node.max_cpu_cores = 0.25 is a live setting")
    assert live_only_notes({"reconstruction_node": {"max_cpu_cores": 0.0}}) == []
    assert live_only_notes({}) == []


def test_several_params_files_each_over_the_ones_before(tmp_path):
    from subpix_ros.process.params import load_params_files

    a, b = tmp_path / "a.yaml", tmp_path / "b.yaml"
    a.write_text("reconstruction_node:\n  ros__parameters:\n    n_frames: 8\n    factor: 2\n")
    b.write_text("/reconstruction_node:\n  ros__parameters:\n    n_frames: 4\nshift_node: {}\n")
    got = load_params_files([a, b])
    assert got == {"reconstruction_node": {"n_frames": 4, "factor": 2}, "shift_node": {}}
    assert load_params_files([b, a])["reconstruction_node"]["n_frames"] == 8
    assert load_params_files([]) == {}


def _yaml(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_wildcard_keys_reach_every_node_that_declares_them(tmp_path):
    """``/**`` keys go to every node that declares them (``use_sim_time``: every node's)."""
    from subpix_ros.process.params import load_params_files

    wild = _yaml(
        tmp_path,
        "wild.yaml",
        "/**:\n  ros__parameters:\n    pixel_pitch_um: 3.08\n    n_points: 120\n"
        "    use_sim_time: true\n",
    )
    # n_points: registration_node and mosaic_node both declare it; use_sim_time: every node's
    assert load_params_files([wild]) == {
        "registration_node": {"pixel_pitch_um": 3.08, "n_points": 120},
        "mosaic_node": {"n_points": 120},
    }


def test_stacked_files_resolve_as_rclpy_resolves_them(tmp_path, ctx):
    """Every order of own, ``/**/`` and ``/**`` sections gives what a real rclpy node takes.

    rcl merges the files' sections by their name as written, each at its first appearance, and
    the node applies the matching ones in that order: a ``/**`` that first appears after the
    node's own section wins over it, and a later file's ``/**/node`` merged into an earlier
    entry loses to a plain ``node`` entry between them. (The loader had said "the node's own
    section wins whatever the order", which rclpy does not do.)
    """
    import itertools

    import rclpy

    from subpix_ros.process.params import load_params_files

    files = {
        "own": "registration_node:\n  ros__parameters:\n    pixel_pitch_um: 2.0\n",
        "any_ns": "/**/registration_node:\n  ros__parameters:\n    pixel_pitch_um: 2.5\n",
        "wild": "/**:\n  ros__parameters:\n    pixel_pitch_um: 3.08\n",
        "any_ns_2": "/**/registration_node:\n  ros__parameters:\n    pixel_pitch_um: 4.0\n",
        "both": "registration_node:\n  ros__parameters:\n    pixel_pitch_um: 5.0\n"
        "/**:\n  ros__parameters:\n    pixel_pitch_um: 6.0\n",
    }
    paths = {k: _yaml(tmp_path, f"{k}.yaml", v) for k, v in files.items()}
    orders = [list(c) for n in (1, 2, 3) for c in itertools.permutations(paths, n)]
    for order in orders:
        args = ["--ros-args"]
        for k in order:
            args += ["--params-file", str(paths[k])]
        node = rclpy.create_node("registration_node", cli_args=args)
        try:
            node.declare_parameter("pixel_pitch_um", 1.54)
            taken = node.get_parameter("pixel_pitch_um").value
        finally:
            node.destroy_node()
        ours = load_params_files([paths[k] for k in order])["registration_node"]["pixel_pitch_um"]
        assert ours == taken, (order, ours, taken)


def test_a_namespaced_section_is_the_node_s_own(tmp_path):
    from subpix_ros.process.params import ParamsError, load_params_files

    nested = _yaml(
        tmp_path,
        "nested.yaml",
        "/drone1:\n  registration_node:\n    ros__parameters:\n      pixel_pitch_um: 3.08\n"
        "/**/shift_node:\n  ros__parameters:\n    max_std_px: 0.2\n",
    )
    assert load_params_files([nested]) == {
        "registration_node": {"pixel_pitch_um": 3.08},
        "shift_node": {"max_std_px": 0.2},
    }
    two = _yaml(
        tmp_path,
        "two.yaml",
        "/drone1/registration_node:\n  ros__parameters:\n    pixel_pitch_um: 3.08\n"
        "/drone2/registration_node:\n  ros__parameters:\n    pixel_pitch_um: 1.54\n",
    )
    with pytest.raises(ParamsError, match="registration_node is given in namespace /drone1"):
        load_params_files([two])


def test_a_key_no_node_declares_is_an_error_with_a_suggestion(tmp_path):
    from subpix_ros.process.params import ParamsError, load_params_files

    cases = {
        "registration_node:\n  ros__parameters:\n    focal_lenght_mm: 9.9\n": (
            "registration_node has no parameter focal_lenght_mm (did you mean focal_length_mm?)"
        ),
        "registration_node:\n  ros__parameters:\n    n_frames: 4\n": (
            "registration_node has no parameter n_frames (a parameter of reconstruction_node)"
        ),
        "/**:\n  ros__parameters:\n    pixel_pich_um: 3.08\n": (
            "/** has pixel_pich_um, which no node of subpix process declares "
            "(did you mean pixel_pitch_um?)"
        ),
        "registraton_node:\n  ros__parameters:\n    pixel_pitch_um: 3.08\n": (
            "no node registraton_node in subpix process (did you mean registration_node?)"
        ),
        "shift_nod:\n  ros__parameters:\n    max_std_px: 0.2\n": (
            "no node shift_nod in subpix process (did you mean shift_node?)"
        ),
    }
    for i, (text, message) in enumerate(cases.items()):
        path = _yaml(tmp_path, f"bad{i}.yaml", text)
        with pytest.raises(ParamsError) as err:
            load_params_files([path])
        assert str(err.value) == f"parameters {path}: {message}"


def test_other_programs_nodes_are_ignored_with_a_warning_and_our_others_with_a_note(tmp_path):
    from subpix_ros.process.params import load_params_files

    stack = _yaml(
        tmp_path,
        "stack.yaml",
        "camera_driver:\n  ros__parameters:\n    fps: 10\n"
        "gps_node:\n  ros__parameters:\n    rate: 5\n"
        "telemetry_node:\n  ros__parameters:\n    phi_deg: 1.0\n"
        "monitor_node:\n  ros__parameters:\n    port: 9000\n"
        "/**:\n  ros__parameters:\n    robot_name: uav1\n    link_timeout_s: 3.0\n"
        "    qos_overrides:\n      /telemetry/fix:\n        subscription:\n          depth: 5\n"
        "registration_node:\n  ros__parameters:\n    pixel_pitch_um: 3.08\n",
    )
    said = []
    assert load_params_files([stack], said.append) == {
        "registration_node": {"pixel_pitch_um": 3.08}
    }
    assert said == [
        f"warning: parameters {stack}: /** has robot_name, which no node of subpix_ros "
        "declares: ignored",
        f"note: parameters {stack}: telemetry_node, monitor_node: not used, subpix process "
        "does not run these nodes",
        f"warning: parameters {stack}: camera_driver is not a node of subpix_ros: its "
        "parameters are ignored",
        f"warning: parameters {stack}: gps_node is not a node of subpix_ros: its "
        "parameters are ignored",
    ]


def test_shipped_config_files_load_and_show_only_what_is_in_effect():
    """config/*.yaml: each alone, and the onboard stack; the other nodes' files with a note."""
    from subpix_ros.process.params import (
        PROCESS_NODES,
        check_params,
        load_params_files,
        pipeline_params,
    )

    config = ROOT / "config"
    files = sorted(config.glob("*.yaml"))
    assert {f.stem for f in files} >= {"demo", "bench", "onboard", "onboard_4k", "telemetry_node"}
    for f in files:
        said = []
        params = load_params_files([f], said.append)
        check_params(params)
        assert set(params) <= set(PROCESS_NODES), f.name
        if f.stem in ("telemetry_node", "monitor_node"):
            assert params == {} and said == [
                f"note: parameters {f}: {f.stem}: not used, subpix process does not run this node"
            ]
        else:
            assert said == [], (f.name, said)
    stack = [config / "bench.yaml", config / "onboard.yaml", config / "onboard_4k.yaml"]
    pp = pipeline_params(load_params_files(stack))
    assert pp["reconstruction_node"]["n_frames"] == 8 and pp["registration_node"]["n_points"] == 150
    shown = {k for body in pp.values() for k in body}
    assert not shown & {"queue_size", "latch_output", "input_timeout_s", "camera_reliable"}
    rec = pipeline_params(load_params_files([config / "reconstruction_node.yaml"]))
    assert "latch_output" not in rec["reconstruction_node"]
    assert "input_timeout_s" not in rec["reconstruction_node"]


def test_the_node_only_tables_match_the_nodes_declarations():
    """process/params.py stays ROS-free: its tables of the nodes' own keys follow the nodes."""
    from subpix_ros.nodes.monitor_node import MonitorNode
    from subpix_ros.nodes.mosaic_node import MosaicNode
    from subpix_ros.nodes.reconstruction_node import ReconstructionNode
    from subpix_ros.nodes.registration_node import RegistrationNode
    from subpix_ros.nodes.shift_node import ShiftNode
    from subpix_ros.nodes.telemetry_node import TelemetryNode
    from subpix_ros.process import params as mod
    from subpix_ros.stages.reconstruction import solver_option_names

    nodes = {
        "registration_node": RegistrationNode,
        "shift_node": ShiftNode,
        "reconstruction_node": ReconstructionNode,
        "mosaic_node": MosaicNode,
    }
    for name, cls in nodes.items():
        declared = {p.name for p in cls.PARAMS}
        extra = solver_option_names() if name == "reconstruction_node" else set()
        assert mod.declared_params(name) == declared | extra, name
    for name, cls in {"telemetry_node": TelemetryNode, "monitor_node": MonitorNode}.items():
        assert set(mod._OTHER_NODES[name]) == {p.name for p in cls.PARAMS}, name
