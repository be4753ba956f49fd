"""edge_sharpness: the report's MTF figures, on a rendered flight with a slanted edge in view."""

import numpy as np
import pytest

from subpix_ros.core.render import render_sequence, slanted_edge_scene
from subpix_ros.core.superres import bicubic_upscale, reconstruct
from subpix_ros.process.sharpness import edge_sharpness


def _flight(crop, p=2, blur=0.4, edge=True):
    base = crop.astype(np.float64)
    if edge:
        hr, _ = slanted_edge_scene(base, p, lr=160)
    else:  # the crop's own texture only, flattened: no straight edge anywhere
        hr = np.full((176 * p, 176 * p), 120.0) + np.random.default_rng(3).normal(
            0, 4, (176 * p, 176 * p)
        )
    shifts = [(a / p, b / p) for a in range(p) for b in range(p)]
    return render_sequence(hr, p, shifts, blur, snr_db=40.0, seed=2)


def test_super_resolution_raises_the_mtf_at_the_scenes_edge(crops):
    seq = _flight(crops[next(iter(crops))])
    sr = reconstruct(seq.frames, seq.shifts, 2, blur_sigma=0.4).image
    bic = bicubic_upscale(seq.frames[0], 2)
    edges = edge_sharpness(seq.frames[0], bic, sr, 2)
    assert edges, "the pasted slanted edge is found"
    e = edges[0]
    # cycles per input px: bicubic stays below the input's Nyquist, SR goes beyond its MTF50
    assert 0.1 < e.bicubic_mtf50 < 0.5 and e.sr_mtf50 > 1.15 * e.bicubic_mtf50
    assert e.sr_mtf30 > e.bicubic_mtf30
    assert e.freqs.shape == e.bicubic_mtf.shape == e.sr_mtf.shape
    # the same image twice: no gain
    same = edge_sharpness(seq.frames[0], bic, bic, 2)
    assert same and same[0].sr_mtf50 == pytest.approx(same[0].bicubic_mtf50)


def test_no_straight_edge_no_figures(crops):
    seq = _flight(crops[next(iter(crops))], edge=False)
    bic = bicubic_upscale(seq.frames[0], 2)
    assert edge_sharpness(seq.frames[0], bic, bic, 2) == []


def test_images_of_the_wrong_size_are_refused():
    ref = np.zeros((40, 40))
    with pytest.raises(ValueError, match="must be 2x"):
        edge_sharpness(ref, np.zeros((80, 80)), np.zeros((60, 60)), 2)


def test_the_report_states_the_edge_figures_or_why_there_are_none():
    from subpix_ros.process.report_sections import _edges_text

    edges = [
        {"mtf50_bicubic": 0.34, "mtf50_sr": 0.68, "mtf30_bicubic": 0.42, "mtf30_sr": 0.74},
        {"mtf50_bicubic": 0.30, "mtf50_sr": 0.60, "mtf30_bicubic": 0.40, "mtf30_sr": 0.70},
    ]
    text = _edges_text(edges, has_truth=False)
    assert "2 straight edges" in text and "MTF50 bicubic 0.320" in text
    assert "super-resolved 0.640 (2.00x)" in text
    assert "no straight edge in the reference and no ground truth" in _edges_text([], False)
    assert "no ground truth" not in _edges_text([], True)


@pytest.mark.parametrize("blur", [0.3, 0.5])
def test_the_gain_holds_on_the_independent_degradation_model_with_the_blur_unknown(blur):
    """The MTF gain on frames from benchmarks/degrade_independent (not core/render).

    A roof's edges in view, the reconstruction left to find the blur itself (``"auto"``).
    """
    from benchmarks.degrade_independent import degrade, scene_crop, shift_layout
    from subpix_ros.core.superres import BLUR_AUTO
    from subpix_ros.data import load_crop

    hr = scene_crop(load_crop("crop_road").astype(float), 2, 128, 8)
    fl = degrade(hr, 2, shift_layout("grid", 2), blur, snr_db=40, roof=True, seed=1)
    sr = reconstruct(fl.frames, fl.shifts, 2, blur_sigma=BLUR_AUTO).image
    edges = edge_sharpness(fl.frames[0], bicubic_upscale(fl.frames[0], 2), sr, 2)
    assert len(edges) >= 2
    for e in edges:  # measured: bicubic 0.30-0.38, SR 0.58-0.70 cycles per input px
        assert e.sr_mtf50 > 1.5 * e.bicubic_mtf50 and e.sr_mtf30 > e.bicubic_mtf30


def test_a_large_reference_s_edge_is_found_at_the_reduced_detection_size():
    """Above DETECT_MAX_PX the report finds segments on a reduced frame, ROIs on the frame."""
    import cv2

    from subpix_ros.core.blur_edges import find_edge_rois
    from subpix_ros.process.sharpness import DETECT_MAX_PX

    h, w, angle = 700, 1300, np.deg2rad(8.0)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    # one straight step 8 deg off the x axis through (650, 350), soft as a lens makes it
    frame = np.where(yy - 350 > np.tan(angle) * (xx - 650), 170.0, 60.0)
    frame = cv2.GaussianBlur(frame, (0, 0), 0.8) + np.random.default_rng(0).normal(0, 1, (h, w))
    assert max(h, w) > 2 * DETECT_MAX_PX  # detected at a quarter of the size

    def on_the_step(roi):
        x, y, rw, rh = roi
        cx, cy = x + rw / 2, y + rh / 2
        return abs((cy - 350) - np.tan(angle) * (cx - 650)) < 6

    rois = find_edge_rois(frame, detect_max_px=DETECT_MAX_PX)
    assert rois and all(on_the_step(r) for r in rois)
    bic = bicubic_upscale(frame, 2)
    edges = edge_sharpness(frame, bic, bic, 2)
    assert edges and all(on_the_step(e.roi) for e in edges)
    assert 0.1 < edges[0].bicubic_mtf50 < 0.5
