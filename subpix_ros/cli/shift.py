"""``subpix shift``: sub-pixel shift between two image files (METHODS.md A)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np

from subpix_ros.cli import CliError
from subpix_ros.core.luminance import luminance
from subpix_ros.core.shift import METHODS, estimate_shift


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``subpix shift`` subcommand to the CLI's subparsers ``sub``."""
    parser = sub.add_parser(
        "shift",
        help="sub-pixel shift (u rows, v columns) from REF to MOVING (METHODS.md A)",
        description="Estimate how far the scene content moved from REF to MOVING: "
        "a feature at (r, c) in REF "
        "appears at (r + u, c + v) in MOVING (pixels). "
        "Colour images are reduced to the seed's luminance "
        "0.2989 R + 0.587 G + 0.1141 B. Prints u, v, their standard errors and the fit quality.",
    )
    parser.add_argument("reference", metavar="REF", help="reference image file")
    parser.add_argument("moving", metavar="MOVING", help="moving image file (same size)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument(
        "--method",
        choices=METHODS,
        default="default",
        help="estimator (seed = the paper's single solve)",
    )
    parser.add_argument(
        "--prior", nargs=2, type=float, metavar=("U", "V"), default=None, help="starting guess (px)"
    )
    parser.add_argument(
        "--mask",
        default=None,
        metavar="MASK.png",
        help="validity mask for both frames (non-zero = valid)",
    )
    parser.set_defaults(func=run)


def _read(path: str, what: str) -> tuple[np.ndarray, str]:
    """Return an image file's luminance and its sample type as stored (``uint8`` ...)."""
    if Path(path).is_dir():
        raise CliError(f"{what} {path} is a folder: give an image file")
    if not Path(path).is_file():
        raise CliError(f"{what} file not found: {path}")
    img = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    if img is None:
        raise CliError(f"cannot read {what} image: {path}")
    if img.ndim == 3:
        order = {3: "bgr", 4: "bgra"}.get(img.shape[2])
        if order is None:
            raise CliError(f"{what} image has {img.shape[2]} channels; expected 1, 3 or 4")
        return luminance(img, order), str(img.dtype)
    return img, str(img.dtype)


def run(args: argparse.Namespace) -> int:
    """Estimate and print the sub-pixel shift between the two images."""
    ref, ref_depth = _read(args.reference, "reference")
    mov, mov_depth = _read(args.moving, "moving")
    if ref.shape != mov.shape:
        raise CliError(
            f"images differ in size: {ref.shape[1]}x{ref.shape[0]} vs {mov.shape[1]}x{mov.shape[0]}"
        )
    if ref_depth != mov_depth:
        raise CliError(
            f"images differ in bit depth ({ref_depth} vs {mov_depth}): the shift model has an "
            "intensity offset but no gain, so both must be on one scale (convert one)"
        )
    mask = None
    if args.mask:
        m, _ = _read(args.mask, "mask")
        if m.shape != ref.shape:
            raise CliError("mask size differs from the images")
        mask = m != 0
    res = estimate_shift(ref, mov, mask=mask, method=args.method, prior=args.prior)
    if args.json:
        print(json.dumps(res.as_dict()))
    if not res.ok:
        raise CliError(res.reason)
    if not args.json:
        print(f"u = {res.u:+.4f} px (rows)    +/- {res.u_std:.4f}")
        print(f"v = {res.v:+.4f} px (columns) +/- {res.v_std:.4f}")
        print(f"z = {res.z:+.3f} (intensity offset, moving - reference)")
        conv = "yes" if res.converged else "no"
        print(
            f"method {res.method}; converged: {conv} ({res.iterations} iterations); "
            f"pixels used: {res.n_pixels}; "
            f"cond(A) = {res.cond:.3g}; residual rms = {res.residual_rms:.3g}"
        )
        if res.misfit:
            print(f"warning: {res.warning}")
    return 0
