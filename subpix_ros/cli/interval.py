"""``subpix interval``: frame interval for a 1/p pixel step (METHODS.md B, eqs. 1-2)."""

from __future__ import annotations

import argparse
import json
import math

from subpix_ros.cli import CliError
from subpix_ros.core.timing import detector_angle, frame_interval


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``subpix interval`` subcommand to the CLI's subparsers ``sub``."""
    parser = sub.add_parser(
        "interval",
        help="time between frames for a 1/p pixel step, t = a H cos(phi) / (p f V)",
        description="Frame interval from the carrier's own motion (METHODS.md B, eq. 1): "
        "t = a H cos(phi) / (p f V). "
        "phi is the angle between the detector's long axis and the ground track; "
        "--rotate uses eq. 2, "
        "phi = arctan(1 / (p - 1)).",
    )
    parser.add_argument("--height-m", type=float, required=True, help="height above ground H (m)")
    parser.add_argument("--speed-mps", type=float, required=True, help="ground speed V (m/s)")
    parser.add_argument("--focal-mm", type=float, required=True, help="focal length f (mm)")
    parser.add_argument(
        "--pixel-um", type=float, required=True, help="detector pixel pitch a (micrometres)"
    )
    parser.add_argument(
        "--p", type=float, required=True, help="sub-pixel steps per pixel (step = 1/p px), p >= 2"
    )
    group = parser.add_mutually_exclusive_group()
    group.add_argument(
        "--phi-deg", type=float, default=0.0, help="detector angle phi (degrees, default 0)"
    )
    group.add_argument(
        "--rotate", action="store_true", help="use the eq. 2 detector angle arctan(1/(p-1))"
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Print the frame interval (and the detector angle) for the given flight; return 0."""
    if args.rotate:
        try:
            phi = detector_angle(args.p)
        except ValueError as exc:
            raise CliError(str(exc)) from None
    else:
        phi = math.radians(args.phi_deg)
    result = frame_interval(
        args.pixel_um * 1e-6, args.height_m, args.focal_mm * 1e-3, args.speed_mps, args.p, phi
    )
    if args.json:
        print(json.dumps(result.as_dict()))
    if not result.ok:
        raise CliError(result.reason)
    if not args.json:
        print(f"t = {result.interval_s * 1e3:.4g} ms ({result.frame_rate_hz:.4g} frames/s)")
        print(f"phi = {result.phi_deg:.4g} deg")
        print(
            f"image motion {result.shift_px_per_s:.4g} px/s; "
            f"step per interval {result.step_px:.4g} px (cos(phi)/p)"
        )
    return 0
