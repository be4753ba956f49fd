"""core.motion: constant-velocity prediction of the next frame's homography."""

import numpy as np
import pytest

from subpix_ros.core.motion import frame_motion, predict_homography, scale_motion


def _h(tx, ty, ang=0.0, s=1.0):
    c, si = s * np.cos(ang), s * np.sin(ang)
    return np.array([[c, -si, tx], [si, c, ty], [0, 0, 1.0]])


def test_constant_velocity_sequence_is_predicted_exactly():
    d = _h(3.2, -1.7, np.deg2rad(0.3), 1.001)  # frame k -> frame k-1, the same every frame
    hs = [np.linalg.matrix_power(d, k) for k in range(1, 6)]  # frame k -> reference (frame 0)
    motion = frame_motion(None, hs[0])
    np.testing.assert_allclose(motion, d, atol=1e-12)
    for k in range(1, 5):
        pred = predict_homography(hs[k - 1], motion)
        np.testing.assert_allclose(pred, hs[k], atol=1e-9)
        motion = frame_motion(hs[k - 1], hs[k])
        np.testing.assert_allclose(motion, d, atol=1e-9)


def test_new_reference_restarts_chain_but_keeps_motion():
    d = _h(0.41, 0.27)
    # the last frame of the old set becomes the reference: the next frame is one step D from it
    np.testing.assert_allclose(predict_homography(None, d), d)
    # a point of the next frame lands where the motion says in the new reference
    x = np.array([100.0, 50.0, 1.0])
    assert np.allclose(predict_homography(None, d) @ x, [100.41, 50.27, 1.0])


def test_scale_of_homography_is_irrelevant_and_bad_input_raises():
    d = _h(1.0, 2.0)
    np.testing.assert_allclose(frame_motion(3.0 * np.eye(3), 5.0 * d), d)
    with pytest.raises(ValueError):
        frame_motion(None, np.full((3, 3), np.nan))
    with pytest.raises(ValueError):
        frame_motion(np.zeros((3, 3)) + np.diag([1.0, 0.0, 1.0]), d)


def test_motion_scaled_by_frame_interval():
    d = _h(0.41, 0.27)  # measured over one frame interval
    np.testing.assert_allclose(
        scale_motion(d, 3.0), _h(1.23, 0.81), atol=1e-12
    )  # two frames dropped
    np.testing.assert_allclose(scale_motion(d, 0.0), np.eye(3), atol=1e-12)
    r = _h(2.0, -1.0, np.deg2rad(0.2))
    # first order: off the true matrix power by ~ rotation x translation (0.0035 rad x 2 px = 0.007 px here),
    # far inside the tracking search radius
    np.testing.assert_allclose(scale_motion(r, 2.0), r @ r, atol=1e-2)
    np.testing.assert_allclose(
        predict_homography(_h(5.0, 1.0), d, ratio=2.0), _h(5.82, 1.54), atol=1e-12
    )
    with pytest.raises(ValueError):
        scale_motion(d, -1.0)


def test_tracker_follows_restarts_forgets_and_gives_up_on_long_gaps():
    from subpix_ros.core.motion import MotionTracker

    d = _h(0.41, 0.27)  # per 0.1 s
    tr = MotionTracker()
    tr.restart(0.0)
    assert tr.predict(0.1) is None  # no motion known, the last frame is the reference: search fully
    tr.update(d, 0.1)
    np.testing.assert_allclose(tr.predict(0.2), d @ d, atol=1e-12)
    np.testing.assert_allclose(
        tr.predict(0.4), _h(1.23 + 0.41, 0.81 + 0.27), atol=1e-12
    )  # two frames lost
    tr.restart(0.1)  # frame 1 becomes the reference: the chain restarts, the motion carries on
    np.testing.assert_allclose(tr.predict(0.2), d, atol=1e-12)
    assert tr.predict(0.1 + 0.1 * 25) is None  # a gap of 25 intervals predicts nothing
    tr.update(d, 0.2)
    tr.forget()  # registration failed: constant position only
    np.testing.assert_allclose(tr.predict(0.3), d, atol=1e-12)
