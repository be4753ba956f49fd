"""Image files for the ``subpix`` subcommands: read as stored, luminance for the methods."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from subpix_ros.cli import CliError


def read_image(path: str | Path) -> np.ndarray:
    """Read an image file as stored (8/16-bit, mono or BGR; an alpha channel dropped).

    Raises :class:`~subpix_ros.cli.CliError` (one line) for a missing or undecodable file.
    """
    if not Path(path).is_file():
        raise CliError(f"cannot read {path}: no such file")
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise CliError(f"cannot read {path}: not an image OpenCV can decode")
    if img.ndim == 3 and img.shape[2] == 4:
        img = img[..., :3]
    return img


def luma(img: np.ndarray) -> np.ndarray:
    """Return an image's luminance in float64 (colour taken as BGR; core.luminance, METHODS A)."""
    if img.ndim == 2:
        return img.astype(np.float64)
    from subpix_ros.core.luminance import luminance

    return luminance(img[..., :3], "bgr")
