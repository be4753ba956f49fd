"""subpix process's stage parameters: transport keys and live-only settings left out, said."""

from subpix_ros.process.params import live_only_notes, pipeline_params
from subpix_ros.stages import Pipeline


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
