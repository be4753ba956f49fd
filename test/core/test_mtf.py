"""Slanted-edge MTF: validation against analytic MTFs, and the paper's evaluation (METHODS.md B)."""

import numpy as np
import pytest
from scipy.special import erf

from subpix_ros.core.evaluate import mtf30_evaluation
from subpix_ros.core.mtf import gaussian_pixel_mtf, mtf_crossing, slanted_edge_mtf


def edge_image(
    h, w, angle_deg, sigma, ss=8, lo=50.0, hi=200.0, noise=0.0, seed=0, horizontal=False
):
    """Pixel-integrated (ss x ss sub-samples) image of a Gaussian-blurred straight edge.

    The edge passes through the image centre, tilted ``angle_deg`` from the column
    direction (from the row direction if ``horizontal``); blur std ``sigma`` px.
    """
    th = np.deg2rad(angle_deg)
    sub = (np.arange(ss) + 0.5) / ss - 0.5
    r = np.arange(h)[:, None, None, None] + sub[None, None, :, None] - h / 2
    c = np.arange(w)[None, :, None, None] + sub[None, None, None, :] - w / 2
    d = (r * np.cos(th) - c * np.sin(th)) if horizontal else (c * np.cos(th) - r * np.sin(th))
    img = lo + (hi - lo) * (0.5 * (1 + erf(d / (np.sqrt(2) * sigma)))).mean(axis=(2, 3))
    if noise:
        img = img + np.random.default_rng(seed).normal(0, noise, img.shape)
    return img


@pytest.mark.parametrize("angle", [3.0, 5.0, 11.0])
@pytest.mark.parametrize("sigma", [0.4, 0.8])
def test_matches_analytic_gaussian_edge(angle, sigma):
    r = slanted_edge_mtf(edge_image(100, 80, angle, sigma))
    f = np.linspace(0, 1, 4001)
    ref = gaussian_pixel_mtf(f, sigma, angle)
    assert abs(r.angle_deg - angle) < 0.05
    assert abs(r.mtf50 - mtf_crossing(f, ref, 0.5)) <= 0.01
    assert abs(r.mtf30 - mtf_crossing(f, ref, 0.3)) <= 0.01
    m = np.interp(f[f <= 0.5], r.freqs, r.mtf)
    assert np.abs(m - ref[f <= 0.5]).max() < 0.02


def test_near_horizontal_edge_and_noise():
    img = edge_image(80, 100, 6.0, 0.6, horizontal=True, noise=0.5)
    r = slanted_edge_mtf(img)
    f = np.linspace(0, 1, 4001)
    assert r.transposed
    assert abs(r.mtf50 - mtf_crossing(f, gaussian_pixel_mtf(f, 0.6, 6.0), 0.5)) <= 0.01


def test_roi_colour_and_line_pairs_per_mm():
    img = np.full((120, 160), 80.0)
    img[10:110, 30:130] = edge_image(100, 100, 5.0, 0.5)
    colour = np.dstack([img, img, img])
    r = slanted_edge_mtf(colour, roi=(30, 10, 100, 100), pixel_pitch_m=5e-6)
    assert np.isclose(r.mtf30_lp_mm, r.mtf30 * 200.0)  # 5 um pixels: 200 px/mm
    assert np.isclose(r.mtf50_lp_mm, r.mtf50 * 200.0)


@pytest.mark.parametrize(
    "image,kw,match",
    [
        (np.full((64, 64), 100.0), {}, "contrast"),
        (edge_image(64, 64, 0.0, 0.5), {}, "too close to the pixel grid"),
        (edge_image(64, 64, 5.0, 0.5), {"roi": (10, 10, 100, 20)}, "outside"),
        (np.zeros((8, 8)), {}, "too small"),
    ],
)
def test_bad_input_raises(image, kw, match):
    with pytest.raises(ValueError, match=match):
        slanted_edge_mtf(image, **kw)


@pytest.mark.parametrize("p", [2, 3, 4])
def test_paper_evaluation_reconstruction_reaches_optics_limit(crops, p):
    """MTF30 of the reconstruction vs one input frame, and vs the optics-blurred HR truth.

    All MTF30 values are converted to cycles per *input* pixel. The physical
    ceiling is the optics-blurred truth (no pixel aperture): reach >= 95 % of it.
    """
    r = mtf30_evaluation(crops["crop_field_edge"], p, lr=112)
    m_in, m_ceiling, m_bicubic, m_rec = r["input"], r["ceiling"], r["bicubic"], r["map"]
    assert m_rec >= 0.95 * m_ceiling, (m_rec, m_ceiling)
    assert m_rec > 1.2 * m_in, (m_rec, m_in)  # resolution gain over one input frame
    assert m_bicubic < m_in  # bicubic interpolation only loses resolution


@pytest.mark.parametrize("sigma", [0.3, 0.4, 0.6])
@pytest.mark.parametrize("angle", [2.5, 5.0, 8.0, 15.0, 30.0])
def test_noisy_8bit_edge_within_001(angle, sigma):
    # 1 DN noise and 8-bit rounding, down to blur 0.3 px (MTF30 beyond Nyquist): error <= 0.01 c/px
    for seed in (3, 4):
        img = np.clip(np.rint(edge_image(100, 80, angle, sigma, noise=1.0, seed=seed)), 0, 255)
        r = slanted_edge_mtf(img)
        f = np.linspace(0, 1, 4001)
        ref = gaussian_pixel_mtf(f, sigma, angle)
        assert abs(r.mtf50 - mtf_crossing(f, ref, 0.5)) <= 0.01
        assert abs(r.mtf30 - mtf_crossing(f, ref, 0.3)) <= 0.01


@pytest.mark.parametrize("angle", [5.0, 15.0])
def test_ringing_lsf_not_cut_by_the_window(angle):
    """An unsharp-masked edge, ``1.6 E(0.5) - 0.6 E(2.0)``: the LSF has negative lobes out to ~6 px.

    Analytic MTF ``(1.6 G(0.5) - 0.6 G(2.0)) x pixel``; the window must widen to keep
    the lobes (a window fitted to the rise alone cuts them and reads MTF30 too high).
    """
    img = 1.6 * edge_image(120, 100, angle, 0.5) - 0.6 * edge_image(120, 100, angle, 2.0)
    img = img + np.random.default_rng(5).normal(0, 0.5, img.shape)
    r = slanted_edge_mtf(img)
    f = np.linspace(0, 1, 4001)
    th = np.deg2rad(angle)
    g = lambda s: np.exp(-2 * np.pi**2 * s**2 * f**2)  # noqa: E731
    ref = (1.6 * g(0.5) - 0.6 * g(2.0)) * np.abs(np.sinc(f * np.cos(th)) * np.sinc(f * np.sin(th)))
    assert abs(r.mtf30 - mtf_crossing(f, ref, 0.3)) <= 0.01
    assert abs(r.mtf50 - mtf_crossing(f, ref, 0.5)) <= 0.01


@pytest.mark.parametrize("shape", [(130, 77, 3), (64, 5, 3), (1, 3, 3), (200, 40)])
def test_bt601_luminance_is_the_weighted_sum_whatever_the_blocks(shape):
    from subpix_ros.core.mtf import bt601_luminance

    img = np.random.default_rng(3).integers(0, 256, shape, dtype=np.uint8)
    got = bt601_luminance(img)
    a = img.astype(np.float64)
    want = a @ np.array([0.114, 0.587, 0.299]) if a.ndim == 3 else a
    assert got.dtype == np.float64 and got.shape == shape[:2]
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-10)  # BLAS kernels may round apart
