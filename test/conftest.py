import os
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from subpix_ros.data import CROP_NAMES, load_crop  # noqa: E402


@pytest.fixture(scope="session")
def crops():
    """Return the four real full-resolution Seneca luminance crops (uint8, 768x768)."""
    return {name: load_crop(name) for name in CROP_NAMES}


@pytest.fixture(scope="session", autouse=True)
def ros_isolation():
    """Keep this test run's DDS traffic to itself: a domain id of its own, localhost only.

    Set in os.environ so subprocesses (nodes, `subpix replay`) inherit it.
    """
    import random

    os.environ["ROS_DOMAIN_ID"] = os.environ.get(
        "SUBPIX_TEST_DOMAIN_ID", str(random.Random().randint(1, 100))
    )
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
    os.environ["PYTHONUNBUFFERED"] = "1"
    # the package's Fast DDS profile, as every entry point loads it (camera frames published from this process)
    from subpix_ros.runtime import configure_ros_environment

    configure_ros_environment()
    yield


@pytest.fixture(scope="session")
def sample_bags(tmp_path_factory):
    """Return the bundled sample flights (data/bags, built by `make sample`; here if missing)."""
    import subprocess

    bags = ROOT / "data" / "bags"
    if (
        not (bags / "subpixel" / "truth.json").is_file()
        or not (bags / "seneca" / "metadata.yaml").is_file()
    ):
        bags = tmp_path_factory.mktemp("bags")
        subprocess.run(
            [sys.executable, str(ROOT / "scripts" / "build_sample_flight.py"), "--out", str(bags)],
            check=True,
        )
    return bags


@pytest.fixture(scope="session")
def flight(sample_bags):
    """Return the 24 frames of the rendered subpixel flight as stage Frames, and its truth.

    The truth maps stamp -> (u, v).
    """
    import json

    from subpix_ros.io import cdr
    from subpix_ros.io.bags import read_messages
    from subpix_ros.stages import Frame

    frames = []
    for m in read_messages(sample_bags / "subpixel", ["/camera/image_raw"]):
        img, header = cdr.cdr_to_image(m.raw)
        frames.append(Frame(cdr.header_to_ns(header), img, header.frame_id))
    truth = json.loads((sample_bags / "subpixel" / "truth.json").read_text())
    return frames, {f["stamp_ns"]: (f["u"], f["v"]) for f in truth["frames"]}


# eight sub-pixel shifts (rows, cols; LR px) that sample a factor-2 grid well: a set of eight frames
SET_SHIFTS = [
    (0.0, 0.0),
    (0.5, 0.0),
    (0.0, 0.5),
    (0.5, 0.5),
    (0.25, 0.75),
    (0.75, 0.25),
    (0.3, 0.6),
    (0.6, 0.3),
]


def rendered_set(crop, seed=5):
    """Render eight frames of a real crop (its top-left 256 x 256) at :data:`SET_SHIFTS`.

    Factor 2, blur 0.4 LR px, 40 dB.
    """
    from subpix_ros.core.render import render_sequence

    return render_sequence(crop[:256, :256], 2, SET_SHIFTS, 0.4, snr_db=40, seed=seed)


def degraded_flight(crop_name, roof, blur, shift_seed, noise_seed):
    """Render 8 frames of a real crop by the independent degradation model (not core.render).

    Factor 2, 128 x 128 px frames of the crop at (240, 240), random shifts (``shift_seed``),
    Gaussian optics of ``blur`` LR px, full pixel, 40 dB (noise ``noise_seed``); ``roof``
    draws a sharp-edged roof in the middle.
    """
    from benchmarks.degrade_independent import degrade, scene_crop, shift_layout

    sc = scene_crop(load_crop(crop_name), 2, 128, 8, (240, 240))
    shifts = shift_layout("random", 2, seed=shift_seed)
    return degrade(sc, 2, shifts, blur, roof=roof, seed=noise_seed, margin=8)


def scene_frames(offsets, w=960, h=720):
    """Return frames of a real Seneca scene whose content moves by ``offsets[k]``.

    ``offsets[k]`` = (rows, cols) px relative to frame 0 (BGR, ``w`` x ``h``).
    """
    import cv2
    import numpy as np

    from subpix_ros.data import seneca_frame_paths

    scene = cv2.imread(str(seneca_frame_paths()[4]), cv2.IMREAD_COLOR)
    out = []
    for u, v in offsets:
        m = np.float32([[1, 0, -200 + v], [0, 1, -200 + u]])
        out.append(cv2.warpAffine(scene, m, (w, h), flags=cv2.INTER_LINEAR))
    return out


@pytest.fixture
def rclpy_node():
    """Yield one node in an initialised rclpy context in this (the test) process."""
    import rclpy

    rclpy.init()
    node = rclpy.create_node("subpix_test")
    yield node
    node.destroy_node()
    rclpy.shutdown()


def logged_popen(cmd, **kwargs):
    """Start ``cmd`` with its stdout and stderr in a log file; ``proc.stdout`` reads that file.

    Not a pipe: a node's output piped and read only at the end blocks the node once it has
    written a pipe's worth (64 KiB: a few hundred warnings from a loaded machine), and with it
    everything the test waits for. ``proc.stdout.read()`` returns what it printed so far (all of
    it once it has stopped); ``proc.log_path`` names the file. Not for ``communicate()``.
    """
    import subprocess
    import tempfile

    fd, path = tempfile.mkstemp(prefix="subpix_proc_", suffix=".log")
    with os.fdopen(fd, "w") as log:
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, text=True, **kwargs)
    proc.stdout = open(path)  # noqa: SIM115 - closed with the Popen (its __exit__ / __del__)
    proc.log_path = Path(path)
    return proc


def node_process(name: str, params: str, *extra: str):
    """Start ``subpix_ros.nodes.<name>`` as its own process with a params file (output logged)."""
    cmd = [sys.executable, "-m", f"subpix_ros.nodes.{name}", "--ros-args", "--params-file", params]
    return logged_popen([*cmd, *extra])


def subpix_cmd(*args: str) -> list[str]:
    """Return the `subpix` command line (run as a module so the checkout's code is used)."""
    return [sys.executable, "-m", "subpix_ros.cli", *args]


@dataclass
class ImageMsg:
    """A plain stand-in for sensor_msgs/Image (subpix_ros.io.images is duck-typed)."""

    height: int
    width: int
    encoding: str
    is_bigendian: int
    step: int
    data: object
    header: object = None


@pytest.fixture
def ctx():
    """Rclpy initialised for one test (the nodes under test live in this process)."""
    import rclpy

    rclpy.init()
    yield
    rclpy.shutdown()


def spin(nodes, until, timeout=10.0, executor=None, procs=()):
    """Spin ``nodes`` (a node or a list) until ``until()`` or ``timeout`` s; returns ``until()``.

    ``executor``: an executor class or factory (default: SingleThreadedExecutor for a list,
    ``rclpy.spin_once`` for one node); ``procs``: subprocesses that must stay alive meanwhile.
    """
    import time

    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    single = not isinstance(nodes, (list, tuple))
    ex = None
    if not single or executor is not None:
        ex = (executor or SingleThreadedExecutor)()
        for n in [nodes] if single else nodes:
            ex.add_node(n)
    deadline = time.monotonic() + timeout
    try:
        while time.monotonic() < deadline and not until():
            if ex is None:
                rclpy.spin_once(nodes, timeout_sec=0.05)
            else:
                ex.spin_once(timeout_sec=0.05)
            for p in procs:
                assert p.poll() is None, f"{p.args[2]} died:\n{p.stdout.read()}"
    finally:
        if ex is not None:
            for n in [nodes] if single else nodes:
                ex.remove_node(n)
    return until()


@pytest.fixture(scope="session")
def processed(sample_bags, tmp_path_factory):
    """`subpix process` of both sample flights with --jobs 2 (demo parameters): (outdir, CompletedProcess).

    Shared by test/process (the products, and the report in headless Chromium).
    """
    import subprocess

    out = tmp_path_factory.mktemp("processed")
    r = subprocess.run(
        subpix_cmd(
            "process",
            str(sample_bags / "subpixel"),
            str(sample_bags / "seneca"),
            "-o",
            str(out),
            "--params",
            str(ROOT / "config" / "demo.yaml"),
            "--jobs",
            "2",
        ),
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    return out, r


def node_diagnostics(h, node):
    """Subscribe ``h`` to /diagnostics; return (``node``'s statuses as received, ``value(key)``).

    ``value(key)`` is the latest value of ``key`` in those statuses (None before any).
    """
    from diagnostic_msgs.msg import DiagnosticArray

    diags = []
    h.create_subscription(
        DiagnosticArray,
        "/diagnostics",
        lambda m: diags.extend(s for s in m.status if s.name == node.diag.name),
        10,
    )

    def value(key):
        vals = [kv.value for s in diags for kv in s.values if kv.key == key]
        return vals[-1] if vals else None

    return diags, value


class AlignedFeed:
    """Stand in for the registration and shift nodes on ``h`` (an rclpy node).

    Publishes ``aligned/reference``, the ``aligned/reference_stamp`` links, ``aligned`` frames
    with their full masks, and ``shift``, with the QoS the real nodes use.
    """

    def __init__(self, h):
        from geometry_msgs.msg import Vector3Stamped
        from sensor_msgs.msg import Image, TimeReference

        from subpix_ros.nodes.qos import latched_qos, reliable_qos

        self.ref = h.create_publisher(Image, "/aligned/reference", latched_qos())
        self.link = h.create_publisher(TimeReference, "/aligned/reference_stamp", latched_qos(20))
        self.img = h.create_publisher(Image, "/aligned", reliable_qos(20))
        self.mask = h.create_publisher(Image, "/aligned/mask", reliable_qos(20))
        self.shift = h.create_publisher(Vector3Stamped, "/shift", reliable_qos(20))
        self.pubs = (self.ref, self.link, self.img, self.mask, self.shift)

    def matched(self) -> bool:
        return all(p.get_subscription_count() for p in self.pubs)

    def reference(self, image, stamp):
        from subpix_ros.nodes import payloads as pl

        self.ref.publish(pl.image_cdr(image, stamp))

    def frame(self, image, stamp, ref_stamp, u, v):
        """One aligned frame of reference ``ref_stamp``, its link, full mask and shift (u, v)."""
        import numpy as np

        from subpix_ros.nodes import payloads as pl

        self.link.publish(pl.reference_link_cdr(stamp, ref_stamp))
        self.img.publish(pl.image_cdr(image, stamp))
        self.mask.publish(pl.mask_cdr(np.ones(image.shape[:2], bool), stamp))
        self.shift.publish(pl.shift_cdr(pl.Shift(stamp, ref_stamp, u, v, 0.0, 0.01, 0.01)))


def dense_map(spec, ay, ax, fy, fx, c, alpha, reg, noise_power, rolloff=0.0):
    """Per-bin normal equations of eq. 9 solved one by one, float64 (the solvers' reference).

    Prior ``c |f|^-alpha`` times, with ``rolloff`` = k > 0, the roll-off ``exp(-k |f|^2)``
    (its exponent capped at ``spectrum.ROLLOFF_MAX_EXP``); DC unregularised.
    """
    import numpy as np

    from subpix_ros.core.superres import spectrum

    n, p, hp = ay.shape
    wc = ax.shape[2]
    out = np.zeros((p, p, hp, wc), complex)
    for ky in range(hp):  # reference: loops over bins on purpose
        for kx in range(wc):
            a = (ay[:, :, None, ky] * ax[:, None, :, kx]).reshape(n, p * p)
            f = np.hypot(fy[:, None, ky], fx[None, :, kx]).ravel()
            lam = reg * np.maximum(f, 1e-30) ** alpha / c
            if rolloff > 0:
                lam = lam * np.exp(np.minimum(rolloff * f**2, spectrum.ROLLOFF_MAX_EXP))
            if ky == 0 and kx == 0:
                lam[0] = 0.0
            m = a.conj().T @ a / noise_power + np.diag(lam)
            out[:, :, ky, kx] = np.linalg.solve(
                m, a.conj().T @ spec[:, ky, kx] / noise_power
            ).reshape(p, p)
    return out


def roof_frames():
    """Eight BGR frames of a real Seneca scene with a roof drawn in, sub-pixel offsets, 8 bit.

    Frame k is shifted by (0.23 k, 0.37 k) px (rows, cols); 463 x 521 px.
    """
    import cv2
    import numpy as np

    scene = cv2.imread(str(ROOT / "data" / "seneca" / "IMG_0463.jpg"), cv2.IMREAD_COLOR)
    big = cv2.resize(scene, None, fx=4, fy=4, interpolation=cv2.INTER_CUBIC)
    roof = np.array([[1600, 1000], [2300, 1100], [2230, 1600], [1530, 1500]], np.int32)
    cv2.fillPoly(big, [roof], (200, 210, 220), lineType=cv2.LINE_AA)  # straight, slanted edges
    small = cv2.resize(big, None, fx=0.25, fy=0.25, interpolation=cv2.INTER_AREA)
    out = []
    for k in range(8):
        m = np.float32([[1, 0, -200 + 0.37 * k], [0, 1, -100 + 0.23 * k]])
        out.append(cv2.warpAffine(small, m, (521, 463), flags=cv2.INTER_CUBIC))
    return out


def assert_lazy_reads(lazy, full, n, seed):
    """Assert ``n`` random slices, the range and the whole of ``lazy`` equal those of ``full``."""
    import numpy as np

    rng = np.random.default_rng(seed)
    for _ in range(n):
        r0, c0 = rng.integers(0, 450), rng.integers(0, 500)
        r1, c1 = r0 + rng.integers(1, 140), c0 + rng.integers(1, 90)
        assert np.array_equal(lazy[r0:r1, c0:c1], full[r0:r1, c0:c1])
    assert lazy.min() == full.min() and lazy.max() == full.max()
    assert np.array_equal(np.asarray(lazy), full)


_BURST_CAMERA = """
import sys, time, numpy as np, rclpy
from sensor_msgs.msg import Image
from subpix_ros.nodes import payloads
from subpix_ros.nodes.qos import camera_qos
rclpy.init()
node = rclpy.create_node("burst_camera")
pub = node.create_publisher(Image, sys.argv[1], camera_qos(False, depth=10))
deadline = time.monotonic() + 20
while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
    time.sleep(0.05)
time.sleep(0.5)
frame = np.random.default_rng(0).integers(0, 255, (540, 960, 3), np.uint8)
for i in range(int(sys.argv[2])):
    pub.publish(payloads.image_cdr(frame, (1000 + i) * 10**9, "cam"))
    time.sleep(0.002)
time.sleep(1.0)
print("sent", pub.get_subscription_count(), flush=True)
"""


def burst_camera(topic: str, frames: int = 100):
    """Run a best-effort camera process that sends ``frames`` 960x540 bgr8 frames in a burst.

    Without the package's Fast DDS profile (as a camera driver of its own), so its 1.5 MB
    frames go over UDP fragments, not a shared-memory segment, and a burst loses some in
    transport. It waits (up to 20 s) for a subscriber first; stdout says "sent <subscribers>".
    """
    import subprocess

    env = {
        k: v
        for k, v in os.environ.items()
        if k not in ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")
    }
    return subprocess.run(
        [sys.executable, "-c", _BURST_CAMERA, topic, str(frames)],
        capture_output=True,
        text=True,
        timeout=60,
        env=env,
    )


def child_processes(parent: int) -> dict[int, str]:
    """Return the processes whose parent is ``parent`` (Linux /proc): pid -> command line."""
    out = {}
    for d in Path("/proc").iterdir():
        try:
            stat = (d / "stat").read_text() if d.name.isdigit() else ""
            if stat and int(stat.rsplit(")", 1)[1].split()[1]) == parent:
                out[int(d.name)] = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode()
        except (OSError, IndexError, ValueError):
            pass
    return out


def process_alive(pid: int) -> bool:
    """Return True while ``pid`` runs (an exited process not yet reaped, a zombie, is not)."""
    try:
        state = (Path("/proc") / str(pid) / "stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state != "Z"
