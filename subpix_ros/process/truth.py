"""Scores against the rendered ground truth a synthetic flight carries beside its bag."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from subpix_ros.process.collector import _Collector


def _load_truth(bag: Path) -> tuple[dict[int, tuple[float, float]], np.ndarray | None, int] | None:
    """Load the rendered ground truth beside the bag (``truth.json``, ``truth_hr.png``), if any."""
    import json

    import cv2

    d = bag if bag.is_dir() else bag.parent
    tj, th = d / "truth.json", d / "truth_hr.png"
    if not (tj.is_file() and th.is_file()):
        return None
    try:
        truth = json.loads(tj.read_text())
        shifts = {int(f["stamp_ns"]): (float(f["u"]), float(f["v"])) for f in truth["frames"]}
        return shifts, cv2.imread(str(th), cv2.IMREAD_UNCHANGED), int(truth["factor"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _score_sets(collector: _Collector, truth) -> None:
    """PSNR of each super-resolved image and of the bicubic reference against the rendered truth."""
    from subpix_ros.core.evaluate import gain_over_bicubic, truth_on_grid

    shifts, hr, factor = truth
    if hr is None:
        return
    for entry, (stamp, img, ref) in zip(collector.sets, collector.sr_images):
        if stamp not in shifts or img.dtype != np.uint8:
            continue
        try:
            truth_k = truth_on_grid(hr, shifts[stamp], factor)
            if truth_k.shape != img.shape[:2]:
                continue
            p_sr, p_bic = gain_over_bicubic(img, ref.image, truth_k, factor, border=24)
        except Exception:  # noqa: BLE001 - scoring is extra information
            continue
        entry.update(psnr_sr_db=p_sr, psnr_bicubic_db=p_bic, gain_db=p_sr - p_bic)
