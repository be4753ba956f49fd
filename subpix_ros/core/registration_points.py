"""Tie points for co-registration: Harris corners, NCC matching, sub-pixel refinement.

METHODS.md C, stage 2 (tie points), vectorised over all points at once:

* Harris response (METHODS C, stage 2): 3x3 Gaussian, Sobel derivatives
  ``Vx, Vy``, an ``w x w`` Gaussian window (11x11 by default) over
  ``Vx^2, Vy^2, Vx Vy`` giving the structure tensor ``I``, and
  ``R = det(I) - k trace(I)^2`` with ``k = 0.04``; local maxima by
  non-maximum suppression and a grid quota so the points spread over the
  whole overlap instead of clustering in the most textured field.
* Matching by normalised cross-correlation (NCC) "around the coarse
  prediction": the moving frame is resampled onto the reference grid around
  each point through the current transform, so rotation, scale and
  perspective between the frames do not spoil the correlation; the integer
  NCC peak is refined by a parabola through its neighbours.
* Sub-pixel refinement: Gauss-Newton on the translation of each patch
  (``delta = (G^T G)^-1 G^T (T - S)``, the gradient model of METHODS A
  applied to one small window, with ``G`` the mean of the patch's and the
  template's gradients: efficient second-order minimisation, fewer
  iterations on noisy texture), with the moving patch resampled (bicubic,
  ``cv2.remap``, positions quantised to 1/32 px, an error random across
  points) at the updated position each iteration, each point until its step
  is below 0.01 px; this converges to the unbiased position, without the
  pixel-locking bias of a parabolic peak.

Coordinates are pixel coordinates ``(x, y) = (column, row)`` with pixel
centres at integers. Transforms are 3x3 homographies mapping MOVING (x, y)
to REFERENCE (x, y).
"""

from __future__ import annotations

import cv2
import numpy as np

#: Relative Harris floor (fraction of the strongest maximum in the overlap): the NIR lawn's maxima are
#: ~1e-5 of a roof corner's (R ~ contrast^4), and 1e-4 left the field pairs with 50-80 inliers.
REL_FLOOR = 1e-6

__all__ = [
    "harris_response",
    "harris_peaks",
    "select_spread",
    "harris_points",
    "apply_h",
    "sample_bicubic",
    "sample_linear_cv",
    "ncc_match",
    "refine_gauss_newton",
]


def harris_response(gray: np.ndarray, window: int = 11, k: float = 0.04) -> np.ndarray:
    """Harris corner response ``R = det(I) - k trace(I)^2`` (METHODS C, stage 2).

    ``I = G_w * [[Vx^2, Vx Vy], [Vx Vy, Vy^2]]`` where ``Vx, Vy`` are Sobel
    derivatives of the 3x3-Gaussian-smoothed image and ``G_w`` a
    ``window x window`` Gaussian. Input float32 HxW (any intensity scale),
    output float32 HxW in (intensity/px)^4.
    """
    g = cv2.GaussianBlur(gray, (3, 3), 0)
    vx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3)
    vy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3)
    ksz = (window, window)
    # Four frame-sized buffers reused in place (same values as the plain expression): every fresh
    # frame-sized temporary costs page faults, which dominated this function's time (3400 -> 30
    # faults and 3x faster at 900x675).
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
    """Local maxima of the Harris response over the whole frame: ``(xs, ys, R)`` (int, int, float32).

    Non-maximum suppression keeps pixels equal to the maximum of their
    ``(2 nms_radius + 1)^2`` neighbourhood with a positive response
    (METHODS C, stage 2). The result depends only on the frame, so a fixed
    reference frame computes it once (:func:`select_spread` then picks per
    overlap).
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
    """Harris maxima inside ``valid`` above the relative floor, with each one's strength rank in its grid cell."""
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
    """Grid-quota selection of Harris maxima inside ``valid``; returns (N, 2) float64 (x, y).

    Maxima weaker than ``REL_FLOOR`` (1e-6) of the strongest one inside
    ``valid`` are dropped (flat noise; the response scales as contrast^4).
    The bounding box of ``valid`` is cut into ``grid`` (rows, cols) cells and
    each cell keeps at most ``ceil(n_target / cells)`` of its strongest
    maxima, so no single textured field takes all the points. With
    ``n_more > 0`` also returns the next tier: the points a quota of
    ``ceil((n_target + n_more) / cells)`` adds (candidates for weak texture).
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
    """Harris maxima spread over ``valid`` by a grid quota; returns (N, 2) float64 (x, y).

    :func:`harris_peaks` (response, non-maximum suppression) followed by
    :func:`select_spread` (relative floor, grid quota over ``valid``'s
    bounding box).
    """
    return select_spread(harris_peaks(gray, window, nms_radius), valid, n_target, grid)


def apply_h(h: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Apply a 3x3 homography to (N, 2) points (x, y): ``p' = (H [x, y, 1]^T)`` dehomogenised."""
    p = np.asarray(pts, dtype=np.float64)
    x, y = p[:, 0], p[:, 1]
    w = h[2, 0] * x + h[2, 1] * y + h[2, 2]
    out = np.empty(p.shape, dtype=np.float64)
    out[:, 0] = (h[0, 0] * x + h[0, 1] * y + h[0, 2]) / w
    out[:, 1] = (h[1, 0] * x + h[1, 1] * y + h[1, 2]) / w
    return out


def _keys(t: np.ndarray) -> np.ndarray:
    """Keys cubic convolution kernel (a = -0.5) at distances ``t``."""
    t = np.abs(t)
    t2, t3 = t * t, t * t * t
    return np.where(
        t <= 1, 1.5 * t3 - 2.5 * t2 + 1, np.where(t < 2, -0.5 * t3 + 2.5 * t2 - 4 * t + 2, 0.0)
    )


def sample_bicubic(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Keys bicubic interpolation of ``img`` at float coordinates (x=col, y=row), float64.

    Exact positions (no fixed-point quantisation of the fraction, unlike
    ``cv2.remap``). Coordinates are clamped to the image (callers only sample
    inside it).
    """
    h, w = img.shape
    x = np.clip(x, 0, w - 1)
    y = np.clip(y, 0, h - 1)
    x0 = np.floor(x).astype(np.intp)
    y0 = np.floor(y).astype(np.intp)
    fx, fy = x - x0, y - y0
    out = np.zeros(x.shape, dtype=np.float64)
    wy = [_keys(fy - j) for j in (-1, 0, 1, 2)]
    wx = [_keys(fx - i) for i in (-1, 0, 1, 2)]
    for j in range(4):  # 16 taps, each vectorised over all samples
        yy = np.clip(y0 + j - 1, 0, h - 1)
        row = np.zeros(x.shape, dtype=np.float64)
        for i in range(4):
            xx = np.clip(x0 + i - 1, 0, w - 1)
            row += wx[i] * img[yy, xx]
        out += wy[j] * row
    return out


#: cv2.remap needs maps of fewer than SHRT_MAX (32767) rows and columns.
_REMAP_MAX = 32000


def _remap(img: np.ndarray, x: np.ndarray, y: np.ndarray, interp: int) -> np.ndarray:
    """``cv2.remap`` of ``img`` at float32 positions ``x, y`` of any shape (..., W); float32, same shape.

    Each output sample depends only on its own position, so the maps are laid
    out as rows of ``W`` samples, in blocks of fewer than ``SHRT_MAX`` rows
    (OpenCV's limit on a map's size).
    """
    shp = x.shape
    mx = x.reshape(-1, shp[-1])
    my = y.reshape(-1, shp[-1])
    if mx.dtype != np.float32:
        mx, my = mx.astype(np.float32), my.astype(np.float32)
    if len(mx) < _REMAP_MAX:
        out = cv2.remap(img, mx, my, interp, borderMode=cv2.BORDER_REPLICATE)
    else:
        out = np.vstack(
            [
                cv2.remap(
                    img,
                    mx[r0 : r0 + _REMAP_MAX],
                    my[r0 : r0 + _REMAP_MAX],
                    interp,
                    borderMode=cv2.BORDER_REPLICATE,
                )
                for r0 in range(0, len(mx), _REMAP_MAX)
            ]
        )
    return out.reshape(shp)


def sample_linear_cv(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear sampling with ``cv2.remap`` (fast; fraction quantised to 1/32 px). float32."""
    return _remap(img, x, y, cv2.INTER_LINEAR)


def sample_cubic_cv(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bicubic sampling with ``cv2.remap`` (fraction quantised to 1/32 px; the error is
    random across points and averages out in the model fit). float32."""
    return _remap(img, x, y, cv2.INTER_CUBIC)


def _patch_grid(half: int) -> tuple[np.ndarray, np.ndarray]:
    o = np.arange(-half, half + 1, dtype=np.float64)
    return np.meshgrid(o, o)  # (qx, qy), each (P, P)


def _ref_patches(ref: np.ndarray, pts: np.ndarray, half: int, dtype=np.float64) -> np.ndarray:
    """Integer-position patches (N, P, P) of ``ref`` centred at rounded ``pts`` (inside the frame)."""
    win = np.lib.stride_tricks.sliding_window_view(ref, (2 * half + 1, 2 * half + 1))
    x0 = np.rint(pts[:, 0]).astype(np.intp) - half
    y0 = np.rint(pts[:, 1]).astype(np.intp) - half
    return win[y0, x0].astype(dtype, copy=False)


def _local_affine(h: np.ndarray, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``h`` at ``pts`` and its 2x2 Jacobian there (analytic, eq. P): ``h(p + q) = c + J q + O(|h_20| q^2)``."""
    c = apply_h(h, pts)
    w = h[2, 0] * pts[:, 0] + h[2, 1] * pts[:, 1] + h[2, 2]
    j = np.empty((len(pts), 2, 2))
    j[:, 0, 0] = (h[0, 0] - c[:, 0] * h[2, 0]) / w
    j[:, 0, 1] = (h[0, 1] - c[:, 0] * h[2, 1]) / w
    j[:, 1, 0] = (h[1, 0] - c[:, 1] * h[2, 0]) / w
    j[:, 1, 1] = (h[1, 1] - c[:, 1] * h[2, 1]) / w
    return c, j


def _correlate_batch(win: np.ndarray, tpl: np.ndarray) -> np.ndarray:
    """Valid cross-correlation of each window with its own template, for all points at once.

    ``num[n, dy, dx] = sum_{i,j} tpl[n, i, j] win[n, dy + i, dx + j]`` for
    ``win`` (N, B, B) and ``tpl`` (N, P, P), offsets ``0 <= dy, dx < K = B - P + 1``;
    float32 (N, K, K). Computed row-wise: ``C[n, r, dx, i] = sum_j win[n, r, dx + j]
    tpl[n, i, j]`` is one batched matrix product over the windows unfolded along
    their rows only (``B K P`` values per point, not ``K^2 P^2``), then
    ``num[n, dy, dx] = sum_i C[n, dy + i, dx, i]`` (``P`` slice additions).
    """
    n, b, _ = win.shape
    pp = tpl.shape[1]
    k = b - pp + 1
    out = np.zeros((n, k, k), np.float32)
    step = max(
        1, int(5e5 // (b * k * pp))
    )  # chunks keep the unfolded copy ~2 MB (cache-sized: 2x faster than 16 MB)
    for c0 in range(0, n, step):  # usually one chunk
        w = win[c0 : c0 + step]
        m = len(w)
        unf = np.lib.stride_tricks.sliding_window_view(w, pp, axis=2).reshape(m, b * k, pp)
        c = np.matmul(unf, tpl[c0 : c0 + step].transpose(0, 2, 1)).reshape(m, b, k, pp)
        o = out[c0 : c0 + step]
        for i in range(pp):  # P additions, each over all points and offsets
            o += c[:, i : i + k, :, i]
    return out


def ncc_match(
    ref: np.ndarray,
    mov: np.ndarray,
    pts_ref: np.ndarray,
    h_mr: np.ndarray,
    half: int = 7,
    radius: int = 3,
    min_ncc: float = 0.5,
    pred_mov: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Match reference points in ``mov`` by NCC around the prediction of ``h_mr``.

    For each reference point ``p`` (integer position), the moving frame is
    resampled onto reference coordinates ``p + q`` (``W(q) = mov(H^-1 (p+q))``,
    bilinear) over a ``(2 half + 1 + 2 radius)^2`` window; the NCC of the
    reference template with every ``(2 radius + 1)^2`` offset ``d`` is
    ``sum(T0 W_d) / (|T0| |W_d - mean W_d|)``. The peak is refined by a
    parabola per axis. A match means ``ref(p) ~ mov(H^-1 (p + d))``.

    ``pred_mov`` (N, 2), optional: each point's own predicted moving position
    (e.g. its match one pyramid level up, scaled), which replaces the
    centre ``H^-1 p`` of its search window (``H`` still gives the window's
    rotation, scale and perspective): ``W(q) = mov(H^-1 (p+q) - H^-1 p + pred)``.
    Points whose prediction is not finite use ``H^-1 p``.

    Returns ``(pts_ref, pts_mov, score)`` for the accepted points: peak NCC
    ``>= min_ncc``, peak not on the border of the search window (the true
    match could lie outside), finite.
    """
    n = pts_ref.shape[0]
    if n == 0:
        z = np.zeros((0, 2))
        return z, z, np.zeros(0)
    p = np.rint(pts_ref)
    t = _ref_patches(ref, p, half, np.float32)
    t0 = t - t.mean(axis=(1, 2), keepdims=True)
    tn = np.sqrt(np.einsum("nij,nij->n", t0, t0).astype(np.float64))
    big = half + radius
    qx, qy = (q.astype(np.float32) for q in _patch_grid(big))
    hinv = np.linalg.inv(h_mr)
    # Window positions H^-1(p + q) by the local affine expansion about p (second-order term
    # ~1e-3 px over the window, below remap's 1/32 px position quantisation).
    c, jm = _local_affine(hinv, p)
    off = np.zeros((n, 2))
    if pred_mov is not None:
        off = np.asarray(pred_mov, dtype=np.float64) - c
        off[~np.isfinite(off).all(axis=1)] = 0.0
    cc = (c + off).astype(np.float32)
    jm = jm.astype(np.float32)
    mx = cc[:, 0, None, None] + jm[:, 0, 0, None, None] * qx + jm[:, 0, 1, None, None] * qy
    my = cc[:, 1, None, None] + jm[:, 1, 0, None, None] * qx + jm[:, 1, 1, None, None] * qy
    win32 = sample_linear_cv(mov, mx, my)
    pp = 2 * half + 1
    k = 2 * radius + 1
    b = pp + 2 * radius
    # Numerator sum(T0 W_d) for all (2r+1)^2 offsets d at once (:func:`_correlate_batch`).
    num = _correlate_batch(win32, t0).astype(np.float64)
    # Local sums of W and W^2 over each offset window: box filters over the windows stacked vertically
    # (anchor top-left, so a sum never crosses into the next window), on mean-removed float32 values.
    wc = (win32 - win32.mean(axis=(1, 2), keepdims=True)).reshape(n * b, b)
    box = dict(
        ddepth=cv2.CV_32F,
        ksize=(pp, pp),
        anchor=(0, 0),
        normalize=False,
        borderType=cv2.BORDER_CONSTANT,
    )
    s1 = cv2.boxFilter(wc, **box).reshape(n, b, b)[:, :k, :k].astype(np.float64)
    s2 = cv2.boxFilter(wc * wc, **box).reshape(n, b, b)[:, :k, :k].astype(np.float64)
    var = np.maximum(s2 - s1 * s1 / (pp * pp), 0.0)
    den = tn[:, None, None] * np.sqrt(var)
    ncc = np.where(den > 1e-9, num / np.maximum(den, 1e-12), -1.0)
    flat = ncc.reshape(n, -1)
    idx = flat.argmax(axis=1)
    iy, ix = np.divmod(idx, k)
    best = flat[np.arange(n), idx]
    inner = (iy > 0) & (iy < k - 1) & (ix > 0) & (ix < k - 1)
    iyc, ixc = np.clip(iy, 1, k - 2), np.clip(ix, 1, k - 2)
    ar = np.arange(n)
    c0 = ncc[ar, iyc, ixc]

    def _para(m, pl):
        d = m - 2 * c0 + pl
        return np.where(d < 0, 0.5 * (m - pl) / np.where(d < 0, d, -1.0), 0.0)

    sx = _para(ncc[ar, iyc, ixc - 1], ncc[ar, iyc, ixc + 1])
    sy = _para(ncc[ar, iyc - 1, ixc], ncc[ar, iyc + 1, ixc])
    dx = ixc - radius + np.clip(sx, -0.5, 0.5)
    dy = iyc - radius + np.clip(sy, -0.5, 0.5)
    ok = inner & (best >= min_ncc) & (tn > 1e-6)
    q = np.stack([p[:, 0] + dx, p[:, 1] + dy], axis=1)
    pm = apply_h(hinv, q) + off
    ok &= np.isfinite(pm).all(axis=1)
    return p[ok], pm[ok], best[ok]


def refine_gauss_newton(
    ref: np.ndarray,
    mov: np.ndarray,
    pts_ref: np.ndarray,
    pts_mov: np.ndarray,
    h_mr: np.ndarray,
    half: int = 7,
    iterations: int = 6,
    tol: float = 0.01,
) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel refinement of tie points by Gauss-Newton on patch translation.

    The moving frame warped to the reference grid, ``W(x) = mov(H^-1 x)``
    (bicubic, ``cv2.remap``; ``H^-1`` linearised about ``p``, ~6e-4 px over
    the patch), is sampled at ``p + d + q`` for the reference
    template grid ``q``; both patches are normalised to zero mean and unit
    norm (gain/offset invariance) and ``d`` is updated by
    ``delta = (G^T G)^-1 G^T (T - S_d)`` with ``G = (grad S_d + grad T) / 2``
    (central differences, px^-1; the efficient second-order minimisation of
    Benhimane and Malis, which needs fewer iterations than ``grad S_d`` alone
    on noisy weak texture, where the noise inflates ``G^T G`` and shortens
    the steps), each component clipped to 0.5 px. The local
    displacement ``d0`` from the current match seeds the iteration. A point
    stops iterating once its step is below ``tol`` px (the others go on, up
    to ``iterations``). Returns the refined moving points ``H^-1 (p + d)``
    and a bool mask of points that converged (finite, well-conditioned, last
    step below ``tol``, ``|d - d0|`` below 1 px).
    """
    n = pts_ref.shape[0]
    if n == 0:
        return pts_mov.copy(), np.zeros(0, bool)
    p = np.rint(pts_ref)
    tf = _ref_patches(ref, p, half + 1)  # template with a 1 px border for its gradient
    t = tf[:, 1:-1, 1:-1]
    t = t - t.mean(axis=(1, 2), keepdims=True)
    tnrm = np.maximum(np.sqrt((t * t).sum(axis=(1, 2), keepdims=True)), 1e-12)
    t = t / tnrm
    gt = np.stack([tf[:, 1:-1, 2:] - tf[:, 1:-1, :-2], tf[:, 2:, 1:-1] - tf[:, :-2, 1:-1]], axis=1)
    gt = (gt / (2 * tnrm[:, None])).astype(np.float32)  # template gradient (x, y), normalised
    d = apply_h(h_mr, pts_mov) - p  # current displacement in reference px
    d0 = d.copy()
    qx, qy = _patch_grid(half + 1)
    hinv = np.linalg.inv(h_mr)
    # Sampling positions H^-1(p + d + q) = c + J (q + d) + O(|c_h| |q + d|^2): the local affine expansion
    # of H^-1 about p (c = H^-1 p, J its Jacobian, c_h the perspective row of H^-1). The second-order
    # term is ~6e-4 px for |q| <= 8 px and |c_h| ~ 1e-5 px^-1, and even in q, so it does not move the
    # patch's centre; remap quantises positions to 1/32 px anyway.
    c, jac = _local_affine(hinv, p)  # jac (n, 2, 2): d(moving x, y) / d(d_x, d_y)
    c, jq = c.astype(np.float32), jac.astype(np.float32)
    qx, qy = qx.astype(np.float32), qy.astype(np.float32)
    bx = c[:, 0, None, None] + jq[:, 0, 0, None, None] * qx + jq[:, 0, 1, None, None] * qy
    by = c[:, 1, None, None] + jq[:, 1, 0, None, None] * qx + jq[:, 1, 1, None, None] * qy
    t = t.astype(np.float32)
    pp = (2 * half + 1) ** 2
    good = np.ones(n, bool)
    done = np.zeros(n, bool)
    for _ in range(iterations):
        act = np.nonzero(good & ~done)[0]  # points still iterating
        if act.size == 0:
            break
        m = act.size
        sh = np.einsum("nij,nj->ni", jac[act], d[act]).astype(np.float32)
        mx = bx[act]
        mx += sh[:, 0, None, None]
        my = by[act]
        my += sh[:, 1, None, None]
        s = sample_cubic_cv(mov, mx, my)
        inner = s[:, 1:-1, 1:-1]
        z = inner - inner.mean(axis=(1, 2), keepdims=True)
        nrm = np.sqrt(np.einsum("nij,nij->n", z, z))
        nrm = np.maximum(nrm, np.float32(1e-12))[:, None, None]
        # ESM Jacobian: the mean of the warped patch's and the template's normalised gradients.
        g = np.empty((m, 2, 2 * half + 1, 2 * half + 1), np.float32)
        np.subtract(s[:, 1:-1, 2:], s[:, 1:-1, :-2], out=g[:, 0])
        np.subtract(s[:, 2:, 1:-1], s[:, :-2, 1:-1], out=g[:, 1])
        g /= 4 * nrm[:, None]
        g += 0.5 * gt[act]
        g = g.reshape(m, 2, pp)
        e = (t[act] - z / nrm).reshape(m, pp, 1)
        am = g @ g.transpose(0, 2, 1)
        bv = (g @ e)[:, :, 0]
        a11, a12, a22 = (
            am[:, 0, 0].astype(np.float64),
            am[:, 0, 1].astype(np.float64),
            am[:, 1, 1].astype(np.float64),
        )
        b1, b2 = bv[:, 0].astype(np.float64), bv[:, 1].astype(np.float64)
        det = a11 * a22 - a12 * a12
        ok = det > 1e-12 * np.maximum(a11 + a22, 1e-30) ** 2
        dets = np.where(ok, det, 1.0)
        dx = np.clip(np.where(ok, (a22 * b1 - a12 * b2) / dets, 0.0), -0.5, 0.5)
        dy = np.clip(np.where(ok, (a11 * b2 - a12 * b1) / dets, 0.0), -0.5, 0.5)
        d[act] += np.stack([dx, dy], axis=1)
        good[act] &= ok & np.isfinite(d[act]).all(axis=1) & (np.hypot(*(d[act] - d0[act]).T) < 1.0)
        done[act] = np.hypot(dx, dy) < tol
    good &= done
    pm = apply_h(hinv, p + d)
    return pm, good
