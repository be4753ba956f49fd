#!/usr/bin/env python3
"""Copy the assets subpix_ros bundles from the real Seneca strip (CC0).

Run once by a developer (the outputs are committed under data/):

* ``data/seneca/IMG_04xx.jpg``: the nine frames downscaled 2x (1800x1350,
  INTER_AREA, JPEG quality 90) plus ``frames.csv`` and the licence;
* ``data/crops/crop_*.png``: 768x768 full-resolution luminance crops
  (0.2989 R + 0.587 G + 0.1141 B, rounded to 8 bit) used as high-resolution
  ground truth when rendering sub-pixel shifted sequences;
* ``data/crops/colour_hr.jpg``: one 1024x1024 full-resolution colour crop (JPEG q95),
  the scene of the rendered ``subpixel`` sample flight.

Usage: ``python scripts/extract_seneca_assets.py [SENECA_DIR]``
(default ``../shared/data/seneca``).
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
# (frame, row0, col0) of each 768x768 luminance crop, full-resolution pixels.
CROPS = {
    "crop_field_edge": (463, 0, 120),
    "crop_rows": (463, 1200, 1600),
    "crop_trees": (467, 1900, 2560),
    "crop_road": (467, 900, 0),
}
COLOUR_CROP = (463, 900, 1300, 1024)


def luminance_u8(bgr: np.ndarray) -> np.ndarray:
    b, g, r = (bgr[..., i].astype(np.float64) for i in range(3))
    return np.clip(np.rint(0.2989 * r + 0.587 * g + 0.1141 * b), 0, 255).astype(np.uint8)


def main(src: Path) -> None:
    out = ROOT / "data" / "seneca"
    out.mkdir(parents=True, exist_ok=True)
    for i in range(461, 470):
        im = cv2.imread(str(src / f"IMG_0{i}.jpg"), cv2.IMREAD_COLOR)
        small = cv2.resize(im, (1800, 1350), interpolation=cv2.INTER_AREA)
        cv2.imwrite(str(out / f"IMG_0{i}.jpg"), small, [cv2.IMWRITE_JPEG_QUALITY, 90])
    for name in ("frames.csv", "LICENSE-CC0.txt"):
        shutil.copy(src / name, out / name)
    crops = ROOT / "data" / "crops"
    crops.mkdir(parents=True, exist_ok=True)
    for name, (frame, r0, c0) in CROPS.items():
        im = cv2.imread(str(src / f"IMG_0{frame}.jpg"), cv2.IMREAD_COLOR)
        cv2.imwrite(str(crops / f"{name}.png"), luminance_u8(im[r0 : r0 + 768, c0 : c0 + 768]))
    frame, r0, c0, n = COLOUR_CROP
    im = cv2.imread(str(src / f"IMG_0{frame}.jpg"), cv2.IMREAD_COLOR)
    cv2.imwrite(
        str(crops / "colour_hr.jpg"), im[r0 : r0 + n, c0 : c0 + n], [cv2.IMWRITE_JPEG_QUALITY, 95]
    )


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT.parent / "shared" / "data" / "seneca")
