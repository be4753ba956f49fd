"""Incremental overview mosaic: the real 9-frame Seneca strip, bounded canvas, rejected frames."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from subpix_ros.core.mosaic import FrameGeometry, Mosaic, PairModel
from subpix_ros.core.registration import apply_h
from subpix_ros.data import seneca_frame_paths


@pytest.fixture(scope="module")
def frames():
    return [cv2.imread(str(p)) for p in seneca_frame_paths()]


@pytest.fixture(scope="module")
def strip_mosaic(frames):
    m = Mosaic(max_size_px=1200)
    ups = [m.add(f) for f in frames]
    return m, ups


def test_strip_keeps_every_frame_with_small_seam_residual(strip_mosaic):
    m, ups = strip_mosaic
    assert all(u.ok for u in ups), [u.reason for u in ups if not u.ok]
    seams = [u.seam_residual_px for u in ups[1:]]
    assert max(seams) <= 1.0, seams  # issue target: <= 1 px at half resolution
    img = m.image()
    assert img.dtype == np.uint8 and img.ndim == 3 and max(img.shape[:2]) <= 1200


def test_reversed_strip_keeps_every_frame_with_small_seam_residual(frames):
    """Keep every frame of the same strip flown the other way (frames 8..0).

    The new frame's overlap is now on its other side and the h(y) transition runs the other way
    round; every frame is kept all the same.
    """
    m = Mosaic(max_size_px=1200)
    ups = [m.add(f) for f in frames[::-1]]
    assert all(u.ok for u in ups), [u.reason for u in ups if not u.ok]
    seams = [u.seam_residual_px for u in ups[1:]]
    assert max(seams) <= 1.0, seams


def test_mosaic_content_matches_last_frame(strip_mosaic, frames):
    """The newest frame is drawn on top: sampling the canvas through its chain reproduces it."""
    m, _ = strip_mosaic
    t = m._s @ m.transforms[-1]
    small = cv2.warpPerspective(
        m.image(),
        np.linalg.inv(t) @ np.diag([1.0, 1.0, 1.0]),
        (frames[-1].shape[1], frames[-1].shape[0]),
    )
    # compare at the canvas' resolution: blur the frame to the canvas scale
    k = int(round(1 / m.scale))
    ref = cv2.resize(
        cv2.resize(frames[-1], None, fx=1 / k, fy=1 / k, interpolation=cv2.INTER_AREA),
        (frames[-1].shape[1], frames[-1].shape[0]),
        interpolation=cv2.INTER_LINEAR,
    )
    inner = (slice(200, -200), slice(200, -200))
    diff = np.abs(small[inner].astype(float) - ref[inner].astype(float)).mean()
    assert diff < 12, diff


def test_canvas_is_bounded_and_rescales(frames):
    m = Mosaic(max_size_px=300, scale=0.12)
    s0 = None
    for f in frames[:5]:
        u = m.add(f)
        assert u.ok, u.reason
        s0 = s0 or u.scale
        assert max(u.canvas_shape) <= 300
    assert m.scale < s0  # the strip outgrew 300 px and the canvas was downscaled


def test_rejected_frame_is_skipped_and_chain_continues(frames):
    m = Mosaic(max_size_px=800)
    assert m.add(frames[3]).ok
    bad = m.add(np.full_like(frames[4], 90))
    assert not bad.ok and "blank" in bad.reason and m.transforms[-1] is None
    u = m.add(frames[4])  # registered to frame 3, the last accepted one
    assert u.ok and u.seam_residual_px is not None


def test_bad_input_raises():
    m = Mosaic()
    with pytest.raises(ValueError):
        m.add(np.zeros((100, 100), np.float32))
    with pytest.raises(ValueError):
        Mosaic(max_size_px=10)


# -- h(y) transition (METHODS C, eq. 3) -------------------------------------------------------


def _h_forward(dy: float, persp: float) -> np.ndarray:
    """Return frame k px -> frame k-1 px for a 200x300 (HxW) frame advanced by ``dy`` rows.

    With a small rotation and perspective (so that H is not a similarity).
    """
    th = np.deg2rad(2.0)
    h = np.array([[np.cos(th), -np.sin(th), 3.0], [np.sin(th), np.cos(th), dy], [0.0, persp, 1.0]])
    return h


def test_transition_weight_and_maps_follow_eq3():
    shape = (200, 300)
    h_prev = PairModel(
        _h_forward(120.0, 2e-4)
    )  # frame k -> k-1 (frame k lies 120 rows further down)
    h_next = PairModel(_h_forward(110.0, -1e-4))  # frame k+1 -> k
    p_prev = np.array(
        [[0.9, -0.1, 40.0], [0.1, 0.9, 70.0], [0, 0, 1.0]]
    )  # similarity placing frame k-1
    geo = FrameGeometry.chained(p_prev, h_prev, shape, shape, h_next, shape)
    # flight direction: frame k-1's centre maps to negative rows of frame k -> d points down (+y)
    assert geo.direction[1] > 0.99
    xs = np.linspace(0, 299, 31)
    trailing = np.stack([xs, np.zeros_like(xs)], 1)  # row 0: the edge frame k-1 is seen across
    assert np.allclose(geo.weight(trailing), 1.0)
    g = np.stack(np.meshgrid(np.linspace(0, 299, 13), np.linspace(0, 199, 9)), -1).reshape(-1, 2)
    inside_next = h_next.fwd(g)  # frame k+1's pixels in frame k ...
    inside_next = inside_next[
        (inside_next >= 0).all(1) & (inside_next[:, 0] <= 299) & (inside_next[:, 1] <= 199)
    ]
    assert len(inside_next) > 20 and np.allclose(
        geo.weight(inside_next), 0.0
    )  # ... keep frame k's own geometry
    # linear in between (eq. 3: h = 1 - (y - H_k) / (H_(k+1) - H_k))
    t = np.linspace(geo.t1, geo.t2, 7)
    pts = geo.centre + t[:, None] * geo.direction
    np.testing.assert_allclose(geo.weight(pts), 1 - (t - geo.t1) / (geo.t2 - geo.t1), atol=1e-12)
    # D_k = P_(k-1) H_k where h = 1, and P_k = P_(k-1) A_k (own geometry) where h = 0
    np.testing.assert_allclose(
        geo.to_mosaic(trailing), apply_h(p_prev, h_prev.fwd(trailing)), atol=1e-9
    )
    np.testing.assert_allclose(
        geo.to_mosaic(inside_next), apply_h(geo.placement, inside_next), atol=1e-9
    )
    a = geo.placement[:2, :2]
    np.testing.assert_allclose(a @ a.T, np.eye(2) * np.linalg.det(a), atol=1e-12)  # a similarity
    # H is not a similarity, so the two geometries really differ inside the frame
    assert (
        np.abs(apply_h(p_prev, h_prev.fwd(inside_next)) - apply_h(geo.placement, inside_next)).max()
        > 1.0
    )


def test_seam_is_exact_and_own_geometry_reverses():
    """Frame k+1 drawn with h = 1 at its seam lands exactly on frame k's own geometry.

    Going back over the same pair reverses the similarity exactly (no drift from the
    construction).
    """
    shape = (200, 300)
    hk, hk1 = PairModel(_h_forward(120.0, 2e-4)), PairModel(_h_forward(110.0, -1e-4))
    geo_k = FrameGeometry.chained(np.eye(3), hk, shape, shape, hk1, shape)
    geo_k1 = FrameGeometry.chained(geo_k.placement, hk1, shape, shape)
    seam = np.stack([np.linspace(0, 299, 11), np.zeros(11)], 1)  # frame k+1's trailing edge
    np.testing.assert_allclose(geo_k1.to_mosaic(seam), geo_k.to_mosaic(hk1.fwd(seam)), atol=1e-9)
    back = FrameGeometry.chained(np.eye(3), PairModel(np.linalg.inv(hk1.h)), shape, shape)
    np.testing.assert_allclose(geo_k1.a @ back.a, np.eye(3), atol=1e-9)


def test_strip_visible_parts_match_their_frames(strip_mosaic, frames):
    """Sampled through a frame's drawing map, the canvas reproduces the frame where it is visible.

    Where each frame stays visible (not covered by later ones); a 2-canvas-px displacement does
    not.
    """
    m, _ = strip_mosaic
    img = m.image()
    hh, ww = frames[0].shape[:2]
    ys, xs = np.mgrid[40 : hh - 40 : 4, 40 : ww - 40 : 4]
    pts = np.stack([xs.ravel(), ys.ravel()], 1).astype(float)
    k = int(round(1 / m.scale))
    border = np.array([[0, 0], [ww - 1, 0], [ww - 1, hh - 1], [0, hh - 1]], float)
    for i in range(len(frames)):
        q = m.to_canvas(i, pts).astype(np.float32)
        covered = np.zeros(img.shape[:2], np.uint8)
        for j in range(i + 1, len(frames)):
            cv2.fillConvexPoly(covered, np.rint(m.to_canvas(j, border)).astype(np.int32), 1)
        covered = cv2.dilate(covered, np.ones((7, 7), np.uint8))
        qi = np.clip(np.rint(q).astype(int), 0, [img.shape[1] - 1, img.shape[0] - 1])
        vis = covered[qi[:, 1], qi[:, 0]] == 0
        assert vis.sum() > 20000, (i, vis.sum())
        ref = (
            cv2.resize(
                cv2.resize(frames[i], None, fx=1 / k, fy=1 / k, interpolation=cv2.INTER_AREA),
                (ww, hh),
                interpolation=cv2.INTER_LINEAR,
            )[ys, xs]
            .reshape(-1, 3)
            .astype(float)
        )

        def diff(dx):
            s = cv2.remap(
                img, (q[:, 0] + dx).reshape(xs.shape), q[:, 1].reshape(xs.shape), cv2.INTER_LINEAR
            )
            return np.abs(s.reshape(-1, 3).astype(float) - ref)[vis].mean()

        assert diff(0.0) < 6.0, (i, diff(0.0))
        assert diff(2.0) > diff(0.0) + 1.0, (i, diff(0.0), diff(2.0))


def test_back_and_forth_placement_does_not_drift_like_the_homography_chain(frames):
    """Frames 0..4..0: frame 0's placement on return vs the first time.

    Corner displacement, frame px, against the plain homography chain over the same
    registrations.
    """
    m = Mosaic(max_size_px=800)
    seq = [0, 1, 2, 3, 4, 3, 2, 1, 0]
    chain = [np.eye(3)]
    for i, k in enumerate(seq):
        u = m.add(frames[k])
        assert u.ok, u.reason
        if i:
            chain.append(chain[-1] @ u.registration.homography)
    hh, ww = frames[0].shape[:2]
    c = np.array([[0, 0], [ww - 1, 0], [ww - 1, hh - 1], [0, hh - 1]], float)
    drift = np.hypot(*(apply_h(m.transforms[-1], c) - c).T).max()
    drift_h = np.hypot(*(apply_h(chain[-1], c) - c).T).max()
    assert drift < 8.0, drift  # loop closure over 8 registrations, frame px
    # and no worse than chaining the same homographies (which also accumulates their perspective terms);
    # with the registrations of issue 4 the chain itself closes to ~15 px (33 px with the earlier ones)
    assert drift < drift_h, (drift, drift_h)


def test_frames_reduced_to_frame_max_px(frames, strip_mosaic):
    """Reduced frames: every frame still added, geometry in reduced pixels, same placement as the full-size mosaic."""
    full, _ = strip_mosaic
    m = Mosaic(max_size_px=1200, frame_max_px=900)
    ups = [m.add(f) for f in frames[:5]]
    assert all(u.ok for u in ups), [u.reason for u in ups if not u.ok]
    assert all(g.shape == (675, 900) for g in m.geometries)
    # frame 4's centre, placed through the reduced chain (x 2 back to full px) and through the full-size chain
    c_red = apply_h(m.transforms[4], np.array([[449.5, 337.0]]))[0] * 2 + 0.5
    c_full = apply_h(full.transforms[4], np.array([[899.5, 674.5]]))[0]
    assert np.hypot(*(c_red - c_full)) < 3.0, (c_red, c_full)
    with pytest.raises(ValueError):
        Mosaic(frame_max_px=10)


def test_stamped_frames_are_tracked_from_the_last_motion_and_drawn_the_same(frames):
    # a steady flight: windows of a real frame moving 37.4 px down, 11.2 px right per 0.5 s
    big = frames[0]
    win = (600, 800)

    def window(k):
        y, x = 40 + 37.4 * k, 30 + 11.2 * k
        m = np.float32([[1, 0, x], [0, 1, y]])
        return cv2.warpAffine(big, m, win[::-1], flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP)

    seq = [window(k) for k in range(8)]
    plain, stamped = Mosaic(max_size_px=1500), Mosaic(max_size_px=1500)
    ups_plain = [plain.add(f) for f in seq]
    ups = [stamped.add(f, stamp_s=100.0 + 0.5 * k) for k, f in enumerate(seq)]
    assert all(u.ok for u in ups) and all(u.ok for u in ups_plain)
    # the first pair has no motion to predict from; every later one is tracked
    assert [bool(u.registration.tracked) for u in ups[1:]] == [False] + [True] * 6
    assert not any(u.registration.tracked for u in ups_plain[1:])
    assert max(u.seam_residual_px for u in ups[1:]) <= 0.1
    a, b = plain.image().astype(float), stamped.image().astype(float)
    assert a.shape == b.shape
    assert np.mean(np.abs(a - b)) < 0.5  # the same placement to a fraction of a pixel


def test_a_stamp_gap_or_reversal_searches_in_full(frames):
    f0 = frames[0][:600, :800]
    f1 = frames[0][20:620, 10:810]
    m = Mosaic(max_size_px=1500)
    m.add(f0, stamp_s=10.0)
    m.add(f1, stamp_s=10.5)
    up = m.add(f0, stamp_s=9.0)  # back in time: no prediction, a full search
    assert up.ok and not up.registration.tracked
