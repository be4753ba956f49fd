"""``subpix demo``: the main job on the bundled sample flights.

Starts the single-process ``pipeline`` (its own process), replays the
``subpixel`` sample flight and then the real ``seneca`` strip into it over
real DDS with ``subpix replay`` (another process), listens to the outputs in
this process and writes what an operator looks at:

* ``superres.png`` beside ``bicubic.png`` (and ``side_by_side.png``): the
  first super-resolved image and the bicubic upscale of its reference frame;
* ``mosaic.png``: the overview mosaic of the Seneca strip;
* ``shifts.csv``: per-frame shifts (and their error against the rendered
  truth) with the telemetry frame timing at that frame;
* ``summary.txt`` / ``summary.json``: frames in/out, PSNR gain over bicubic,
  time per stage (from /diagnostics);
* ``flights/<bag>/``: both flights through ``subpix process`` (the same stages
  in this process, without DDS), with the flight report ``report.html``,
  whose path is printed last.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

from subpix_ros.cli import CliError
from subpix_ros.cli._ros import stop_processes


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "demo",
        help="run the pipeline on the bundled sample flights and write the results",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    p.add_argument(
        "--bags", default=None, help="folder of the sample bags (default: the bundled data/bags)"
    )
    p.add_argument(
        "--rate", type=float, default=0.5, help="replay speed of the subpixel flight (default 0.5)"
    )
    p.add_argument(
        "--seneca-rate",
        type=float,
        default=4.0,
        help="replay speed of the Seneca strip (default 4)",
    )
    p.add_argument(
        "--timeout", type=float, default=240.0, help="give up after this many seconds per flight"
    )
    p.set_defaults(func=run)


class _Collector:
    """Subscribes to the pipeline's outputs and keeps what the demo writes."""

    def __init__(self, node) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import Vector3Stamped
        from sensor_msgs.msg import CompressedImage, Image
        from std_msgs.msg import Float64

        from subpix_ros.nodes.qos import latched_qos, reliable_qos

        self.lock = threading.Lock()
        self.sr: list = []
        self.shifts: list = []
        self.mosaic = None
        self.mosaic_jpeg = 0
        self.interval = None
        self.aligned = 0
        self.refs: list[int] = []
        self.diag: dict[str, dict[str, str]] = {}
        q = reliable_qos(50)
        node.create_subscription(Image, "/super_resolved", self._on_sr, latched_qos(), raw=True)
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

        img, _ = cdr.cdr_to_image(raw)
        self.mosaic = img.copy()

    def _on_mosaic_c(self, raw) -> None:
        self.mosaic_jpeg += 1

    def _on_interval(self, msg) -> None:
        self.interval = float(msg.data)

    def _on_diag(self, msg) -> None:
        for st in msg.status:
            self.diag[st.name] = {kv.key: kv.value for kv in st.values} | {"_message": st.message}


def _spin_until(node, cond, timeout: float, procs=()) -> bool:
    import rclpy

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
        if cond():
            return True
        for p in procs:
            if p.poll() is not None and p.returncode != 0:
                raise CliError(
                    f"{p.args[2] if len(p.args) > 2 else p.args[0]} exited with status {p.returncode}"
                )
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


def run(args: argparse.Namespace) -> int:
    import cv2
    import numpy as np

    from subpix_ros.cli._ros import ros_node
    from subpix_ros.core.evaluate import gain_over_bicubic, truth_on_grid, wrapped_error
    from subpix_ros.core.superres import bicubic_upscale
    from subpix_ros.data import bags_dir
    from subpix_ros.io import cdr
    from subpix_ros.io.bags import read_messages

    root = Path(__file__).resolve().parents[2]
    bags = Path(args.bags) if args.bags else bags_dir()
    for name in ("subpixel", "seneca"):
        if not (bags / name / "metadata.yaml").is_file():
            raise CliError(
                f"sample bag {bags / name} missing: run `make sample` (scripts/build_sample_flight.py)"
            )
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    truth = json.loads((bags / "subpixel" / "truth.json").read_text())
    factor = int(truth["factor"])
    frames = {m.timestamp_ns: m for m in read_messages(bags / "subpixel", [truth["topic"]])}
    true_shift = {f["stamp_ns"]: (f["u"], f["v"]) for f in truth["frames"]}
    truth_hr = cv2.imread(str(bags / "subpixel" / "truth_hr.png"), cv2.IMREAD_COLOR)
    env = dict(os.environ)
    timings: dict[str, float] = {}
    t_start = time.monotonic()
    pipeline = subprocess.Popen(_pipeline_cmd(root), env=env)
    procs = [pipeline]
    try:
        with ros_node("subpix_demo") as node:
            col = _Collector(node)
            outputs = ("/aligned/reference", "/shift", "/super_resolved", "/mosaic")
            if not _spin_until(
                node, lambda: all(node.count_publishers(t) for t in outputs), 60.0, [pipeline]
            ):
                raise CliError("the pipeline did not come up within 60 s")
            _spin_until(node, lambda: False, 1.0, [pipeline])
            # ---- flight 1: the rendered sub-pixel pass -> shifts and super-resolution
            t0 = time.monotonic()
            replay = subprocess.Popen(
                [
                    sys.executable,
                    "-m",
                    "subpix_ros.cli",
                    "replay",
                    str(bags / "subpixel"),
                    "--rate",
                    str(args.rate),
                    "--wait-for",
                    "/camera/image_raw",
                    "--wait-timeout",
                    "60",
                ],
                env=env,
            )
            procs.append(replay)
            expected_sets = len(truth["frames"]) // 8
            _spin_until(node, lambda: replay.poll() is not None, args.timeout, [pipeline])
            if replay.returncode != 0:
                raise CliError(f"replay of the subpixel flight failed (status {replay.returncode})")
            _spin_until(node, lambda: len(col.sr) >= expected_sets, args.timeout, [pipeline])
            timings["subpixel flight (s)"] = time.monotonic() - t0
            _spin_until(node, lambda: False, 1.2, [pipeline])  # one more /diagnostics round
            with col.lock:
                shifts = list(col.shifts)
                srs = list(col.sr)
                refs = sorted(col.refs)
                diag_subpixel = {k: dict(v) for k, v in col.diag.items()}
            # ---- flight 2: the real Seneca strip -> the overview mosaic
            t0 = time.monotonic()
            replay2 = subprocess.run(
                [
                    sys.executable,
                    "-m",
                    "subpix_ros.cli",
                    "replay",
                    str(bags / "seneca"),
                    "--rate",
                    str(args.seneca_rate),
                    "--topics",
                    "/camera/image_raw",
                    "--wait-for",
                    "/camera/image_raw",
                ],
                env=env,
                timeout=args.timeout,
            )
            if replay2.returncode != 0:
                raise CliError(f"replay of the seneca flight failed (status {replay2.returncode})")

            def mosaic_done() -> bool:
                d = col.diag.get("mosaic_node", {})
                return (
                    d.get("frames_added") == "9"
                    and col.mosaic is not None
                    and col.mosaic.shape[1] > 1000
                )

            _spin_until(node, mosaic_done, 60.0, [pipeline])
            time.sleep(1.5)
            _spin_until(
                node, lambda: False, 1.5, [pipeline]
            )  # let the last mosaic publication arrive
            timings["seneca flight (s)"] = time.monotonic() - t0
            diag = dict(col.diag)
            mosaic = col.mosaic
    finally:
        stop_processes(procs)

    # ---- write what the operator looks at
    summary: dict = {"frames_in": {"subpixel": len(frames), "seneca": 9}, "timing_s": timings}

    def reference_of(stamp: int) -> int | None:
        earlier = [r for r in refs if r <= stamp]
        return max(earlier) if earlier else None

    rows, errs = [], []
    for stamp, u, v, z, interval in shifts:
        ref = reference_of(stamp)
        if stamp not in true_shift or ref is None:
            continue
        tu, tv = np.subtract(
            true_shift[stamp], true_shift[ref]
        )  # truth against the frame's reference
        eu, ev = wrapped_error(np.array([u, v]), np.array([tu, tv]))
        errs.append((eu, ev))
        rows.append(
            {
                "stamp_ns": stamp,
                "reference_stamp_ns": ref,
                "u_px": f"{u:.4f}",
                "v_px": f"{v:.4f}",
                "z": f"{z:.3f}",
                "true_u_px": f"{tu:.4f}",
                "true_v_px": f"{tv:.4f}",
                "error_u_px": f"{eu:+.4f}",
                "error_v_px": f"{ev:+.4f}",
                "frame_interval_s": "" if interval is None else f"{interval:.4f}",
            }
        )
    with open(out / "shifts.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]) if rows else ["stamp_ns"])
        w.writeheader()
        w.writerows(rows)
    summary["shifts_out"] = len(rows)
    if errs:
        summary["shift_rmse_px"] = float(np.sqrt(np.mean(np.asarray(errs) ** 2)))
    summary["super_resolved_out"] = len(srs)
    gains = []
    for i, (ref_stamp, sr) in enumerate(srs):  # each image carries its reference frame's stamp
        if ref_stamp not in frames:
            continue
        ref_img = cdr.cdr_to_image(frames[ref_stamp].raw)[0]
        truth_k = truth_on_grid(truth_hr, true_shift[ref_stamp], factor)
        p_sr, p_bic = gain_over_bicubic(sr, ref_img, truth_k, factor, border=24)
        gains.append(
            {
                "reference_stamp_ns": ref_stamp,
                "psnr_sr_db": p_sr,
                "psnr_bicubic_db": p_bic,
                "gain_db": p_sr - p_bic,
            }
        )
        if i == 0:
            bic = np.dstack(
                [bicubic_upscale(ref_img[..., c].astype(np.float64), factor) for c in range(3)]
            )
            bic = np.clip(np.rint(bic), 0, 255).astype(np.uint8)
            cv2.imwrite(str(out / "superres.png"), sr)
            cv2.imwrite(str(out / "bicubic.png"), bic)
            cv2.imwrite(str(out / "side_by_side.png"), np.hstack([bic, sr]))
    summary["psnr"] = gains
    if mosaic is not None:
        cv2.imwrite(str(out / "mosaic.png"), mosaic)
        summary["mosaic_px"] = list(mosaic.shape[:2])
    stage_keys = {
        "registration_node": "registration_ms",
        "shift_node": "estimate_ms",
        "reconstruction_node": "reconstruction_ms",
        "mosaic_node": "add_ms",
    }

    def _ms(d, n, k):
        v = d.get(n, {}).get(f"{k}_p50")
        return None if v is None else round(float(v), 1)

    # each stage's median time over the flight, as its last /diagnostics reported it (machine load included)
    summary["stage_ms_subpixel"] = {
        n: _ms(diag_subpixel, n, k) for n, k in stage_keys.items() if n != "mosaic_node"
    }
    summary["stage_ms_seneca"] = {
        n: _ms(diag, n, k)
        for n, k in stage_keys.items()
        if n in ("registration_node", "mosaic_node")
    }
    summary["dropped_frames"] = {n: diag.get(n, {}).get("dropped_frames") for n in stage_keys}
    rec = diag_subpixel.get("reconstruction_node", {})
    if (
        "blur_sigma" in rec
    ):  # the blur the reconstruction used (blur_sigma: auto) and where it came from
        summary["blur"] = {
            "sigma_px": float(rec["blur_sigma"]),
            "source": rec.get("blur_source", ""),
            "reason": rec.get("blur_reason", ""),
            "rendered_px": truth.get("blur_sigma_lr_px"),
        }
    summary["elapsed_s"] = time.monotonic() - t_start
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    lines = []
    lines.append("subpix_ros demo: bundled sample flights through the pipeline over DDS")
    lines.append(
        f"  subpixel flight: {len(frames)} frames in, {len(rows)} shifts out"
        + (
            f", shift RMSE vs truth {summary['shift_rmse_px']:.4f} px"
            if "shift_rmse_px" in summary
            else ""
        )
    )
    lines.append(
        f"  super-resolved images (x{factor}): {len(srs)}; PSNR gain over bicubic of the reference frame: "
        + ", ".join(
            f"{g['gain_db']:+.2f} dB ({g['psnr_sr_db']:.2f} vs {g['psnr_bicubic_db']:.2f})"
            for g in gains
        )
    )
    if "blur" in summary:
        b = summary["blur"]
        lines.append(
            f"  optics blur used: {b['sigma_px']:.3f} px ({b['source']}: {b['reason']}); the flight was "
            f"rendered with {b['rendered_px']} px"
        )
    lines.append(f"  seneca strip: 9 frames in, mosaic {summary.get('mosaic_px', 'not produced')}")
    lines.append(
        "  time per stage (median), subpixel flight (ms, 448x448 in): "
        + ", ".join(
            f"{n.replace('_node', '')} {v}" for n, v in summary["stage_ms_subpixel"].items()
        )
    )
    lines.append(
        "  time per stage (median), seneca strip (ms, 1800x1350 in): "
        + ", ".join(f"{n.replace('_node', '')} {v}" for n, v in summary["stage_ms_seneca"].items())
    )
    lines.append(f"  frames dropped by the queues: {summary['dropped_frames']}")
    lines.append(
        f"  outputs in {out}/: superres.png, bicubic.png, side_by_side.png, mosaic.png, shifts.csv, summary.json"
    )
    text = "\n".join(lines)
    (out / "summary.txt").write_text(text + "\n")
    print(text)
    _flight_report(root, bags, out / "flights")  # prints the report's path
    if not srs or mosaic is None:
        raise CliError(
            "the demo did not produce every output (see summary.txt and the pipeline's log)"
        )
    return 0


def _flight_report(root: Path, bags: Path, out: Path) -> Path:
    """``subpix process`` of both sample flights into ``out``; prints and returns the subpixel report's path."""
    from subpix_ros.process.batch import run_batch
    from subpix_ros.process.params import load_params

    params = load_params(root / "config" / "demo.yaml")
    results = run_batch([bags / "subpixel", bags / "seneca"], out, params, force=True)
    bad = [r.line for r in results if r.status not in ("ok", "skipped")]
    if bad:
        raise CliError(f"subpix process of the sample flights: {bad[0]}")
    report = out / "subpixel" / "report.html"
    print(f"flight report: {report.resolve()}")
    return report
