"""``subpix demo`` over DDS: the pipeline in its own process, the sample flights replayed into it.

What this process hears from the pipeline (shifts, super-resolved images,
references, mosaic, /diagnostics) is collected in a :class:`Captured`.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from subpix_ros.cli import CliError
from subpix_ros.cli._ros import stop_processes

__all__ = ["Captured", "mosaic_complete", "run_flights"]

#: The camera topic of the sample flights (what ``subpix replay`` sends to the pipeline).
CAMERA_TOPIC = "/camera/image_raw"


class _Collector:
    """Subscribes to the pipeline's outputs and keeps what the demo writes."""

    def __init__(self, node) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import Vector3Stamped
        from sensor_msgs.msg import CompressedImage, Image
        from std_msgs.msg import Float64

        from subpix_ros.nodes.qos import FollowingSubscription, latched_qos, reliable_qos

        self.lock = threading.Lock()
        self.sr: list = []
        self.shifts: list = []
        self.mosaic = None
        self.mosaic_stamp_ns: int | None = None  # the stamp of the last frame drawn into it
        self.mosaic_jpeg = 0
        self.interval = None
        self.aligned = 0
        self.refs: list[int] = []
        self.diag: dict[str, dict[str, str]] = {}
        q = reliable_qos(50)
        self.sr_sub = FollowingSubscription(node, Image, "/super_resolved", self._on_sr, raw=True)
        node.create_subscription(Vector3Stamped, "/shift", self._on_shift, q, raw=True)
        node.create_subscription(Image, "/aligned", self._on_aligned, q, raw=True)
        node.create_subscription(
            Image, "/aligned/reference", self._on_reference, latched_qos(), raw=True
        )
        node.create_subscription(Image, "/mosaic", self._on_mosaic, latched_qos(), raw=True)
        node.create_subscription(
            CompressedImage, "/mosaic/compressed", self._on_mosaic_c, latched_qos(), raw=True
        )
        node.create_subscription(Float64, "/telemetry/frame_interval", self._on_interval, q)
        node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, q)

    def _on_sr(self, raw) -> None:
        from subpix_ros.io import cdr

        img, header = cdr.cdr_to_image(raw)
        with self.lock:
            self.sr.append((cdr.header_to_ns(header), img.copy()))

    def _on_shift(self, raw) -> None:
        from subpix_ros.io import cdr

        vec, header = cdr.cdr_to_vector3_stamped(raw)
        with self.lock:
            self.shifts.append((cdr.header_to_ns(header), *map(float, vec), self.interval))

    def _on_aligned(self, raw) -> None:
        self.aligned += 1

    def _on_reference(self, raw) -> None:
        from subpix_ros.io import cdr

        with self.lock:
            self.refs.append(cdr.header_to_ns(cdr.cdr_to_image_msg(raw).header))

    def _on_mosaic(self, raw) -> None:
        from subpix_ros.io import cdr

        img, header = cdr.cdr_to_image(raw)
        self.mosaic = img.copy()
        self.mosaic_stamp_ns = cdr.header_to_ns(header)

    def _on_mosaic_c(self, raw) -> None:
        self.mosaic_jpeg += 1

    def _on_interval(self, msg) -> None:
        self.interval = float(msg.data)

    def _on_diag(self, msg) -> None:
        for st in msg.status:
            self.diag[st.name] = {kv.key: kv.value for kv in st.values} | {"_message": st.message}


class _SignalsDeferred:
    """Hold SIGINT and SIGTERM while the child processes are stopped, then act on one that came.

    A second Ctrl-C during :func:`~subpix_ros.cli._ros.stop_processes` would leave the
    processes not yet waited for (or a hung one not killed); held, it raises
    KeyboardInterrupt once they are all gone. Outside the main thread, nothing is held.
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self.came: list[int] = []
        self._old: dict = {}

    def __enter__(self) -> _SignalsDeferred:
        if threading.current_thread() is threading.main_thread():
            for sig in self.SIGNALS:
                self._old[sig] = signal.signal(sig, lambda signum, frame: self.came.append(signum))
        return self

    def __exit__(self, *exc) -> None:
        for sig, handler in self._old.items():
            signal.signal(sig, handler)
        if self.came and exc[0] is None:
            raise KeyboardInterrupt


def _spin_until(node, cond, timeout: float, procs=()) -> bool:
    import rclpy

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
        if cond():
            return True
        for proc in procs:
            if proc.poll() is not None and proc.returncode != 0:
                name = proc.args[2] if len(proc.args) > 2 else proc.args[0]
                raise CliError(f"{name} exited with status {proc.returncode}")
    return False


def _pipeline_cmd(root: Path) -> list[str]:
    return [
        sys.executable,
        "-m",
        "subpix_ros.nodes.pipeline",
        "--no-telemetry",
        "--ros-args",
        "-r",
        "image:=/camera/image_raw",
        "--params-file",
        str(root / "config" / "demo.yaml"),
        "--log-level",
        "error",
    ]


@dataclass
class Captured:
    """What the demo heard from the pipeline over DDS."""

    shifts: list  # (stamp_ns, u, v, z, frame interval or None)
    srs: list  # (reference stamp_ns, super-resolved BGR image)
    refs: list  # stamps of the reference frames, sorted
    diag_subpixel: dict  # /diagnostics after the subpixel flight: node -> key -> value
    diag: dict  # /diagnostics after the seneca strip
    mosaic: Any  # the last /mosaic image, or None
    timings: dict = field(default_factory=dict)


def _start(cmd: list[str], env: dict) -> subprocess.Popen:
    """Start one of the demo's processes (the pipeline, a replay) in a session of its own.

    The demo stops them itself, once each (:func:`~subpix_ros.cli._ros.stop_processes`). In
    the terminal's process group, Ctrl-C reached them as well, and the demo's own SIGINT came
    second, while the pipeline was closing: a KeyboardInterrupt traceback from its
    ``destroy_node``. The demo ends them on SIGINT, SIGTERM and SIGHUP (``subpix demo``).

    Parameters
    ----------
    cmd : list of str
        The command line.
    env : dict
        Its environment.

    Returns
    -------
    subprocess.Popen
        The process.
    """
    from subpix_ros.runtime import DIE_WITH_PARENT_ENV

    # and ended by the kernel if the demo dies without stopping them (SIGKILL)
    return subprocess.Popen(cmd, env={**env, DIE_WITH_PARENT_ENV: "1"}, start_new_session=True)


def _replay_cmd(bag: Path, rate: float, *extra: str) -> list[str]:
    """Return the ``subpix replay`` command line of one bag."""
    return [sys.executable, "-m", "subpix_ros.cli", "replay", str(bag), "--rate", str(rate), *extra]


def run_flights(root: Path, bags: Path, expected_sets: int, args) -> Captured:
    """Start the pipeline, replay both sample flights into it over DDS and collect its outputs.

    Parameters
    ----------
    root : Path
        Source tree (its ``config/demo.yaml`` configures the pipeline).
    bags : Path
        Folder of the ``subpixel`` and ``seneca`` sample bags.
    expected_sets : int
        Super-resolved images to wait for after the subpixel flight.
    args : argparse.Namespace
        ``subpix demo`` arguments (replay rates, timeout).

    Returns
    -------
    Captured
        What the pipeline published.

    Raises
    ------
    CliError
        When the pipeline does not come up, exits, or a replay fails.
    KeyboardInterrupt
        On Ctrl-C or SIGTERM (``subpix demo`` raises it for both): the pipeline and a replay
        still running have been stopped.

    Notes
    -----
    rclpy's own signal handlers are left out (``ros_node(rclpy_signals=False)``): they shut
    the context down under the spinning node, and the demo ended with a traceback of
    ``ExternalShutdownException`` (exit 1) instead of "interrupted" (130).
    """
    from subpix_ros.cli._ros import ros_node

    env = dict(os.environ)
    pipeline = _start(_pipeline_cmd(root), env)
    procs = [pipeline]
    try:
        with ros_node("subpix_demo", rclpy_signals=False) as node:
            col = _Collector(node)
            outputs = ("/aligned/reference", "/shift", "/super_resolved", "/mosaic")
            if not _spin_until(
                node, lambda: all(node.count_publishers(t) for t in outputs), 60.0, [pipeline]
            ):
                raise CliError("the pipeline did not come up within 60 s")
            _spin_until(node, lambda: False, 1.0, [pipeline])
            captured = _subpixel_flight(node, col, bags, expected_sets, args, env, procs)
            captured.diag, captured.mosaic = _seneca_flight(
                node, col, bags, args, env, procs, captured.timings
            )
            return captured
    finally:
        with _SignalsDeferred():
            stop_processes(procs)


def _subpixel_flight(
    node, col: _Collector, bags: Path, expected_sets: int, args, env, procs
) -> Captured:
    """Replay the rendered sub-pixel pass: shifts and super-resolved images."""
    pipeline = procs[0]
    t0 = time.monotonic()
    wait = ("--wait-for", "/camera/image_raw", "--wait-timeout", "60")
    replay = _start(_replay_cmd(bags / "subpixel", args.rate, *wait), env)
    procs.append(replay)
    _spin_until(node, lambda: replay.poll() is not None, args.timeout, [pipeline])
    if replay.returncode != 0:
        raise CliError(f"replay of the subpixel flight failed (status {replay.returncode})")
    _spin_until(node, lambda: len(col.sr) >= expected_sets, args.timeout, [pipeline])
    timings = {"subpixel flight (s)": time.monotonic() - t0}
    _spin_until(node, lambda: False, 1.2, [pipeline])  # one more /diagnostics round
    with col.lock:
        return Captured(
            shifts=list(col.shifts),
            srs=list(col.sr),
            refs=sorted(col.refs),
            diag_subpixel={k: dict(v) for k, v in col.diag.items()},
            diag={},
            mosaic=None,
            timings=timings,
        )


def frame_stamps(bag: Path, topic: str = CAMERA_TOPIC) -> list[int]:
    """Return the header stamps (ns) of the camera frames of ``bag``, in the bag's order.

    Parameters
    ----------
    bag : Path
        A sample flight's bag folder.
    topic : str, optional
        Its camera topic.

    Returns
    -------
    list of int
        One stamp per frame, as the pipeline's nodes see it.
    """
    from subpix_ros.io import cdr
    from subpix_ros.io.bags import read_messages

    return [
        cdr.header_to_ns(cdr.cdr_to_image_msg(m.raw).header) for m in read_messages(bag, [topic])
    ]


def mosaic_complete(mosaic_stamp_ns: int | None, mosaic_diag: dict, sent: list[int]) -> bool:
    """Tell whether the mosaic the demo received holds every frame of the flight.

    The mosaic node draws its frames in order and stamps ``/mosaic`` with the last frame
    drawn; its /diagnostics count the frames in the canvas (``frames_added``). The mosaic is
    complete once the one received carries the stamp of the flight's last frame and the node
    counts every frame sent as added. Its size says nothing: the Seneca strip is a tall
    mosaic (1786 x 687 px).

    Parameters
    ----------
    mosaic_stamp_ns : int or None
        The stamp of the latest ``/mosaic`` received (None before the first).
    mosaic_diag : dict
        The mosaic node's latest /diagnostics values (key -> str).
    sent : list of int
        The stamps of the frames the flight sent, in order (:func:`frame_stamps`).

    Returns
    -------
    bool
        True when nothing more is to come for this flight's mosaic.
    """
    if not sent or mosaic_stamp_ns is None:
        return False
    return mosaic_stamp_ns == sent[-1] and mosaic_diag.get("frames_added") == str(len(sent))


def _seneca_flight(node, col: _Collector, bags: Path, args, env, procs, timings: dict):
    """Replay the real Seneca strip: the overview mosaic; return the diagnostics and the mosaic."""
    pipeline = procs[0]
    t0 = time.monotonic()
    sent = frame_stamps(bags / "seneca")
    only_camera = ("--topics", CAMERA_TOPIC, "--wait-for", CAMERA_TOPIC)
    cmd = _replay_cmd(bags / "seneca", args.seneca_rate, *only_camera)
    replay = _start(cmd, env)
    procs.append(replay)  # stopped with the pipeline if the demo is interrupted
    _spin_until(node, lambda: replay.poll() is not None, args.timeout, [pipeline])
    if replay.returncode != 0:
        raise CliError(f"replay of the seneca flight failed (status {replay.returncode})")

    def mosaic_done() -> bool:
        return mosaic_complete(col.mosaic_stamp_ns, col.diag.get("mosaic_node", {}), sent)

    _spin_until(node, mosaic_done, 60.0, [pipeline])
    _spin_until(node, lambda: False, 1.2, [pipeline])  # one more /diagnostics round
    timings["seneca flight (s)"] = time.monotonic() - t0
    return dict(col.diag), col.mosaic
