"""Harris tie points for co-registration (METHODS.md C, stage 2).

Harris response: 3x3 Gaussian, Sobel derivatives ``Vx, Vy``, a ``w x w`` Gaussian window
(11x11 by default) over ``Vx^2, Vy^2, Vx Vy`` giving the structure tensor ``I``, and
``R = det(I) - k trace(I)^2`` with ``k = 0.04`` [1]_; local maxima by non-maximum suppression
and a grid quota so the points spread over the whole overlap instead of clustering in the most
textured field.

References
----------
.. [1] C. Harris and M. Stephens, "A combined corner and edge detector", Proc. Alvey Vision
   Conference, 147-151, 1988. https://doi.org/10.5244/C.2.23
"""

from __future__ import annotations

import cv2
import numpy as np

#: Relative Harris floor (fraction of the strongest maximum in the overlap; design notes).
REL_FLOOR = 1e-6


def harris_response(gray: np.ndarray, window: int = 11, k: float = 0.04) -> np.ndarray:
    """Compute the Harris corner response ``R = det(I) - k trace(I)^2`` (METHODS C, stage 2).

    Parameters
    ----------
    gray : ndarray of float32, shape (H, W)
        The frame (any intensity scale).
    window : int
        Side of the Gaussian window ``G_w`` (px).
    k : float
        Harris constant.

    Returns
    -------
    ndarray of float32, shape (H, W)
        The response, in (intensity/px)^4.

    Notes
    -----
    ``I = G_w * [[Vx^2, Vx Vy], [Vx Vy, Vy^2]]`` where ``Vx, Vy`` are Sobel derivatives of the
    3x3-Gaussian-smoothed image (Harris and Stephens, 1988).
    """
    g = cv2.GaussianBlur(gray, (3, 3), 0)
    vx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3)
    vy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3)
    ksz = (window, window)
    # four frame-sized buffers reused in place (same values): fresh temporaries cost page faults
    np.multiply(vx, vy, out=g)  # g := Vx Vy
    np.multiply(vx, vx, out=vx)  # vx := Vx^2
    np.multiply(vy, vy, out=vy)  # vy := Vy^2
    a = cv2.GaussianBlur(vx, ksz, 0)
    b = cv2.GaussianBlur(g, ksz, 0, dst=vx)
    c = cv2.GaussianBlur(vy, ksz, 0, dst=g)
    tr = np.add(a, c, out=vy)  # trace
    np.multiply(b, b, out=b)
    np.multiply(a, c, out=a)
    a -= b  # det = a c - b^2
    np.multiply(tr, tr, out=tr)
    tr *= np.float32(k)
    a -= tr  # R = det - k trace^2
    return a


def harris_peaks(
    gray: np.ndarray, window: int = 11, nms_radius: int = 4
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Find the local maxima of the Harris response over the whole frame.

    Parameters
    ----------
    gray : ndarray of float32
        The frame.
    window : int
        Harris window (:func:`harris_response`).
    nms_radius : int
        Non-maximum suppression keeps pixels equal to the maximum of their
        ``(2 nms_radius + 1)^2`` neighbourhood with a positive response.

    Returns
    -------
    xs, ys : ndarray of int
        Positions, row by row.
    response : ndarray of float32
        The response there.

    Notes
    -----
    The result depends only on the frame, so a fixed reference frame computes it once
    (:func:`select_spread` then picks per overlap).
    """
    resp = harris_response(gray, window)
    k = 2 * nms_radius + 1
    dil = cv2.dilate(resp, np.ones((k, k), np.uint8))
    # Pixels equal to their neighbourhood maximum and positive, listed row by row (as np.nonzero).
    nz = cv2.findNonZero(
        cv2.bitwise_and(cv2.compare(resp, dil, cv2.CMP_GE), cv2.compare(resp, 0, cv2.CMP_GT))
    )
    if nz is None:
        z = np.zeros(0, np.intp)
        return z, z, np.zeros(0, np.float32)
    nz = nz.reshape(-1, 2).astype(np.intp)
    xs, ys = nz[:, 0], nz[:, 1]
    return xs, ys, resp[ys, xs]


def _quota_rank(peaks, valid: np.ndarray, grid: tuple[int, int]):
    """Return the maxima inside ``valid`` above the floor and their strength rank in their cell."""
    xs, ys, r = peaks
    inv = valid[ys, xs]
    xs, ys, r = xs[inv], ys[inv], r[inv]
    if xs.size == 0:
        return xs, ys, np.zeros(0, np.intp)
    keep = r > REL_FLOOR * float(r.max())
    ys, xs, r = ys[keep], xs[keep], r[keep]
    rows, cols = np.flatnonzero(valid.any(axis=1)), np.flatnonzero(valid.any(axis=0))
    y0, y1, x0, x1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
    gr, gc = grid
    cell = np.minimum((ys - y0) * gr // max(y1 - y0, 1), gr - 1) * gc + np.minimum(
        (xs - x0) * gc // max(x1 - x0, 1), gc - 1
    )
    order = np.lexsort((-r, cell))  # by cell, strongest first
    cs = cell[order]
    rank = np.arange(cs.size) - np.searchsorted(cs, cs, side="left")  # 0 = strongest of its cell
    return xs[order], ys[order], rank


def select_spread(
    peaks: tuple[np.ndarray, np.ndarray, np.ndarray],
    valid: np.ndarray,
    n_target: int = 600,
    grid: tuple[int, int] = (12, 16),
    n_more: int = 0,
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Select Harris maxima inside ``valid`` by a grid quota.

    Parameters
    ----------
    peaks : tuple of ndarray
        ``(xs, ys, response)`` from :func:`harris_peaks`.
    valid : ndarray of bool
        Where points may lie.
    n_target : int
        Points wanted: each cell keeps at most ``ceil(n_target / cells)`` of its strongest
        maxima, so no single textured field takes all the points.
    grid : tuple of int
        (rows, cols) cells over the bounding box of ``valid``.
    n_more : int
        With ``n_more > 0`` also return the next tier: the points a quota of
        ``ceil((n_target + n_more) / cells)`` adds (candidates for weak texture).

    Returns
    -------
    ndarray, shape (N, 2), or tuple of two
        Points (x, y), float64; with ``n_more > 0`` the pair (points, next tier).

    Notes
    -----
    Maxima weaker than ``REL_FLOOR`` (1e-6) of the strongest one inside ``valid`` are dropped
    (flat noise; the response scales as contrast^4).
    """
    xs, ys, rank = _quota_rank(peaks, valid, grid)
    cells = grid[0] * grid[1]
    q1 = int(np.ceil(n_target / cells))
    pts = np.stack([xs, ys], axis=1).astype(np.float64)
    if n_more <= 0:
        return pts[rank < q1]
    q2 = int(np.ceil((n_target + n_more) / cells))
    return pts[rank < q1], pts[(rank >= q1) & (rank < q2)]


def harris_points(
    gray: np.ndarray,
    valid: np.ndarray,
    n_target: int = 600,
    grid: tuple[int, int] = (12, 16),
    window: int = 11,
    nms_radius: int = 4,
) -> np.ndarray:
    """Detect Harris maxima spread over ``valid`` by a grid quota.

    :func:`harris_peaks` (response, non-maximum suppression) followed by :func:`select_spread`
    (relative floor, grid quota over ``valid``'s bounding box); parameters as there.

    Returns
    -------
    ndarray, shape (N, 2)
        Points (x, y), float64.
    """
    return select_spread(harris_peaks(gray, window, nms_radius), valid, n_target, grid)
