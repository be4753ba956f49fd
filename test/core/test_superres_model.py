"""Observation model (METHODS.md B, eq. 3) and the paper's reference solutions (eqs. 4, 6, 7)."""

import numpy as np
import pytest

from subpix_ros.core.render import render_sequence
from subpix_ros.core.superres.model import (
    FrameOperator,
    box_sum,
    box_sum_adjoint,
    frame_transfer_1d,
    translation_homography,
)
from subpix_ros.core.superres.paper import (
    band_matrix,
    grid_offsets,
    interleave,
    pinv_solution,
    recursive_solution,
    windowed_filter,
    windowed_solution,
)


@pytest.mark.parametrize("p,q", [(2, 2), (2, 3), (3, 2), (4, 4)])
def test_box_sum_is_eq3_and_adjoint_exact(p, q):
    rng = np.random.default_rng(p * 10 + q)
    x = rng.normal(size=(13 + p - 1, 11 + q - 1))
    y = box_sum(x, p, q)
    # eq. 5: T1 X T2 with band matrices of ones
    np.testing.assert_allclose(y, band_matrix(13, p) @ x @ band_matrix(11, q).T, atol=1e-12)
    yy = rng.normal(size=y.shape)
    assert np.isclose(np.sum(y * yy), np.sum(x * box_sum_adjoint(yy, p, q)), rtol=1e-12)


@pytest.mark.parametrize("p,q", [(2, 2), (2, 3), (3, 3), (4, 2)])
def test_recursion_eq4_exact_on_noise_free_data(p, q):
    rng = np.random.default_rng(7)
    x = rng.uniform(0, 255, size=(40 + p - 1, 37 + q - 1))
    y = box_sum(x, p, q)
    boundary = np.zeros_like(x)
    boundary[: p - 1] = x[: p - 1]
    boundary[:, : q - 1] = x[:, : q - 1]
    np.testing.assert_allclose(recursive_solution(y, p, q, boundary), x, atol=1e-8)
    # and the recursion is what eq. 4 says: every box of the solution reproduces y
    np.testing.assert_allclose(box_sum(recursive_solution(y, p, q, boundary), p, q), y, atol=1e-8)


def test_recursion_wrong_boundary_shape_raises():
    with pytest.raises(ValueError):
        recursive_solution(np.zeros((5, 5)), 2, 2, np.zeros((5, 5)))


def test_interleaved_grid_frames_are_eq3_exactly(crops):
    # shifts of k/p LR px are whole HR px: the rendered frames (no blur, no noise) are eq. 3 exactly
    p = 2
    hr = crops["crop_trees"][: 2 * 64, : 2 * 64].astype(float)
    shifts = [(0, 0), (0, 0.5), (0.5, 0), (0.5, 0.5)]
    seq = render_sequence(hr, p, shifts, blur_sigma=0.0, noise_sigma=0.0, quantize=False, margin=4)
    y, filled = interleave(seq.frames, grid_offsets(seq.shifts, p, p), p, p)
    # y[k, l] = sum of truth[k..k+p-1, l..l+p-1] wherever the frames reach
    inner = (slice(p, -2 * p), slice(p, -2 * p))
    direct = box_sum(seq.truth, p, p)
    np.testing.assert_allclose(
        y[: direct.shape[0], : direct.shape[1]][inner], direct[inner], atol=1e-6
    )
    assert filled[inner].all()


def test_pinv_eq6_least_norm_exact_solution():
    p = q = 2
    rng = np.random.default_rng(3)
    nx, ny = 7, 9  # n + p - 1 divisible by p
    x = rng.normal(size=(nx + p - 1, ny + q - 1))
    y = box_sum(x, p, q)
    sol = pinv_solution(y, p, q)
    np.testing.assert_allclose(box_sum(sol, p, q), y, atol=1e-9)  # solves eq. 5 exactly
    # least norm: the Kronecker-form minimum-norm solution
    t = np.kron(band_matrix(nx, p), band_matrix(ny, q))
    ln = np.linalg.lstsq(t, y.ravel(), rcond=None)[0].reshape(x.shape)
    np.testing.assert_allclose(sol, ln, atol=1e-9)


def test_pinv_divisibility_condition_enforced():
    with pytest.raises(ValueError, match="divisible"):
        pinv_solution(np.zeros((8, 7)), 2, 2)


def test_windowed_eq7_dc_gain_and_normalisation():
    g, c = windowed_filter(2, 6, normalise=False)
    assert c == 3
    assert np.isclose(
        2 * g.sum(), 8 / 7
    )  # the 1.14 brightness error of eq. 7 as written (p=2, w=6)
    gn, _ = windowed_filter(2, 6)
    assert np.isclose(2 * gn.sum(), 1.0)
    with pytest.raises(ValueError):
        windowed_filter(2, 5)  # w + p - 1 even


def test_windowed_convolution_equals_per_pixel_window_solve():
    p, w = 2, 6
    rng = np.random.default_rng(5)
    y = rng.normal(size=(30, 30))
    xw = windowed_solution(y, p, p, w=w, normalise=False)
    t = band_matrix(w, p)
    c = (w + p - 2) // 2
    for k, l in [(10, 12), (15, 9), (20, 20)]:
        win = y[k - c : k - c + w, l - c : l - c + w]
        local = np.linalg.pinv(t) @ win @ np.linalg.pinv(t).T  # eq. 6 in the window
        assert np.isclose(xw[k, l], local[c, c])


def test_frame_transfer_matches_direct_periodic_model():
    # 1-D periodic check of the folded Fourier model used by the MAP solver
    p, n = 3, 21  # odd lengths: no Nyquist bin, whose real-signal convention differs
    rng = np.random.default_rng(2)
    x = rng.normal(size=p * n)
    shift, sigma = 0.37, 0.4  # LR px
    f = np.fft.fftfreq(p * n)
    z = np.fft.ifft(
        np.fft.fft(x)
        * np.exp(-2j * np.pi * f * p * shift)
        * np.exp(-2 * np.pi**2 * (p * sigma) ** 2 * f**2)
    )
    z = z.real
    y = np.array([z[p * i : p * i + p].mean() for i in range(n)])
    a, _ = frame_transfer_1d(n, p, shift, sigma)
    big = np.fft.fft(x)
    pred = sum(a[m] * big[np.arange(n) + m * n] for m in range(p))
    np.testing.assert_allclose(np.fft.fft(y), pred, atol=1e-9)


@pytest.mark.parametrize("p", [2, 3])
@pytest.mark.parametrize("fill", [0.8, 0.93])
def test_frame_transfer_with_pixel_fill_is_the_box_average_about_the_pixel_centre(p, fill):
    # 1-D periodic: the trigonometric interpolant of the shifted, blurred HR signal averaged
    # over w LR px about each LR pixel's centre (HR coordinate p i + (p - 1) / 2)
    n = 21  # odd p n: no Nyquist bin
    rng = np.random.default_rng(5)
    x = rng.normal(size=p * n)
    shift, sigma = 0.37, 0.3  # LR px
    f = np.fft.fftfreq(p * n)
    z_hat = np.fft.fft(x) * np.exp(-2j * np.pi * f * p * shift)
    z_hat = z_hat * np.exp(-2 * np.pi**2 * (p * sigma) ** 2 * f**2)
    t = (np.arange(400) + 0.5) / 400 - 0.5  # midpoints across the aperture, fractions of it
    y = np.empty(n, complex)
    for i in range(n):  # LR pixels
        pos = p * i + (p - 1) / 2 + t * fill * p  # HR px
        y[i] = (z_hat[None, :] * np.exp(2j * np.pi * f[None, :] * pos[:, None])).sum() / (
            p * n * pos.size
        )
    a, _ = frame_transfer_1d(n, p, shift, sigma, pixel_fill=fill)
    big = np.fft.fft(x)
    pred = sum(a[m] * big[np.arange(n) + m * n] for m in range(p))
    np.testing.assert_allclose(np.fft.fft(y), pred, atol=2e-3 * np.abs(pred).max())


def test_frame_transfer_default_fill_is_the_discrete_box():
    for p in (2, 3, 4):
        a, f = frame_transfer_1d(24, p, 0.3, 0.4)
        b, g = frame_transfer_1d(24, p, 0.3, 0.4, pixel_fill=1.0)
        assert np.array_equal(a, b) and np.array_equal(f, g)


def test_frame_operator_adjoint_and_translation():
    rng = np.random.default_rng(4)
    hr = rng.normal(size=(80, 96))
    h = np.array(
        [[np.cos(0.01), -np.sin(0.01), 0.3], [np.sin(0.01), np.cos(0.01), -0.2], [1e-5, 0, 1]]
    )
    op = FrameOperator(h, (36, 44), hr.shape, 2, 2, 0.4)
    y = rng.normal(size=(36, 44))
    assert np.isclose(np.sum(op.forward(hr) * y), np.sum(hr * op.adjoint(y)), rtol=1e-10)
    # integer LR translation: frame = reference moved by (1, -2) LR px
    op0 = FrameOperator(translation_homography(0, 0), (40, 48), hr.shape, 2, 2, 0.0)
    op1 = FrameOperator(translation_homography(1, -2), (40, 48), hr.shape, 2, 2, 0.0)
    a, b = op0.forward(hr), op1.forward(hr)
    both = op0.valid[:-1, 2:] & op1.valid[1:, :-2]
    np.testing.assert_allclose(b[1:, :-2][both], a[:-1, 2:][both], atol=1e-12)
    assert both.sum() > 1000
