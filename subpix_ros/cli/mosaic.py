"""``subpix mosaic FRAME... -o mosaic.png``: incremental overview mosaic, seam residuals."""

from __future__ import annotations

import argparse

import cv2

from . import CliError

#: Default bound on the offline mosaic's side (px). The live preview (mosaic_node) keeps its own,
#: smaller bound; offline the mosaic keeps the input resolution up to this size.
MAX_SIZE_DEFAULT = 16384


def run(args: argparse.Namespace) -> int:
    """Build the mosaic of the given frames, print each seam residual and write the image."""
    from ..core.mosaic import Mosaic

    if len(args.frames) < 2:
        raise CliError("need at least two frames")
    if args.max_size < 64:
        raise CliError(f"--max-size must be at least 64, got {args.max_size}")
    # scale=1: the canvas starts at the input resolution; it shrinks only beyond max_size
    mosaic = Mosaic(max_size_px=args.max_size, scale=1.0)
    n_ok = 0
    scale = 1.0
    print("frame  ok  inliers  rms_px  seam_px  overlap_px  time_ms  file")
    for i, path in enumerate(args.frames):
        img = cv2.imread(path, cv2.IMREAD_COLOR)
        if img is None:
            raise CliError(f"cannot read image {path!r}")
        update = mosaic.add(img)
        n_ok += update.ok
        rms = "-" if update.rms_px is None else f"{update.rms_px:.3f}"
        seam = "-" if update.seam_residual_px is None else f"{update.seam_residual_px:.3f}"
        over = "-" if update.overlap_residual_px is None else f"{update.overlap_residual_px:.3f}"
        print(
            f"{i:5d}  {'yes' if update.ok else 'NO ':3s} {update.inliers:7d}  "
            f"{rms:>6s}  {seam:>7s}  "
            f"{over:>10s}  "
            f"{update.time_s * 1000:7.0f}  {path}" + ("" if update.ok else f"  ({update.reason})")
        )
        if mosaic.scale < scale - 1e-9:
            scale = mosaic.scale
            h, w = mosaic.image().shape[:2]
            print(
                f"       scaled to {scale:.3f} canvas px per frame px ({w}x{h}) to stay within "
                f"--max-size {args.max_size}"
            )
    if not cv2.imwrite(args.output, mosaic.image()):
        raise CliError(f"cannot write {args.output!r}")
    print(
        f"{n_ok}/{len(args.frames)} frames in the mosaic -> {args.output} "
        f"({mosaic.image().shape[1]}x{mosaic.image().shape[0]}, "
        f"scale {mosaic.scale:.3f} canvas px per frame px)"
    )
    if n_ok < 2:
        raise CliError("no frame could be registered to its predecessor")
    return 0


def register(sub) -> None:
    """Add the ``subpix mosaic`` subcommand to the CLI's subparsers ``sub``."""
    parser = sub.add_parser(
        "mosaic",
        help="build an overview mosaic from consecutive overlapping frames",
        description="Register each frame to its predecessor and draw it onto one canvas at the "
        "input resolution (1 canvas px per px of the first frame), up to --max-size px on a side "
        f"(default "
        f"{MAX_SIZE_DEFAULT}); a larger mosaic is scaled down to fit, and the command says so.",
    )
    parser.add_argument("frames", nargs="+", help="frames in flight order")
    parser.add_argument("-o", "--output", required=True, help="mosaic image to write (PNG)")
    parser.add_argument(
        "--max-size",
        type=int,
        default=MAX_SIZE_DEFAULT,
        help=f"maximum canvas side, px (default {MAX_SIZE_DEFAULT}; a bgr8 canvas of that size "
        "takes 3 bytes per px: 805 MB at 16384x16384)",
    )
    parser.set_defaults(func=run)
