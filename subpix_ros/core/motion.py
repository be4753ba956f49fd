"""Frame-to-frame motion model for video-rate registration (constant velocity).

Homographies follow :mod:`subpix_ros.core.registration`: ``H_k`` maps frame
``k``'s pixel coordinates ``(x, y, 1)`` (x = column, y = row) to the
reference frame's. The motion between consecutive frames is

    D_k = H_{k-1}^-1 H_k        (frame k pixels -> frame k-1 pixels),

and under constant velocity ``D_{k+1} ~ D_k``, so the prediction for the
next frame is

    H_{k+1} ~ H_k D_k    (scaled by the ratio of frame intervals when frames were dropped).

A new reference frame restarts the chain at ``H = I`` while ``D`` carries on
(the camera's motion does not change because the reference did). Used to
start :func:`~subpix_ros.core.registration.register` from a prior instead of
a coarse search; the registration checks the prediction and falls back to
the full search when it is wrong, so the model only has to be good to a few
pixels.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "MotionTracker",
    "displacement_through_homography",
    "frame_motion",
    "image_velocity",
    "predict_homography",
    "scale_motion",
]


def _normalised(h: np.ndarray) -> np.ndarray:
    h = np.asarray(h, dtype=np.float64).reshape(3, 3)
    if not np.isfinite(h).all() or abs(h[2, 2]) < 1e-12:
        raise ValueError("homography must be finite with a non-zero H[2, 2]")
    return h / h[2, 2]


def frame_motion(h_prev: np.ndarray | None, h: np.ndarray) -> np.ndarray:
    """Return ``D = H_prev^-1 H`` (frame k -> frame k-1 pixels), normalised to ``D[2, 2] = 1``.

    ``h_prev`` None means the previous frame is the reference itself
    (``H_prev = I``). Raises ``ValueError`` for a singular or non-finite input.
    """
    h = _normalised(h)
    if h_prev is None:
        return h
    hp = _normalised(h_prev)
    if abs(np.linalg.det(hp)) < 1e-12:
        raise ValueError("previous homography is singular")
    return _normalised(np.linalg.solve(hp, h))


def scale_motion(motion: np.ndarray, ratio: float) -> np.ndarray:
    """Scale a motion to ``ratio`` times the time it was measured over: ``D^ratio``.

    ``D^ratio ~ I + ratio (D - I)``.

    First order in ``D - I`` (exact for translations; consecutive frames
    differ by a small rotation/scale, so the neglected term is tiny next to
    the tracking search radius). Used when frames were dropped or skipped
    and the time between frames changed. ``ratio`` >= 0.
    """
    if not (np.isfinite(ratio) and ratio >= 0):
        raise ValueError(f"ratio must be finite and >= 0, got {ratio!r}")
    d = _normalised(motion)
    return _normalised(np.eye(3) + ratio * (d - np.eye(3)))


def predict_homography(
    h_last: np.ndarray | None, motion: np.ndarray, ratio: float = 1.0
) -> np.ndarray:
    """Predict at constant velocity: ``H_{k+1} = H_k D_k^ratio`` (next frame -> reference pixels).

    ``h_last`` None means the last frame was the reference (``H_k = I``);
    ``ratio`` = (time from frame k to k+1) / (time over which ``motion`` was
    measured), see :func:`scale_motion`.
    """
    d = _normalised(motion) if ratio == 1.0 else scale_motion(motion, ratio)
    return d if h_last is None else _normalised(_normalised(h_last) @ d)


class MotionTracker:
    """The state behind the prediction: the chain against the current reference and the last motion.

    ``restart(t)`` when frame ``t`` becomes the reference (the chain restarts
    at ``H = I``, the motion carries on); ``update(H, t)`` after frame ``t``
    was registered (``H``: frame -> reference); ``forget()`` when the motion is
    no longer known (a failed registration); ``predict(t)`` gives the
    homography expected for frame ``t`` or None (no basis: search fully).
    Times in seconds. A gap of more than ``max_ratio`` measured intervals
    predicts nothing.
    """

    def __init__(self, max_ratio: float = 20.0) -> None:
        self.max_ratio = float(max_ratio)
        self.h_last: np.ndarray | None = (
            None  # last frame -> reference (None: it was the reference)
        )
        self.motion: np.ndarray | None = None  # last frame-to-frame motion D
        self.motion_dt = 0.0  # the time D took, s
        self.last_t: float | None = None  # stamp of the last frame of the chain

    def restart(self, t: float) -> None:
        """Restart the chain at stamp ``t`` (a new reference: the identity); keep the motion."""
        self.h_last, self.last_t = None, t

    def forget(self) -> None:
        """Forget the motion (after a failed registration)."""
        self.motion = None

    def update(self, h: np.ndarray, t: float) -> None:
        """Record the homography ``h`` of the frame at stamp ``t`` and the motion since the last."""
        h = _normalised(h)
        self.motion = frame_motion(self.h_last, h)
        self.motion_dt = t - self.last_t if self.last_t is not None else 0.0
        self.h_last, self.last_t = h, t

    def predict(self, t: float) -> np.ndarray | None:
        """Predict the homography at stamp ``t``: ``H_k D^ratio``.

        ``ratio`` = (t - last stamp) / the motion's interval; the last homography (constant
        position) while no motion is known; None without a basis or beyond ``max_ratio``.
        """
        if self.motion is None or self.last_t is None or self.motion_dt <= 0:
            return self.h_last
        ratio = (t - self.last_t) / self.motion_dt
        if not 0 <= ratio <= self.max_ratio:
            return None
        return predict_homography(self.h_last, self.motion, ratio)


def image_velocity(stamps_s: np.ndarray, positions: np.ndarray) -> tuple[float, float] | None:
    """Fit the image velocity of a set: a least-squares line through positions against time.

    Parameters
    ----------
    stamps_s : numpy.ndarray
        (N,) frame stamps (s).
    positions : numpy.ndarray
        (N, 2) image displacement ``(u, v)`` of each frame against the reference (LR px,
        rows and cols; the reference's is (0, 0)).

    Returns
    -------
    (float, float) or None
        ``(vu, vv)`` px/s, the slopes ``sum (t - t_mean)(x - x_mean) / sum (t - t_mean)^2``;
        None with fewer than 2 distinct stamps or non-finite input.
    """
    t = np.asarray(stamps_s, dtype=np.float64)
    x = np.asarray(positions, dtype=np.float64).reshape(-1, 2)
    if t.size < 2 or t.size != x.shape[0] or not (np.isfinite(t).all() and np.isfinite(x).all()):
        return None
    tc = t - t.mean()
    den = float(tc @ tc)
    if den <= 0.0:
        return None
    vel = tc @ (x - x.mean(axis=0)) / den
    return (float(vel[0]), float(vel[1]))


def displacement_through_homography(
    homography: np.ndarray | None, shape: tuple[int, int], u: float, v: float
) -> tuple[float, float]:
    """Return how far the scene moved in an original frame against its reference (px).

    Parameters
    ----------
    homography : numpy.ndarray or None
        (3, 3) original frame pixel (x, y) -> reference pixel: the warp that aligned the frame
        onto the reference's grid (None: identity).
    shape : (int, int)
        ``(rows, cols)`` of the reference grid.
    u, v : float
        Sub-pixel shift left in the aligned frame (rows, cols; content at (r, c) of the
        reference is at (r + u, c + v) of the aligned frame).

    Returns
    -------
    (float, float)
        ``(u, v)``: content at the reference's centre ``c`` is at ``H^-1 (c + (v, u))`` in
        the original frame, minus ``c``; ``(u, v)`` itself when the homography is the identity.
    """
    if homography is None or np.allclose(homography, np.eye(3)):
        return (float(u), float(v))
    rows, cols = shape
    c = np.array([(cols - 1) / 2.0, (rows - 1) / 2.0])
    q = np.linalg.solve(np.asarray(homography, dtype=np.float64), np.r_[c + (v, u), 1.0])
    return (float(q[1] / q[2] - c[1]), float(q[0] / q[2] - c[0]))
