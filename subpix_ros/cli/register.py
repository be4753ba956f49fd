"""``subpix register REF MOVING [--json] [-o aligned.png]``: co-register two frames."""

from __future__ import annotations

import argparse
import json

import cv2
import numpy as np

from . import CliError


def _read(path: str) -> np.ndarray:
    img = cv2.imread(path, cv2.IMREAD_COLOR)
    if img is None:
        raise CliError(f"cannot read image {path!r}")
    return img


def run(args: argparse.Namespace) -> int:
    """Co-register MOVING to REF, print the result and write the aligned frame when asked."""
    from ..core.registration import align, register

    ref, mov = _read(args.ref), _read(args.moving)
    try:
        res = register(ref, mov, model=args.model, distortion=not args.no_distortion)
    except ValueError as exc:
        raise CliError(str(exc)) from exc
    if not res.ok:
        if args.json:
            print(json.dumps(res.as_dict()))
        raise CliError(f"registration failed: {res.reason}")
    if args.output:
        al = align(ref, mov, res)
        if not cv2.imwrite(args.output, al.aligned):
            raise CliError(f"cannot write {args.output!r}")
    if args.json:
        d = res.as_dict()
        if args.output:
            d.update(
                aligned=args.output,
                prior_shift=list(al.prior_shift),
                integer_offset=list(al.integer_offset),
                warped=al.warped,
            )
        print(json.dumps(d))
    else:
        h = res.homography
        print(
            f"inliers {res.inliers}  rms {res.rms_px:.3f} px "
            f"(projective only {res.rms_px_projective:.3f} px)  "
            f"overlap {res.overlap:.2f}  distortion lambda {res.distortion:+.4f}  "
            f"{res.time_s * 1000:.0f} ms"
        )
        ac = res.residual_along_cross()
        if ac is not None:
            hint = (
                " (mostly along: parallax of relief, not a registration error)"
                if ac[0] > 1.5 * ac[1]
                else ""
            )
            print(f"residual rms along the baseline {ac[0]:.3f} px, across {ac[1]:.3f} px{hint}")
        print("homography (MOVING px -> REF px):")
        for row in h:
            print("  " + "  ".join(f"{v: .6g}" for v in row))
        if args.output:
            print(
                f"aligned frame -> {args.output} (integer offset {al.integer_offset}, prior shift "
                f"({al.prior_shift[0]:+.3f}, {al.prior_shift[1]:+.3f}) px, warped={al.warped})"
            )
    return 0


def register(sub) -> None:  # noqa: A001 - the CLI module protocol's name
    """Add the ``subpix register`` subcommand to the CLI's subparsers ``sub``."""
    parser = sub.add_parser(
        "register", help="co-register two overlapping frames (homography moving -> ref)"
    )
    parser.add_argument("ref", help="reference frame (image file)")
    parser.add_argument("moving", help="moving frame (image file)")
    parser.add_argument("--json", action="store_true", help="print the result as one JSON object")
    parser.add_argument(
        "-o", "--output", help="write the moving frame aligned onto the reference grid"
    )
    parser.add_argument("--model", choices=("projective", "affine"), default="projective")
    parser.add_argument(
        "--no-distortion", action="store_true", help="do not estimate the radial distortion term"
    )
    parser.set_defaults(func=run)
