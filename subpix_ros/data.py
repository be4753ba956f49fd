"""Locate the sample data bundled with subpix_ros (real Seneca frames, crops, bags).

Search order: ``$SUBPIX_DATA``; the ``data/`` folder of a source checkout
(editable/venv install); ``share/subpix_ros/data`` of an installed package.
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

CROP_NAMES = ("crop_field_edge", "crop_rows", "crop_trees", "crop_road")


def data_root() -> Path:
    """Return the folder of the bundled data (``SUBPIX_DATA``, the checkout, or the install)."""
    env = os.environ.get("SUBPIX_DATA")
    candidates = [Path(env)] if env else []
    candidates.append(Path(__file__).resolve().parents[1] / "data")
    try:  # installed via colcon: share/subpix_ros/data
        from ament_index_python.packages import get_package_share_directory

        candidates.append(Path(get_package_share_directory("subpix_ros")) / "data")
    except Exception:  # noqa: BLE001 - ament index absent or package not indexed
        pass
    for c in candidates:
        if (c / "seneca" / "frames.csv").is_file():
            return c
    raise FileNotFoundError(
        "subpix_ros sample data not found (looked in: "
        + ", ".join(str(c) for c in candidates)
        + "); set SUBPIX_DATA to the repository's data/ folder"
    )


def bags_dir() -> Path:
    """Folder of the generated sample bags (``make sample`` builds them)."""
    return data_root() / "bags"


def load_crop(name: str) -> np.ndarray:
    """Load a 768x768 uint8 full-resolution luminance crop of the real Seneca strip."""
    if name not in CROP_NAMES:
        raise KeyError(f"unknown crop {name!r}; choose from {CROP_NAMES}")
    img = cv2.imread(str(data_root() / "crops" / f"{name}.png"), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise FileNotFoundError(f"cannot read crop {name}")
    return img


def seneca_frame_paths() -> list[Path]:
    """Return the nine bundled Seneca frames (1800x1350 JPEG), in flight order."""
    return sorted((data_root() / "seneca").glob("IMG_*.jpg"))
