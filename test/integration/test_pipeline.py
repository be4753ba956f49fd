"""The sample flights replayed through the nodes in separate processes, and through `pipeline`.

Real rclpy and Fast DDS: every node is its own process, `subpix replay` is
another, and this test process listens to the public topics.
"""

import json
import subprocess
import sys

import cv2
import numpy as np
import pytest
import rclpy
from conftest import ROOT, node_process, spin, subpix_cmd
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Vector3Stamped
from sensor_msgs.msg import CompressedImage, Image

from subpix_ros.cli._ros import stop_processes as _stop
from subpix_ros.core.evaluate import gain_over_bicubic, truth_on_grid, wrapped_error
from subpix_ros.io import cdr
from subpix_ros.io.bags import read_messages
from subpix_ros.nodes.qos import latched_qos, reliable_qos

PARAMS = str(ROOT / "config" / "demo.yaml")


def _node(name, *extra):
    return node_process(name, PARAMS, *extra)


class Outputs:
    def __init__(self, node):
        self.shifts, self.sr, self.mosaic, self.mosaic_c, self.refs = [], [], [], [], []
        self.diag = {}  # node name -> its latest /diagnostics values (for failure messages)
        self.node = node
        self.subs = [
            node.create_subscription(
                DiagnosticArray,
                "/diagnostics",
                lambda m: self.diag.update(
                    {s.name: {kv.key: kv.value for kv in s.values} for s in m.status}
                ),
                50,
            ),
            node.create_subscription(
                Image,
                "/aligned/reference",
                lambda r: self.refs.append(cdr.header_to_ns(cdr.cdr_to_image_msg(r).header)),
                latched_qos(),
                raw=True,
            ),
            node.create_subscription(
                Vector3Stamped,
                "/shift",
                lambda r: self.shifts.append(cdr.cdr_to_vector3_stamped(r)),
                reliable_qos(100),
                raw=True,
            ),
            node.create_subscription(
                Image,
                "/super_resolved",
                lambda r: self.sr.append(cdr.cdr_to_image(r)),
                reliable_qos(10),
                raw=True,
            ),
            node.create_subscription(
                Image,
                "/mosaic",
                lambda r: self.mosaic.append(cdr.cdr_to_image(r)),
                latched_qos(),
                raw=True,
            ),
            node.create_subscription(
                CompressedImage,
                "/mosaic/compressed",
                lambda r: self.mosaic_c.append(cdr.cdr_to_compressed(r)),
                latched_qos(),
                raw=True,
            ),
        ]

    def close(self):
        """Stop listening (what was received stays): a later run's messages are not decoded twice."""
        for sub in self.subs:
            self.node.destroy_subscription(sub)
        self.subs = []

    def report(self):
        """Return what the stages said about drops and failures (read it when a count is short)."""
        keys = (
            "input_total",
            "output_total",
            "dropped_frames",
            "queue_depth",
            "worker_errors",
            "shift_failures",
            "shifts_published",
            "warnings_total",
            "errors_total",
            "recent_problems",
        )
        return "; ".join(
            f"{name}: " + ", ".join(f"{k}={v[k]}" for k in keys if v.get(k))
            for name, v in sorted(self.diag.items())
        )


def _replay_subpixel(node, out, bags, procs, rate="0.5"):
    # the outputs' publishers must be discovered here before the flight starts
    topics = ("/aligned/reference", "/shift", "/super_resolved")
    assert spin(node, lambda: all(node.count_publishers(t) for t in topics), 30, procs=procs)
    spin(node, lambda: False, 1.0, procs=procs)
    replay = subprocess.Popen(
        subpix_cmd(
            "replay",
            str(bags / "subpixel"),
            "--rate",
            rate,
            "--topics",
            "/camera/image_raw",
            "--wait-for",
            "/camera/image_raw",
            "--wait-timeout",
            "60",
        )
    )
    assert spin(node, lambda: replay.poll() is not None, 120, procs=procs)
    assert replay.returncode == 0
    # All 21 shifts AND 3 images, not the images alone: the executor takes one message per subscription
    # per wait, so shifts published before the last image can still be queued here when it is taken.
    spin(node, lambda: len(out.sr) >= 3 and len(out.shifts) >= 21, 60, procs=procs)


def _check_subpixel(out, bags):
    truth = json.loads((bags / "subpixel" / "truth.json").read_text())
    true = {f["stamp_ns"]: (f["u"], f["v"]) for f in truth["frames"]}
    frames = {
        m.timestamp_ns: cdr.cdr_to_image(m.raw)[0]
        for m in read_messages(bags / "subpixel", ["/camera/image_raw"])
    }
    est = {cdr.header_to_ns(h): v[:2] for v, h in out.shifts}
    stamps = sorted(frames)
    assert len(est) >= 18, (
        f"only {len(est)} shifts of the 21 aligned frames (frames "
        f"{[stamps.index(s) for s in sorted(est) if s in stamps]}); {out.report()}"
    )
    assert len(out.refs) == 3  # frames 0, 8 and 16 start the three 8-frame sets

    def relative_truth(stamp):  # against the reference the frame was aligned to
        ref = max(r for r in out.refs if r <= stamp)
        return np.asarray(true[stamp]) - np.asarray(true[ref])

    err = np.array([wrapped_error(np.asarray(v), relative_truth(s)) for s, v in est.items()])
    rmse = float(np.sqrt(np.mean(err**2)))
    assert rmse <= 0.02, f"shift RMSE {rmse:.4f} px against the bag's ground truth"
    assert len(out.sr) >= 2
    truth_hr = cv2.imread(str(bags / "subpixel" / "truth_hr.png"), cv2.IMREAD_COLOR)
    gains = []
    for img, header in out.sr:
        ref = cdr.header_to_ns(header)  # the reference frame's stamp: the image is on its grid
        assert img.shape == (2 * frames[ref].shape[0], 2 * frames[ref].shape[1], 3)
        assert img.dtype == np.uint8
        t = truth_on_grid(truth_hr, true[ref], 2)
        p_sr, p_bic = gain_over_bicubic(img, frames[ref], t, 2, border=24)
        gains.append(p_sr - p_bic)
    assert min(gains) >= 2.0, f"PSNR gains over bicubic {gains}"
    return est, out.sr


@pytest.fixture(scope="module")
def ros():
    rclpy.init()
    node = rclpy.create_node("subpix_pipeline_test")
    yield node
    node.destroy_node()
    rclpy.shutdown()


def _run_layout(ros, bags, layout):
    if layout == "single":
        procs = [
            subprocess.Popen(
                [
                    sys.executable,
                    "-m",
                    "subpix_ros.nodes.pipeline",
                    "--no-telemetry",
                    "--ros-args",
                    "--params-file",
                    PARAMS,
                    "-r",
                    "image:=/camera/image_raw",
                ],
                stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
                text=True,
            )
        ]
    else:
        procs = [
            _node("registration_node", "-r", "image:=/camera/image_raw"),
            _node("shift_node"),
            _node("reconstruction_node"),
        ]
    out = Outputs(ros)
    try:
        _replay_subpixel(ros, out, bags, procs)
    finally:
        _stop(procs)
        out.close()
    return out


@pytest.fixture(scope="module")
def separate(ros, sample_bags):
    """Run the subpixel flight through registration, shift and reconstruction, one process each."""
    return _run_layout(ros, sample_bags, "separate")


def test_separate_processes_shift_and_superres(separate, sample_bags):
    _check_subpixel(separate, sample_bags)
    # each node process runs OpenCV's loops in the calling thread (runtime.configure_opencv_threads)
    threads = {name: v.get("opencv_threads") for name, v in separate.diag.items()}
    assert len(threads) >= 3 and set(threads.values()) == {"1"}, threads
    # and spins on one executor thread (nodes/run.py, SUBPIX_EXECUTOR unset)
    executors = {name: v.get("executor") for name, v in separate.diag.items()}
    assert set(executors.values()) == {"single"}, executors
    # the shift node writes no image: the small shared-memory segment; it still got every
    # aligned frame it needed from the registration node's segment (_check_subpixel above)
    profiles = {name: v.get("fastdds_profile") for name, v in separate.diag.items()}
    shift = [p for name, p in profiles.items() if "shift" in name]
    others = [p for name, p in profiles.items() if "shift" not in name]
    assert shift == ["fastdds_profile_small.xml"], profiles
    assert others and set(others) == {"fastdds_profile.xml"}, profiles
    # each node process reports its own load (CPU in cores, resident memory's peak)
    load = {
        name: (float(v["process_cpu_cores"]), float(v["process_rss_peak_mb"]))
        for name, v in separate.diag.items()
    }
    assert all(cores >= 0 and peak > 50 for cores, peak in load.values()), load


def _set_members(est, refs, ref):
    """Stamps of the frames with a shift in the set that starts at reference ``ref`` (up to the next one)."""
    later = [r for r in refs if r > ref]
    end = min(later) if later else None
    return sorted(s for s in est if s >= ref and (end is None or s < end))


def test_single_process_pipeline_gives_the_same_outputs(ros, separate, sample_bags):
    single = _run_layout(ros, sample_bags, "single")
    est, sr = _check_subpixel(single, sample_bags)
    est2 = {cdr.header_to_ns(h): v[:2] for v, h in separate.shifts}
    common = sorted(set(est) & set(est2))
    assert len(common) >= 18
    assert (
        max(float(np.max(np.abs(np.asarray(est[s]) - np.asarray(est2[s])))) for s in common) < 1e-9
    )
    by_stamp = {cdr.header_to_ns(h): img for img, h in separate.sr}
    assert by_stamp
    # A set whose frames differ between the runs (a frame dropped or without a shift in one of them: the
    # reconstruction node still uses a set of min_frames or more) gives a different image; the same
    # frames with the same shifts must give the same image, byte for byte.
    compared, differ = 0, []
    for img, h in sr:
        s = cdr.header_to_ns(h)
        if s not in by_stamp:
            continue
        mine, theirs = _set_members(est, single.refs, s), _set_members(est2, separate.refs, s)
        if mine != theirs:
            differ.append((s, sorted(set(mine) ^ set(theirs))))
            print(f"set {s}: frames differ {differ[-1][1]}")
            continue
        assert np.array_equal(img, by_stamp[s]), (
            f"set {s}: same {len(mine)} frames and shifts, different image"
        )
        compared += 1
    assert compared >= 1, (
        f"no set with the same frames in both runs to compare: {differ}; single: "
        f"{single.report()}; separate: {separate.report()}"
    )


def test_seneca_bag_produces_a_mosaic(ros, sample_bags):
    procs = [_node("mosaic_node", "-r", "image:=/camera/image_raw")]
    added = []
    ros.create_subscription(
        DiagnosticArray,
        "/diagnostics",
        lambda m: added.extend(
            int(kv.value)
            for s in m.status
            if s.name == "mosaic_node"
            for kv in s.values
            if kv.key == "frames_added"
        ),
        50,
    )
    out = Outputs(ros)
    try:
        r = subprocess.run(
            subpix_cmd(
                "replay",
                str(sample_bags / "seneca"),
                "--rate",
                "5",
                "--topics",
                "/camera/image_raw",
                "--wait-for",
                "/camera/image_raw",
            ),
            timeout=120,
        )
        assert r.returncode == 0
        assert spin(
            ros, lambda: 9 in added, 60.0, procs=procs
        )  # every frame of the strip is in the mosaic
        spin(ros, lambda: False, 2.0, procs=procs)  # and its last publication arrives
        # a late joiner (transient local) still gets the latest mosaic at once
        late = rclpy.create_node("late_operator")
        got = []
        late.create_subscription(
            Image,
            "/mosaic",
            lambda raw: got.append(cdr.cdr_to_image(raw)[0]),
            latched_qos(),
            raw=True,
        )
        spin(late, lambda: bool(got), 10.0, procs=procs)
        late.destroy_node()
    finally:
        _stop(procs)
        out.close()
    assert out.mosaic and out.mosaic_c and got
    mosaic = out.mosaic[-1][0]
    assert mosaic.ndim == 3 and max(mosaic.shape[:2]) <= 2400 and np.array_equal(got[-1], mosaic)
    covered = mosaic.max(axis=2) > 0
    assert 0.2 < covered.mean() < 0.95
    jpeg = out.mosaic_c[-1][0]
    assert jpeg.shape == mosaic.shape
