import numpy as np
import pytest

from subpix_ros.core.render import box_integrate, fourier_shift_blur, render_sequence


def test_integer_fourier_shift_is_exact_roll():
    rng = np.random.default_rng(1)
    img = rng.normal(size=(64, 80))
    out = fourier_shift_blur(img, (3, -2), 0.0)
    # content moves by (+3, -2): out[r, c] == img[r - 3, c + 2] away from the border
    np.testing.assert_allclose(out[10:-10, 10:-10], img[7:-13, 12:-8], atol=1e-9)


def test_box_integrate_mean_of_blocks():
    x = np.arange(16, dtype=float).reshape(4, 4)
    np.testing.assert_allclose(box_integrate(x, 2), [[2.5, 4.5], [10.5, 12.5]])


def test_sequence_shift_convention(crops):
    # A shift of exactly one LR pixel equals a one-pixel roll of the reference frame.
    seq = render_sequence(
        crops["crop_rows"][:256, :256], 2, [(0, 0), (1, 0), (0, -1)], 0.4, quantize=False
    )
    ref, down, left = seq.frames
    np.testing.assert_allclose(down[1:], ref[:-1], atol=1e-6)
    np.testing.assert_allclose(left[:, :-1], ref[:, 1:], atol=1e-6)
    assert seq.truth.shape == (2 * ref.shape[0], 2 * ref.shape[1])


def test_pad_too_small_raises():
    with pytest.raises(ValueError):
        fourier_shift_blur(np.zeros((16, 16)), (10, 0), 0.0, pad=8)
