"""``subpix mtf``: slanted-edge MTF of an image region (ISO 12233 manner)."""

from __future__ import annotations

import argparse

import cv2
import numpy as np

from subpix_ros.cli import CliError
from subpix_ros.cli._images import luma, read_image


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``subpix mtf`` subcommand to the CLI's subparsers ``sub``."""
    parser = sub.add_parser(
        "mtf",
        help="slanted-edge MTF, MTF50 and MTF30 of an image region",
        description="Measure the MTF of a straight edge tilted a few degrees from the pixel grid "
        "(ISO 12233 slanted-edge method). Frequencies in cycles/pixel; with --pixel-um "
        "also line pairs per mm.",
    )
    parser.add_argument(
        "image", metavar="IMAGE", help="image file (colour is converted to luminance)"
    )
    parser.add_argument(
        "--roi",
        default=None,
        help="x,y,w,h of the region holding one edge (pixels; default: whole image)",
    )
    parser.add_argument(
        "--pixel-um", type=float, default=None, help="pixel pitch in micrometres (for lp/mm)"
    )
    parser.add_argument("--plot", default=None, help="write the MTF curve as a PNG plot")
    parser.set_defaults(func=run)


def _parse_roi(text: str) -> tuple[int, int, int, int]:
    try:
        vals = tuple(int(v) for v in text.split(","))
    except ValueError:
        raise CliError(f"--roi must be x,y,w,h integers, got {text!r}") from None
    if len(vals) != 4:
        raise CliError(f"--roi must be x,y,w,h integers, got {text!r}")
    return vals  # type: ignore[return-value]


def plot_mtf(freqs: np.ndarray, mtf: np.ndarray, path: str, marks: dict[str, float]) -> None:
    """Draw the MTF curve (0..1 cycles/pixel) with OpenCV and write it as PNG."""
    w, h, m = 640, 400, 50
    img = np.full((h, w, 3), 255, np.uint8)
    x0, y0, x1, y1 = m, h - m, w - 20, 20

    def to_px(f: float, v: float) -> tuple[int, int]:
        return int(x0 + (x1 - x0) * f / 1.0), int(y0 - (y0 - y1) * v / 1.2)

    cv2.rectangle(img, (x0, y1), (x1, y0), (0, 0, 0), 1)
    for f in np.arange(0, 1.01, 0.1):  # grid lines
        cv2.line(img, to_px(f, 0), to_px(f, 1.2), (220, 220, 220), 1)
        cv2.putText(
            img,
            f"{f:.1f}",
            (to_px(f, 0)[0] - 10, y0 + 18),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.4,
            (0, 0, 0),
            1,
        )
    for v in (0.3, 0.5, 1.0):
        cv2.line(img, to_px(0, v), to_px(1, v), (200, 200, 255), 1)
        cv2.putText(
            img, f"{v:.1f}", (5, to_px(0, v)[1] + 4), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1
        )
    pts = np.array(
        [to_px(f, min(max(v, 0), 1.2)) for f, v in zip(freqs, mtf) if f <= 1.0], np.int32
    )
    cv2.polylines(img, [pts], False, (200, 0, 0), 2)
    for k, (name, f) in enumerate(marks.items()):
        cv2.putText(
            img,
            f"{name} = {f:.3f} cy/px",
            (x1 - 200, y1 + 20 + 18 * k),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.45,
            (0, 0, 0),
            1,
        )
    cv2.putText(
        img, "cycles / pixel", (w // 2 - 50, h - 10), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1
    )
    if not cv2.imwrite(path, img):
        raise CliError(f"cannot write {path}")


def run(args: argparse.Namespace) -> int:
    """Measure the slanted-edge MTF in the given region, print it and plot it when asked."""
    from subpix_ros.core.mtf import slanted_edge_mtf

    img = read_image(args.image)
    if img.ndim == 3:
        img = luma(img)
    roi = _parse_roi(args.roi) if args.roi else None
    if args.pixel_um is not None and not args.pixel_um > 0:
        raise CliError("--pixel-um must be > 0")
    pitch = args.pixel_um * 1e-6 if args.pixel_um else None
    try:
        result = slanted_edge_mtf(img, roi=roi, pixel_pitch_m=pitch)
    except ValueError as exc:
        hint = (
            ""
            if roi is not None
            else " (the whole image was measured as one edge: give --roi x,y,w,h around one straight "
            "edge, or let `subpix blur` find the edges)"
        )
        raise CliError(f"{exc}{hint}") from None
    print(
        f"edge angle {result.angle_deg:+.2f} deg"
        + (" (edge near horizontal: rows/cols swapped)" if result.transposed else "")
    )
    print(
        f"MTF50 {result.mtf50:.4f} cycles/pixel"
        + (f"  {result.mtf50_lp_mm:.1f} lp/mm" if result.mtf50_lp_mm else "")
    )
    print(
        f"MTF30 {result.mtf30:.4f} cycles/pixel"
        + (f"  {result.mtf30_lp_mm:.1f} lp/mm" if result.mtf30_lp_mm else "")
    )
    if args.plot:
        plot_mtf(
            result.freqs, result.mtf, args.plot, {"MTF50": result.mtf50, "MTF30": result.mtf30}
        )
        print(f"plot: {args.plot}")
    return 0
