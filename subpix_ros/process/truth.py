"""Scores against the rendered ground truth a synthetic flight carries beside its bag."""

from __future__ import annotations

from pathlib import Path

import numpy as np


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


def set_scorer(truth):
    """Return ``score(entry, stamp, image, bicubic, reference, factor)`` for the collector.

    It adds to a set's summary entry, as the set arrives: the PSNR of the super-resolved
    image and of the bicubic reference against the rendered truth (a synthetic flight), and
    the slanted-edge MTF50/MTF30 of both at the reference's own straight edges
    (:func:`~subpix_ros.process.sharpness.edge_sharpness`; any flight with such an edge).
    """

    def score(entry: dict, stamp: int, img, bicubic, ref, factor: int) -> None:
        if truth is not None:
            _score_truth(entry, truth, stamp, img, ref)
        _score_edges(entry, img, bicubic, ref, factor)

    return score


def _score_truth(entry: dict, truth, stamp: int, img, ref) -> None:
    """Add the PSNR against the rendered truth to a set's entry, where the truth covers it."""
    from subpix_ros.core.evaluate import gain_over_bicubic, truth_on_grid

    shifts, hr, factor = truth
    if hr is None or stamp not in shifts or img.dtype != np.uint8:
        return
    try:
        truth_k = truth_on_grid(hr, shifts[stamp], factor)
        if truth_k.shape != img.shape[:2]:
            return
        p_sr, p_bic = gain_over_bicubic(img, ref.image, truth_k, factor, border=24)
    except Exception:  # noqa: BLE001 - scoring is extra information
        return
    entry.update(psnr_sr_db=p_sr, psnr_bicubic_db=p_bic, gain_db=p_sr - p_bic)


def _score_edges(entry: dict, img, bicubic, ref, factor: int) -> None:
    """Add the edge MTF figures (cycles per input px) to a set's entry, where an edge exists."""
    from subpix_ros.process.products import rounded
    from subpix_ros.process.sharpness import edge_sharpness

    if factor < 2:
        return
    try:
        edges = edge_sharpness(ref.image, bicubic, img, factor)
    except (ValueError, cv2_error()):
        return
    entry["edges"] = [
        {
            "roi": [int(v) for v in e.roi],
            "angle_deg": rounded(e.angle_deg),
            "mtf50_bicubic": rounded(e.bicubic_mtf50),
            "mtf50_sr": rounded(e.sr_mtf50),
            "mtf30_bicubic": rounded(e.bicubic_mtf30),
            "mtf30_sr": rounded(e.sr_mtf30),
        }
        for e in edges
    ]


def cv2_error():
    """OpenCV's exception class (an edge search on a degenerate image raises it)."""
    import cv2

    return cv2.error
