"""Property tests (hypothesis) for the core estimators.

Invariances that must hold for any shift, crop and offset, not just the hand-picked cases.
"""

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from subpix_ros.core.registration import register
from subpix_ros.core.render import render_sequence
from subpix_ros.core.shift import estimate_shift
from subpix_ros.data import CROP_NAMES, load_crop

CROPS = {n: load_crop(n) for n in CROP_NAMES}
FAST = settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
frac = st.floats(min_value=-2.5, max_value=2.5, allow_nan=False)


def _pair(name, r0, c0, shift, seed):
    hr = CROPS[name][r0 : r0 + 320, c0 : c0 + 320]
    return render_sequence(hr, 2, [(0.0, 0.0), shift], 0.4, snr_db=40, seed=seed, margin=12).frames


@FAST
@given(
    name=st.sampled_from(CROP_NAMES),
    r0=st.integers(0, 400),
    c0=st.integers(0, 400),
    u=frac,
    v=frac,
    seed=st.integers(0, 1000),
)
def test_shift_estimate_recovers_any_shift(name, r0, c0, u, v, seed):
    ref, mov = _pair(name, r0, c0, (u, v), seed)
    r = estimate_shift(ref, mov)
    assert r.ok, r.reason
    assert abs(r.u - u) < 0.02 and abs(r.v - v) < 0.02, (r.u, r.v, u, v)


@FAST
@given(name=st.sampled_from(CROP_NAMES), u=frac, v=frac, a=st.integers(-5, 5), b=st.integers(-5, 5))
def test_moving_the_input_by_whole_pixels_moves_the_estimate(name, u, v, a, b):
    ref, mov = _pair(name, 200, 200, (u, v), 1)
    r1 = estimate_shift(ref, mov)
    # content of the moving frame moved by (a, b) more: crop both frames consistently
    h, w = mov.shape
    m = 6
    moved = np.zeros_like(mov)
    moved[m + a : h - m + a, m + b : w - m + b] = mov[m : h - m, m : w - m]
    valid = np.zeros(mov.shape, bool)
    valid[m + a : h - m + a, m + b : w - m + b] = True
    r2 = estimate_shift(ref, moved, mask=(np.ones_like(valid), valid))
    assert r1.ok and r2.ok
    assert abs((r2.u - r1.u) - a) < 0.01 and abs((r2.v - r1.v) - b) < 0.01


@FAST
@given(name=st.sampled_from(CROP_NAMES), u=frac, v=frac)
def test_swapping_the_frames_negates_the_shift(name, u, v):
    ref, mov = _pair(name, 100, 300, (u, v), 2)
    f, b = estimate_shift(ref, mov), estimate_shift(mov, ref)
    assert f.ok and b.ok
    assert abs(f.u + b.u) < 0.01 and abs(f.v + b.v) < 0.01


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    name=st.sampled_from(["crop_road", "crop_trees", "crop_field_edge"]),
    u=st.floats(-6, 6),
    v=st.floats(-6, 6),
)
def test_registration_of_a_translation_is_that_translation(name, u, v):
    hr = CROPS[name][:640, :640]
    ref, mov = render_sequence(
        hr, 2, [(0.0, 0.0), (u, v)], 0.4, snr_db=40, seed=3, margin=12
    ).frames
    r = register(ref, mov)
    assert r.ok, r.reason
    # moving (x, y) -> reference: content moved by +(u, v) (rows, cols), so H translates by -(v, u)
    hn = r.homography / r.homography[2, 2]
    assert abs(hn[0, 2] + v) < 0.1 and abs(hn[1, 2] + u) < 0.1
    np.testing.assert_allclose(hn[:2, :2], np.eye(2), atol=2e-3)
