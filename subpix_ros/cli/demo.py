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
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from subpix_ros.cli import CliError
from subpix_ros.cli._demo_flights import Captured, run_flights


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``subpix demo`` subcommand to the CLI's subparsers ``sub``."""
    parser = sub.add_parser(
        "demo",
        help="run the pipeline on the bundled sample flights and write the results",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    parser.add_argument(
        "--bags", default=None, help="folder of the sample bags (default: the bundled data/bags)"
    )
    parser.add_argument(
        "--rate", type=float, default=0.5, help="replay speed of the subpixel flight (default 0.5)"
    )
    parser.add_argument(
        "--seneca-rate",
        type=float,
        default=4.0,
        help="replay speed of the Seneca strip (default 4)",
    )
    parser.add_argument(
        "--timeout", type=float, default=240.0, help="give up after this many seconds per flight"
    )
    parser.set_defaults(func=run)


@dataclass
class _Inputs:
    """The sample flights and the rendered flight's truth."""

    root: Path  # the source tree (config/demo.yaml)
    bags: Path
    out: Path
    truth: dict  # subpixel/truth.json
    factor: int
    frames: dict  # stamp (ns) -> camera message of the subpixel flight
    true_shift: dict  # stamp (ns) -> true (u, v), px
    truth_hr: Any  # the HR scene the flight was rendered from (BGR)


def _load_inputs(args: argparse.Namespace) -> _Inputs:
    """Check the sample bags are there and read the subpixel flight with its truth."""
    import cv2

    from subpix_ros.data import bags_dir
    from subpix_ros.io.bags import read_messages

    bags = Path(args.bags) if args.bags else bags_dir()
    for name in ("subpixel", "seneca"):
        if not (bags / name / "metadata.yaml").is_file():
            raise CliError(
                f"sample bag {bags / name} missing: run `make sample` "
                "(scripts/build_sample_flight.py)"
            )
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    truth = json.loads((bags / "subpixel" / "truth.json").read_text())
    return _Inputs(
        root=Path(__file__).resolve().parents[2],
        bags=bags,
        out=out,
        truth=truth,
        factor=int(truth["factor"]),
        frames={m.timestamp_ns: m for m in read_messages(bags / "subpixel", [truth["topic"]])},
        true_shift={f["stamp_ns"]: (f["u"], f["v"]) for f in truth["frames"]},
        truth_hr=cv2.imread(str(bags / "subpixel" / "truth_hr.png"), cv2.IMREAD_COLOR),
    )


def _shift_rows(inp: _Inputs, cap: Captured) -> tuple[list[dict], list]:
    """Return the shifts.csv rows and the (u, v) errors against the truth, wrapped."""
    import numpy as np

    from subpix_ros.core.evaluate import wrapped_error

    def reference_of(stamp: int) -> int | None:
        earlier = [r for r in cap.refs if r <= stamp]
        return max(earlier) if earlier else None

    rows, errs = [], []
    for stamp, u, v, z, interval in cap.shifts:
        ref = reference_of(stamp)
        if stamp not in inp.true_shift or ref is None:
            continue
        # truth against the frame's reference
        tu, tv = np.subtract(inp.true_shift[stamp], inp.true_shift[ref])
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
    return rows, errs


def _psnr_gains(inp: _Inputs, srs: list, written: list[str]) -> list[dict]:
    """Return the PSNR of each super-resolved image and of bicubic; write the first pair.

    The names of the images written are appended to ``written``.
    """
    import cv2
    import numpy as np

    from subpix_ros.core.evaluate import gain_over_bicubic, truth_on_grid
    from subpix_ros.core.superres import bicubic_upscale
    from subpix_ros.io import cdr

    factor, out = inp.factor, inp.out
    gains = []
    for i, (ref_stamp, sr) in enumerate(srs):  # each image carries its reference frame's stamp
        if ref_stamp not in inp.frames:
            continue
        ref_img = cdr.cdr_to_image(inp.frames[ref_stamp].raw)[0]
        truth_k = truth_on_grid(inp.truth_hr, inp.true_shift[ref_stamp], factor)
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
            written += ["superres.png", "bicubic.png", "side_by_side.png"]
    return gains


_STAGE_KEYS = {
    "registration_node": "registration_ms",
    "shift_node": "estimate_ms",
    "reconstruction_node": "reconstruction_ms",
    "mosaic_node": "add_ms",
}


def _stage_summary(summary: dict, cap: Captured, truth: dict) -> None:
    """Add each stage's median time, the dropped frames and the blur used to ``summary``."""

    def _ms(d, n, k):
        v = d.get(n, {}).get(f"{k}_p50")
        return None if v is None else round(float(v), 1)

    # each stage's median over the flight, as its last /diagnostics said (machine load included)
    summary["stage_ms_subpixel"] = {
        n: _ms(cap.diag_subpixel, n, k) for n, k in _STAGE_KEYS.items() if n != "mosaic_node"
    }
    summary["stage_ms_seneca"] = {
        n: _ms(cap.diag, n, k)
        for n, k in _STAGE_KEYS.items()
        if n in ("registration_node", "mosaic_node")
    }
    summary["dropped_frames"] = {n: cap.diag.get(n, {}).get("dropped_frames") for n in _STAGE_KEYS}
    reg = cap.diag_subpixel.get("registration_node", {})
    if "telemetry_check" in reg:  # METHODS eq. 1's parameters against the frames' motion
        summary["telemetry_check"] = reg["telemetry_check"]
    rec = cap.diag_subpixel.get("reconstruction_node", {})
    if "blur_sigma" in rec:  # the blur the reconstruction used (blur_sigma: auto) and its source
        summary["blur"] = {
            "sigma_px": float(rec["blur_sigma"]),
            "source": rec.get("blur_source", ""),
            "reason": rec.get("blur_reason", ""),
            "rendered_px": truth.get("blur_sigma_lr_px"),
        }


def _summary_text(summary: dict, inp: _Inputs, n_sr: int, written: list[str]) -> str:
    """Return the summary the demo prints (and writes to summary.txt).

    Parameters
    ----------
    summary : dict
        What summary.json holds.
    inp : _Inputs
        The sample flights.
    n_sr : int
        Super-resolved images received.
    written : list of str
        The names of the files the demo writes into its output folder, listed last.

    Returns
    -------
    str
        The summary's lines.
    """
    gains = summary["psnr"]
    lines = ["subpix_ros demo: bundled sample flights through the pipeline over DDS"]
    lines.append(
        f"  subpixel flight: {len(inp.frames)} frames in, {summary['shifts_out']} shifts out"
        + (
            f", shift RMSE vs truth {summary['shift_rmse_px']:.4f} px"
            if "shift_rmse_px" in summary
            else ""
        )
    )
    lines.append(
        f"  super-resolved images (x{inp.factor}): {n_sr}; "
        "PSNR gain over bicubic of the reference frame: "
        + ", ".join(
            f"{g['gain_db']:+.2f} dB ({g['psnr_sr_db']:.2f} vs {g['psnr_bicubic_db']:.2f})"
            for g in gains
        )
    )
    if "blur" in summary:
        b = summary["blur"]
        lines.append(
            f"  optics blur used: {b['sigma_px']:.3f} px ({b['source']}: {b['reason']}); "
            f"the flight was rendered with {b['rendered_px']} px"
        )
        if b["source"] == "fallback":
            lines.append(
                "  (no straight edge in this flight: measure the camera once with `subpix blur` "
                "and give the result as blur_sigma; see the README's blur section)"
            )
    if "telemetry_check" in summary:
        lines.append(f"  telemetry vs frames (registration node): {summary['telemetry_check']}")
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
    lines.append(f"  outputs in {inp.out}/: {', '.join(written)}")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    """Run the demo: both flights over DDS, the outputs written, then ``subpix process``.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed ``subpix demo`` arguments.

    Returns
    -------
    int
        0 (``subpix demo`` exits 130 when interrupted: Ctrl-C, SIGTERM and SIGHUP raise
        KeyboardInterrupt here).

    Raises
    ------
    CliError
        When a sample bag is missing, the pipeline does not come up, a replay
        fails, or an output was not produced.
    """
    import signal

    import cv2
    import numpy as np

    from subpix_ros.process.batch import interrupt_on_signals

    # Ctrl-C, SIGTERM, or the terminal closed (SIGHUP: the pipeline and replays, in sessions
    # of their own, do not get it): children stopped, "interrupted", exit status 130
    interrupt_on_signals()
    signal.signal(signal.SIGHUP, signal.getsignal(signal.SIGTERM))
    inp = _load_inputs(args)
    t_start = time.monotonic()
    cap = run_flights(inp.root, inp.bags, len(inp.truth["frames"]) // 8, args)
    out = inp.out
    summary: dict = {
        "frames_in": {"subpixel": len(inp.frames), "seneca": 9},
        "timing_s": cap.timings,
    }
    written: list[str] = []  # the files written into out/, in this order (the summary lists them)
    rows, errs = _shift_rows(inp, cap)
    with open(out / "shifts.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]) if rows else ["stamp_ns"])
        w.writeheader()
        w.writerows(rows)
    written.append("shifts.csv")
    summary["shifts_out"] = len(rows)
    if errs:
        summary["shift_rmse_px"] = float(np.sqrt(np.mean(np.asarray(errs) ** 2)))
    summary["super_resolved_out"] = len(cap.srs)
    summary["psnr"] = _psnr_gains(inp, cap.srs, written)
    if cap.mosaic is not None:
        cv2.imwrite(str(out / "mosaic.png"), cap.mosaic)
        written.append("mosaic.png")
        summary["mosaic_px"] = list(cap.mosaic.shape[:2])
    _stage_summary(summary, cap, inp.truth)
    summary["elapsed_s"] = time.monotonic() - t_start
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    written += ["summary.json", "summary.txt"]  # summary.txt: the text below, which lists it
    text = _summary_text(summary, inp, len(cap.srs), written)
    (out / "summary.txt").write_text(text + "\n")
    print(text)
    _flight_report(inp.root, inp.bags, out / "flights")  # prints the report's path
    if not cap.srs or cap.mosaic is None:
        raise CliError(
            "the demo did not produce every output (see summary.txt and the pipeline's log)"
        )
    return 0


def _flight_report(root: Path, bags: Path, out: Path) -> Path:
    """Run ``subpix process`` on both sample flights into ``out``.

    Returns
    -------
    Path
        The subpixel flight's report (its path is printed).

    Raises
    ------
    CliError
        When a flight fails.
    """
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
