"""``subpix superres``: super-resolve N sub-pixel shifted frames into one image.

Output grid: low-resolution pixel i of the FIRST frame covers output pixels
factor*i .. factor*i + factor - 1 (pixel centres aligned as in cv2.resize).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np

from subpix_ros.cli import CliError
from subpix_ros.cli._images import luma, read_image

HELP = """Super-resolve FRAME... (first frame = reference) by METHODS.md B.

Output grid: low-resolution pixel i of the first frame covers output pixels
factor*i .. factor*i+factor-1. Shifts (u, v) = (rows, columns) in pixels are
how far the scene moved from the first frame to each frame (a feature at
(r, c) in the first frame is at (r+u, c+v) in the frame). Colour frames:
luminance is super-resolved, chroma bicubic-upscaled from the first frame.
"""


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``subpix superres`` subcommand to the CLI's subparsers ``sub``."""
    parser = sub.add_parser(
        "superres",
        help="super-resolve sub-pixel shifted frames (METHODS.md B)",
        description=HELP,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "frames", nargs="+", metavar="FRAME", help="input images (2 or more, same size)"
    )
    parser.add_argument("--factor", type=int, default=2, help="resolution factor 2..4 (default 2)")
    parser.add_argument(
        "--method",
        default="map",
        choices=["map", "windowed", "pinv", "bicubic"],
        help="map: MAP estimate (eq. 9, default); windowed: eq. 7; pinv: eq. 6 (reference only); "
        "bicubic: the reference frame upscaled",
    )
    parser.add_argument(
        "--prior",
        default="powerlaw",
        choices=["powerlaw", "rolloff"],
        help="image prior of map: powerlaw (default) or rolloff (a Gaussian roll-off fitted to "
        "the frames: for scenes soft in themselves, e.g. haze; up to 0.5 dB below powerlaw on "
        "sharp scenes)",
    )
    parser.add_argument(
        "--shifts",
        default="auto",
        help="'auto' (estimate with subpix_ros.core.shift.estimate_shift, default) or a JSON file "
        "with one [u, v] per frame relative to the first frame (rows, cols; px)",
    )
    parser.add_argument(
        "--blur-sigma",
        default="auto",
        help="optics blur std of the model, input px: "
        "'auto' (default: measured on straight edges in "
        "the frames, biased low; a low fallback when none is in view) or a number in 0..3 "
        "(a lab calibration; checked against straight edges in the frames: replaced by their "
        "measurement where they show it too high, said 'not checked' where none is usable)",
    )
    parser.add_argument(
        "--motion-blur",
        default=None,
        metavar="DU,DV",
        help="image motion during each exposure, input px (rows, cols), e.g. '0,1.5' for 1.5 px "
        "of motion along the columns: a box of that length in the model's PSF (default: none)",
    )
    parser.add_argument(
        "--pixel-fill",
        type=float,
        default=None,
        metavar="W",
        help="the pixel aperture's width, input px, in (0, 1] (a lab calibration of the fill "
        "factor; default: the blur estimate's, measured on sharp straight edges with "
        "--blur-sigma auto, else 1)",
    )
    parser.add_argument(
        "--noise-sigma", type=float, default=None, help="noise std in DN (default: estimated)"
    )
    parser.add_argument(
        "--no-refine", action="store_true", help="use the shifts as given (no refinement)"
    )
    parser.add_argument(
        "-o",
        "--output",
        required=True,
        help="output file: .png (8- or 16-bit as the frames, clipped), .tif/.tiff (32-bit float) "
        "or .npy (float64)",
    )
    parser.set_defaults(func=run)


def _shifts_from_file(path: str, n: int) -> np.ndarray:
    try:
        data = json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise CliError(f"shift file {path} not found") from None
    except (OSError, json.JSONDecodeError) as exc:
        raise CliError(f"shift file {path}: {exc}") from None
    arr = np.asarray(data, dtype=object)
    try:
        s = np.asarray(data, dtype=np.float64)
    except (TypeError, ValueError):
        raise CliError(f"shift file {path}: expected a JSON list of [u, v] pairs") from None
    if s.shape != (n, 2) or not np.isfinite(s).all():
        raise CliError(
            f"shift file {path}: expected {n} [u, v] pairs (one per frame), got shape {arr.shape}"
        )
    return s


def _auto_shifts(lumas: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, list[int]]:
    from subpix_ros.core.shift import estimate_shift

    shifts, covs, keep = [np.zeros(2)], [np.zeros((2, 2))], [0]
    for i, f in enumerate(lumas[1:], start=1):
        r = estimate_shift(lumas[0], f)
        if not r.ok:
            print(
                f"subpix superres: frame {i} left out: shift estimate failed ({r.reason})",
                file=sys.stderr,
            )
            continue
        shifts.append(np.array([r.u, r.v]))
        covs.append(np.asarray(r.cov)[:2, :2] if r.cov is not None else np.zeros((2, 2)))
        keep.append(i)
    return np.array(shifts), np.array(covs), keep


def _write(path: str, image: np.ndarray, dtype: np.dtype) -> None:
    """Write ``image``: .npy as it is, .tif as float32, .png rounded into the frames' ``dtype``."""
    ext = Path(path).suffix.lower()
    if ext == ".npy":
        np.save(path, image)
        return
    if ext == ".png":  # 8- or 16-bit as the frames were (a 16-bit image clipped to 8 is white)
        kind = np.uint16 if np.dtype(dtype) == np.uint16 else np.uint8
        out = np.clip(np.rint(image), 0, np.iinfo(kind).max).astype(kind)
    elif ext in (".tif", ".tiff"):
        out = image.astype(np.float32)
    else:
        raise CliError(f"unsupported output type {ext or '(none)'}: use .png, .tif/.tiff or .npy")
    if not cv2.imwrite(path, out):
        raise CliError(f"cannot write {path}")


def run(args: argparse.Namespace) -> int:
    """Super-resolve the given frames into one image and write it."""
    from subpix_ros.core.superres import MAX_FACTOR, reconstruct_colour

    if not 2 <= args.factor <= MAX_FACTOR:
        raise CliError(f"--factor must be 2..{MAX_FACTOR}, got {args.factor}")
    if len(args.frames) < 2:
        raise CliError("need at least 2 frames")
    ext = Path(args.output).suffix.lower()
    if ext not in (".png", ".npy", ".tif", ".tiff"):
        raise CliError(f"unsupported output type {ext or '(none)'}: use .png, .tif/.tiff or .npy")
    imgs = [read_image(f) for f in args.frames]
    if len({i.shape[:2] for i in imgs}) != 1:
        raise CliError(
            "frames differ in size: "
            + ", ".join(f"{f}: {i.shape[1]}x{i.shape[0]}" for f, i in zip(args.frames, imgs))
        )
    if len({(i.ndim, i.dtype) for i in imgs}) != 1:
        raise CliError(
            "frames differ in channels or bit depth (all must be alike: convert them): "
            + ", ".join(
                f"{f}: {'colour' if i.ndim == 3 else 'grey'} {i.dtype.itemsize * 8}-bit"
                for f, i in zip(args.frames, imgs)
            )
        )
    cov = None
    lumas = [luma(i) for i in imgs]
    if args.shifts == "auto":
        shifts, cov, keep = _auto_shifts(lumas)
        if len(keep) < 2:
            raise CliError("no frame could be registered to the first one")
        imgs, lumas = [imgs[k] for k in keep], [lumas[k] for k in keep]
    else:
        shifts = _shifts_from_file(args.shifts, len(imgs))
    from subpix_ros.core.blur import parse_blur_sigma

    try:
        blur = parse_blur_sigma(args.blur_sigma)
    except ValueError as exc:
        raise CliError(f"--blur-sigma: {exc}") from None
    motion = None
    if args.motion_blur is not None:
        from subpix_ros.core.superres.model import motion_blur_vector

        try:
            motion = motion_blur_vector([float(v) for v in args.motion_blur.split(",")])
        except ValueError:
            raise CliError(
                f"--motion-blur: expected two finite numbers DU,DV (px), got {args.motion_blur!r}"
            ) from None
    if args.pixel_fill is not None and not 0.0 < args.pixel_fill <= 1.0:
        raise CliError(f"--pixel-fill: must be in (0, 1] (input px), got {args.pixel_fill:g}")
    if blur != "auto" and args.method == "map":  # a lab value, checked as the node checks it
        from subpix_ros.core.blur import BlurCalibration

        check = BlurCalibration(blur, check_given=True)
        blur = check.update(lumas, np.asarray(shifts, dtype=np.float64), motion_blur=motion)
    kw = dict(
        method=args.method,
        prior=args.prior,
        blur_sigma=blur,
        pixel_fill=args.pixel_fill,
        motion_blur=motion,
        noise_sigma=args.noise_sigma,
        refine_shifts=not args.no_refine,
        shift_cov=cov,
    )
    try:
        res = reconstruct_colour(imgs, shifts, args.factor, **kw)
    except ValueError as exc:
        raise CliError(str(exc)) from None
    _write(args.output, res.image, imgs[0].dtype)
    note = (
        f" (fell back: {res.reason})"
        if res.fell_back
        else (f" ({res.reason})" if res.reason else "")
    )
    blur_note = (
        f"blur_sigma={res.blur_sigma:.3f} px ({res.blur_source}: {res.blur_reason})"
        if res.blur_source != "unused"
        else "blur_sigma unused"
    )
    if res.blur_source != "unused":
        blur_note += f" pixel_fill={float(getattr(res, 'pixel_fill', 1.0)):.2f}"
    if motion is not None:
        blur_note += f" motion_blur=({motion[0]:.2f}, {motion[1]:.2f}) px"
    print(
        f"{args.output}: {res.image.shape[1]}x{res.image.shape[0]} method={res.method} "
        f"noise_sigma={res.noise_sigma:.3g} DN frames={len(imgs)} {blur_note}{note}"
    )
    if res.fell_back:  # the file holds a bicubic upscale: said, and not an exit status of success
        print(
            f"subpix superres: {args.output} is the first frame upscaled (bicubic), not a "
            f"super-resolved image: {res.reason}",
            file=sys.stderr,
        )
        return 1
    return 0
