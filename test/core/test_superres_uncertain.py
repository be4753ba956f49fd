"""The MAP solve with a registration-error covariance (the uncertain solver), any frame count."""

import numpy as np
import pytest

from subpix_ros.core.render import render_sequence
from subpix_ros.core.superres import bicubic_upscale, psnr, reconstruct
from subpix_ros.data import load_crop


def _flight(p, n, seed):
    rng = np.random.default_rng(seed)
    shifts = rng.uniform(-1, 1, (n, 2))
    shifts[0] = 0.0
    crop = load_crop("crop_trees")[:192, :192]
    return render_sequence(crop, p, shifts, 0.4, snr_db=40, seed=seed)


def _gain(seq, img, p):
    return psnr(img, seq.truth, 4 * p) - psnr(bicubic_upscale(seq.frames[0], p), seq.truth, 4 * p)


@pytest.mark.parametrize("p, n", [(2, 3), (3, 4), (3, 8), (4, 8), (2, 6)])
def test_a_registration_covariance_costs_nothing_with_fewer_frames_than_unknowns(p, n):
    """Fewer frames than p^2 with shift_cov: the image of the same solve without it.

    (The covariance form of the solve, n x n per bin, once returned a finite image some 600 dB
    below bicubic here: the DC's 1e30 prior variance swamped the rest.)
    """
    seq = _flight(p, n, seed=p * 10 + n)
    kw = dict(blur_sigma=0.4, refine_shifts=False)
    plain = reconstruct(seq.frames, seq.shifts, p, **kw)
    cov = np.tile(np.diag([0.02**2, 0.02**2]), (n, 1, 1))
    uncertain = reconstruct(seq.frames, seq.shifts, p, shift_cov=cov, **kw)
    assert uncertain.method == "map" and not uncertain.fell_back, uncertain.reason
    g0, g1 = _gain(seq, plain.image, p), _gain(seq, uncertain.image, p)
    assert g0 > 1.0 and abs(g1 - g0) < 0.1


def test_a_diverged_solve_falls_back_to_bicubic_and_says_so(monkeypatch):
    """A finite image far outside the frames' range is not published as an estimate."""
    from subpix_ros.core.superres import reconstruction as mod

    real = mod._fourier_map

    def diverged(*a, **k):
        sol = real(*a, **k)
        sol.image[10:12, 10:12] = 1e12
        return sol

    monkeypatch.setattr(mod, "_fourier_map", diverged)
    seq = _flight(2, 4, seed=1)
    res = reconstruct(seq.frames, seq.shifts, 2, blur_sigma=0.4, refine_shifts=False)
    assert res.fell_back and res.method == "bicubic" and "diverged" in res.reason
    assert np.array_equal(res.image, bicubic_upscale(seq.frames[0], 2))
