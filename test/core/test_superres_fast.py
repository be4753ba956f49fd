"""The fast paths of the super-resolution solver equal their direct definitions.

Each vectorised / blocked / windowed helper of :mod:`subpix_ros.core.superres`
and :func:`subpix_ros.core.superres.paper.interleave` is compared with a
plain reference written here from its docstring (dense per-bin solves,
whole-frame filtering, an array-wide roll-based hole fill, a per-exponent
least-squares loop). Random inputs; tolerances are the single-precision
round-off of the fast path.
"""

import cv2
import numpy as np
import pytest
from conftest import dense_map

from subpix_ros.core import superres as sr
from subpix_ros.core.filters import fractional_shift, tukey
from subpix_ros.core.render import render_sequence
from subpix_ros.core.shift import lk_inner_region, lk_window_context, lucas_kanade_batch
from subpix_ros.core.superres.dft import _assemble_hr
from subpix_ros.core.superres.geometry import _refine_shifts
from subpix_ros.core.superres.lowpass import _integer_preshift, _lowpass_window, _WholeLowpass
from subpix_ros.core.superres.model import frame_transfer_1d, gaussian_kernel
from subpix_ros.core.superres.paper import interleave
from subpix_ros.core.superres.result import _bicubic_rim
from subpix_ros.core.superres.separable import _solve_separable
from subpix_ros.core.superres.spectrum import _spectrum_bins


@pytest.mark.parametrize("p,n,block", [(2, 4, 40), (2, 7, 1 << 16), (3, 5, 64), (4, 3, 50)])
def test_separable_solve_equals_dense_per_bin_solve(p, n, block):
    rng = np.random.default_rng(p * 10 + n)
    hp, wp = 12, 14
    wc = wp // 2 + 1
    shifts = rng.uniform(-0.5, 0.5, (n, 2))
    shifts[0] = 0
    ay = np.stack([frame_transfer_1d(hp, p, s, 0.4)[0] for s in shifts[:, 0]])
    ax = np.stack([frame_transfer_1d(wp, p, s, 0.4)[0][:, :wc] for s in shifts[:, 1]])
    fy = frame_transfer_1d(hp, p, 0.0, 0.4)[1]
    fx = frame_transfer_1d(wp, p, 0.0, 0.4)[1][:, :wc]
    spec = (rng.normal(size=(n, hp, wc)) + 1j * rng.normal(size=(n, hp, wc))) * 100
    args = (spec.astype(np.complex64), ay, ax, fy, fx, 3.0e5, 2.5, 1.0, hp * wp * 0.5)
    ref = dense_map(spec, *args[1:])
    fast = _solve_separable(*args, block_bins=block)  # small blocks: several row blocks
    assert np.abs(fast - ref).max() < 1e-4 * np.abs(ref).max()
    # rank-one Gram entries from the shifts the transfers were built with (frame 0 not at 0 here)
    shifts[0] = rng.uniform(-0.5, 0.5, 2)
    ay = np.stack([frame_transfer_1d(hp, p, s, 0.4)[0] for s in shifts[:, 0]])
    ax = np.stack([frame_transfer_1d(wp, p, s, 0.4)[0][:, :wc] for s in shifts[:, 1]])
    args = (spec.astype(np.complex64), ay, ax, fy, fx, 3.0e5, 2.5, 1.0, hp * wp * 0.5)
    ref = dense_map(spec, *args[1:])
    fast = _solve_separable(*args, block_bins=block, shifts=shifts)
    assert np.abs(fast - ref).max() < 1e-4 * np.abs(ref).max()


@pytest.mark.parametrize("p", [2, 3, 4])
@pytest.mark.parametrize("hp,wp", [(16, 16), (15, 21), (18, 25), (27, 32)])
def test_assemble_hr_inverts_the_alias_split(p, hp, wp):
    rng = np.random.default_rng(hp * wp + p)
    img = rng.normal(size=(p * hp, p * wp))
    spec = np.fft.fft2(img)
    wc = wp // 2 + 1
    xs = np.empty((p, p, hp, wc), np.complex64)
    for m1 in range(p):
        for m2 in range(p):
            xs[m1, m2] = spec[m1 * hp : (m1 + 1) * hp, m2 * wp : m2 * wp + wc]
    out = _assemble_hr(xs, hp, wp)
    assert out.shape == img.shape
    assert np.abs(out - img).max() < 1e-4


def _interleave_reference(frames, offsets, p, q):
    """Build the eq. 3 interleave as documented, the hole fill as whole-array cyclic rolls."""
    h, w = frames[0].shape
    acc = np.zeros((h * p, w * q))
    cnt = np.zeros((h * p, w * q))
    for fr, (tr, tc) in zip(frames, offsets):
        for i in range(h):
            for j in range(w):
                k, l = p * i - tr, q * j - tc
                if 0 <= k < h * p and 0 <= l < w * q:
                    acc[k, l] += p * q * float(fr[i, j])
                    cnt[k, l] += 1
    filled = cnt > 0
    y = np.where(filled, acc / np.maximum(cnt, 1), 0.0)
    have = filled.copy()
    for axis, f in ((0, p), (1, q), (0, p), (1, q)):
        for d in range(1, f + 1):
            for sgn in (1, -1):
                take = ~have & np.roll(have, sgn * d, axis=axis)
                y[take] = np.roll(y, sgn * d, axis=axis)[take]
                have |= take
            if have.all():
                break
        if have.all():
            break
    return y, filled


@pytest.mark.parametrize("p,q", [(2, 2), (3, 2), (4, 4)])
def test_interleave_equals_reference(p, q):
    rng = np.random.default_rng(p * q)
    for trial in range(6):
        h, w = rng.integers(4, 12, 2)
        if trial == 0:  # the standard grid
            offs = np.array([(a, b) for a in range(p) for b in range(q)])
        else:  # random: duplicates, missing phases, frames partly or wholly outside
            offs = rng.integers(-2 * p, 2 * p, (int(rng.integers(1, 2 * p * q)), 2))
        frames = [rng.integers(0, 256, (h, w)).astype(np.uint8) for _ in range(len(offs))]
        y_ref, f_ref = _interleave_reference(frames, offs, p, q)
        y, filled = interleave(frames, offs, p, q)
        np.testing.assert_array_equal(filled, f_ref)
        np.testing.assert_allclose(y, y_ref, rtol=1e-12, atol=1e-9)
        y32, _ = interleave(frames, offs, p, q, dtype=np.float32)
        # 8-bit sums are exact in float32; averages of frames sharing a phase are rounded to float32
        np.testing.assert_allclose(y32.astype(np.float64), y_ref, rtol=1.2e-7, atol=0)
        if len({(int(a) % p, int(b) % q) for a, b in offs}) == len(offs):
            np.testing.assert_array_equal(y32.astype(np.float64), y_ref)


@pytest.mark.parametrize(
    "pre,post", [((0, 0), (0, 0)), ((1, -2), (0, 0)), ((0, 0), (-1, 1)), ((2, 1), (1, -1))]
)
def test_lowpass_window_equals_whole_frame_filter(pre, post):
    rng = np.random.default_rng(5)
    frame = rng.normal(size=(60, 70))
    g = gaussian_kernel(1.0)
    whole = cv2.sepFilter2D(
        _integer_preshift(frame, *pre), cv2.CV_64F, g, g, borderType=cv2.BORDER_REFLECT_101
    )
    whole = _integer_preshift(whole, *post)
    for rows, cols in [
        (slice(20, 40), slice(25, 50)),
        (slice(0, 30), slice(0, 20)),
        (slice(45, 60), slice(50, 70)),
        (slice(2, 58), slice(1, 69)),
    ]:
        np.testing.assert_allclose(
            _lowpass_window(frame, g, pre, post, rows, cols),
            whole[rows, cols],
            rtol=0,
            atol=1e-12,
        )


def test_fractional_shift_window_equals_whole_image():
    rng = np.random.default_rng(6)
    img = rng.uniform(0, 255, (50, 64)).astype(np.float32)
    whole = fractional_shift(img, 0.3, -0.45)
    for win in [
        (slice(0, 10), slice(0, 64)),
        (slice(40, 50), slice(0, 64)),
        (slice(10, 40), slice(0, 7)),
        (slice(10, 40), slice(57, 64)),
        (slice(20, 30), slice(20, 30)),
    ]:
        np.testing.assert_allclose(
            fractional_shift(img, 0.3, -0.45, window=win), whole[win], rtol=0, atol=1e-3
        )


@pytest.mark.parametrize("p", [2, 3, 4])
def test_bicubic_rim_equals_whole_frame_bicubic(p):
    rng = np.random.default_rng(p)
    ref = rng.uniform(0, 255, (40, 52))
    img = rng.normal(size=(40 * p, 52 * p))
    inner = img[p:-p, p:-p].copy()
    out = _bicubic_rim(img.copy(), ref, p)
    bic = sr.bicubic_upscale(ref, p)
    np.testing.assert_array_equal(out[p:-p, p:-p], inner)  # the inside is untouched
    rim = np.ones(out.shape, bool)
    rim[p:-p, p:-p] = False
    # strips vs whole frame: OpenCV's cubic weights are single precision, from absolute coordinates
    assert np.abs(out[rim] - bic[rim]).max() < 0.02


def test_refined_shifts_do_not_depend_on_batching(crops):
    seq = render_sequence(
        crops["crop_trees"][: 2 * 160, : 2 * 160],
        2,
        [(0, 0), (0.3, 0.6), (0.55, 0.1), (0.8, 0.9)],
        blur_sigma=0.4,
        snr_db=40,
        seed=3,
    )
    frames = np.stack(seq.frames).astype(np.float64)
    given = seq.shifts + np.array([[0, 0], [0.05, -0.04], [-0.03, 0.06], [0.02, 0.03]])
    ishift = np.rint(given).astype(np.int64)
    resid = given - ishift
    together = _refine_shifts(frames, ishift, resid)
    for i in range(1, 4):  # each frame alone against the reference
        alone = _refine_shifts(frames[[0, i]], ishift[[0, i]], resid[[0, i]])
        np.testing.assert_allclose(alone[0][1], together[0][i], rtol=0, atol=1e-12)
        np.testing.assert_allclose(alone[1][1], together[1][i], rtol=1e-9)
        np.testing.assert_allclose(alone[3][1], together[3][i], rtol=1e-9)
    assert np.abs(together[0] + ishift - seq.shifts).max() < 0.01


def _fit_one_exponent(alpha, psd_obs, amp, logf, noise_sigma):
    """Return (misfit, c, sigma^2) of one exponent: 3 passes of weighted least squares.

    As fit_spectrum documents.
    """
    q = np.sum(amp * np.exp(-alpha * logf), axis=0)
    wgt = 1.0 / np.maximum(psd_obs, 1e-12) ** 2
    for _ in range(3):
        if noise_sigma is None:
            mat = np.stack([q, np.ones_like(q)], axis=1)
            c_, s2 = np.linalg.solve((mat * wgt[:, None]).T @ mat, (mat * wgt[:, None]).T @ psd_obs)
            s2 = max(s2, 1e-6)
        else:
            s2 = noise_sigma**2
            c_ = float(np.sum(wgt * q * (psd_obs - s2)) / np.sum(wgt * q * q))
        c_ = max(c_, 1e-12)
        model = c_ * q + s2
        wgt = 1.0 / model**2
    return float(np.mean(((psd_obs - model) / model) ** 2)), c_, s2


def _fit_spectrum_loop(psd_obs, amp, logf, noise_sigma, alphas):
    """fit_spectrum's exponent search over ``alphas`` written as the plain per-exponent loop."""
    fits = [(*_fit_one_exponent(a, psd_obs, amp, logf, noise_sigma), a) for a in alphas]
    err, c_, s2, alpha = min(fits, key=lambda t: t[0])
    return c_, alpha, float(np.sqrt(s2))


@pytest.mark.parametrize("noise_sigma", [None, 0.6])
@pytest.mark.parametrize("p", [2, 3])
def test_fit_spectrum_equals_per_exponent_loop(crops, p, noise_sigma):
    seq = render_sequence(
        crops["crop_field_edge"][: 100 * p, : 100 * p],
        p,
        [(0, 0), (0.5, 0.5)],
        blur_sigma=0.4,
        snr_db=40,
        seed=2,
    )
    frames = np.stack(seq.frames).astype(np.float64)
    c, alpha, sigma = sr.fit_spectrum(frames, p, 0.4, noise_sigma)
    # the same observation and model terms, built as fit_spectrum's docstring states
    h = w = frames.shape[1]
    win = np.outer(tukey(h), tukey(w))
    x = (frames - frames.mean(axis=(1, 2), keepdims=True)) * win
    psd = np.mean([np.abs(np.fft.rfft2(f)) ** 2 for f in x], axis=0) / float(np.sum(win**2))
    ay, fy = frame_transfer_1d(h, p, 0.0, 0.4)
    ax, fx = frame_transfer_1d(w, p, 0.0, 0.4)
    wc = w // 2 + 1
    sel = _spectrum_bins(h, w, 8000)
    ky, kx = np.unravel_index(sel, (h, wc))
    amp = (np.abs(ay[:, None, ky] * ax[:, :wc][None, :, kx]) ** 2).reshape(p * p, -1) * p * p
    logf = np.log(
        np.maximum(np.hypot(fy[:, None, ky], fx[:, :wc][None, :, kx]).reshape(p * p, -1), 1e-9)
    )
    obs = psd.ravel()[sel]
    # the documented search: 0.3 grid over [1, 4], then the 0.1 grid within +-0.2 of its winner
    a_coarse = _fit_spectrum_loop(obs, amp, logf, noise_sigma, 1.0 + 0.3 * np.arange(11))[1]
    fine = [a for a in a_coarse + 0.1 * np.arange(-2, 3) if 1.0 - 1e-9 <= a <= 4.0 + 1e-9]
    c_ref, alpha_ref, sigma_ref = _fit_spectrum_loop(obs, amp, logf, noise_sigma, fine)
    # and it finds the minimum of the full 0.1 grid (the misfit has one minimum in alpha)
    assert _fit_spectrum_loop(obs, amp, logf, noise_sigma, 1.0 + 0.1 * np.arange(31))[
        1
    ] == pytest.approx(alpha_ref)
    assert alpha == pytest.approx(alpha_ref, abs=1e-9)
    assert c == pytest.approx(c_ref, rel=1e-3)  # single- vs double-precision periodogram
    assert sigma == pytest.approx(sigma_ref, rel=1e-3)


@pytest.mark.parametrize(
    "pre,post",
    [((0, 0), (0, 0)), ((1, -2), (0, 0)), ((0, 0), (-1, 1)), ((0, 0), (2, -3)), ((2, 1), (1, -1))],
)
def test_lowpass_window_from_whole_lowpass_equals_direct(pre, post):
    """Windows sliced (or reflected) from the shared low-pass equal the per-window filtering.

    To the shared low-pass's single-precision round-off: values ~100, float32 eps 1.2e-7.
    """
    rng = np.random.default_rng(7)
    frames = rng.normal(size=(2, 60, 70)) * 30 + 100
    g = gaussian_kernel(1.0)
    lp = _WholeLowpass(frames)
    assert lp.get(1, 1.0) is not None and lp.get(1, 0.5) is None  # another low-pass: not shared
    for rows, cols in [
        (slice(20, 40), slice(25, 50)),
        (slice(0, 30), slice(0, 20)),
        (slice(45, 60), slice(50, 70)),
        (slice(2, 58), slice(1, 69)),
        (slice(0, 60), slice(0, 70)),
    ]:
        direct = _lowpass_window(frames[1], g, pre, post, rows, cols)
        shared = _lowpass_window(frames[1], g, pre, post, rows, cols, whole=lp.get(1, 1.0))
        assert shared.shape == direct.shape
        if pre == (0, 0):  # always served from the shared (single-precision) low-pass
            assert shared.dtype == np.float32
        np.testing.assert_allclose(shared, direct, rtol=0, atol=1e-4)


def test_lk_residual_variance_equals_direct_residual(crops):
    """lucas_kanade_batch's noise variance from the z z^T sums equals var(F - R - d . grad R) on pixels."""
    seq = render_sequence(
        crops["crop_trees"][: 2 * 96, : 2 * 96],
        2,
        [(0, 0), (0.3, -0.4)],
        blur_sigma=0.4,
        snr_db=40,
        seed=4,
    )
    frames = np.stack(seq.frames).astype(np.float64)
    g = gaussian_kernel(1.0)
    sl = (slice(24, 72), slice(24, 72))
    ctx = lk_window_context(sl, 96, 96)
    inner = lk_inner_region(sl, ctx)
    ref = _lowpass_window(frames[0], g, (0, 0), (0, 0), *ctx)

    def mov(_k, iu, iv):
        return _lowpass_window(frames[1], g, (0, 0), (iu, iv), *ctx)

    s, sig, rv = lucas_kanade_batch(
        [ref], np.zeros(1, int), mov, np.arange(1), np.array([[0.25, -0.35]]), inner, g, iters=1
    )
    # the same single Gauss-Newton step written out on the pixels (Fourier shift by the start value)
    pad = 8
    pr = np.pad(ref, pad, mode="reflect")
    ky = np.fft.fftfreq(pr.shape[0])[:, None]
    kx = np.fft.fftfreq(pr.shape[1])[None, :]
    s0 = np.array([0.25, -0.35])
    pred = np.fft.ifft2(np.fft.fft2(pr) * np.exp(-2j * np.pi * (ky * s0[0] + kx * s0[1]))).real[
        pad:-pad, pad:-pad
    ]
    gy, gx = np.gradient(pred)
    r0, r1, c0, c1 = inner[0].start, inner[0].stop, inner[1].start, inner[1].stop
    e = (mov(0, 0, 0) - pred)[r0:r1, c0:c1].ravel()
    gm = np.stack([gy[r0:r1, c0:c1].ravel(), gx[r0:r1, c0:c1].ravel()], axis=1)
    step = -np.linalg.solve(gm.T @ gm, gm.T @ e)
    resid = e + gm @ step
    np.testing.assert_allclose(s[0], s0 + step, rtol=0, atol=1e-4)
    np.testing.assert_allclose(rv[0], np.var(resid) / (2.0 * np.sum(g**2) ** 2), rtol=2e-3)


def test_noise_estimate_of_8bit_frames_equals_float_path():
    """The histogram median of 8-bit frames is exactly the float path's np.median (odd, even n)."""
    rng = np.random.default_rng(8)
    for h, w in [(3, 3), (4, 5), (17, 30), (64, 64), (101, 37)]:
        for spread in (0.3, 5.0, 60.0):
            f = np.clip(np.rint(rng.normal(128, spread, (h, w))), 0, 255).astype(np.uint8)
            assert sr.estimate_noise_sigma(f) == sr.estimate_noise_sigma(f.astype(np.float64))
    f = rng.integers(0, 256, (300, 280)).astype(np.uint8)
    assert sr.estimate_noise_sigma(f, max_size=256) == sr.estimate_noise_sigma(
        f.astype(np.float64), max_size=256
    )
