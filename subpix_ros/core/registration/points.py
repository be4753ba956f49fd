"""Tie-point matching for co-registration: NCC search, sub-pixel refinement.

METHODS.md C, stage 2 (tie points), vectorised over all points at once (the Harris points
come from :mod:`.harris`):

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

References
----------
.. [1] S. Benhimane and E. Malis, "Real-time image-based tracking of planes using efficient
   second-order minimization", Proc. IEEE/RSJ IROS, 943-948, 2004.
   https://doi.org/10.1109/IROS.2004.1389474
.. [2] J. P. Lewis, "Fast normalized cross-correlation", Vision Interface, 120-123, 1995.
"""

from __future__ import annotations

import cv2
import numpy as np

from .geometry import apply_h


def _keys(t: np.ndarray) -> np.ndarray:
    """Evaluate the Keys cubic convolution kernel (a = -0.5) at distances ``t``."""
    t = np.abs(t)
    t2, t3 = t * t, t * t * t
    return np.where(
        t <= 1, 1.5 * t3 - 2.5 * t2 + 1, np.where(t < 2, -0.5 * t3 + 2.5 * t2 - 4 * t + 2, 0.0)
    )


def sample_bicubic(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Interpolate ``img`` bicubically (Keys, a = -0.5) at float coordinates; float64.

    Parameters
    ----------
    img : ndarray, shape (H, W)
        The image.
    x, y : ndarray
        Columns and rows (clamped to the image; callers only sample inside it).

    Returns
    -------
    ndarray
        Samples, shape of ``x``. Exact positions (no fixed-point quantisation of the fraction,
        unlike ``cv2.remap``).
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
    """Sample ``img`` with ``cv2.remap`` at positions ``x, y`` of any shape (..., W); float32.

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
    """Sample bilinearly with ``cv2.remap`` (fraction quantised to 1/32 px); float32."""
    return _remap(img, x, y, cv2.INTER_LINEAR)


def sample_cubic_cv(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Sample bicubically with ``cv2.remap``; float32.

    The fraction is quantised to 1/32 px; the error is random across points and averages out
    in the model fit.
    """
    return _remap(img, x, y, cv2.INTER_CUBIC)


def _patch_grid(half: int) -> tuple[np.ndarray, np.ndarray]:
    o = np.arange(-half, half + 1, dtype=np.float64)
    return np.meshgrid(o, o)  # (qx, qy), each (P, P)


def _ref_patches(ref: np.ndarray, pts: np.ndarray, half: int, dtype=np.float64) -> np.ndarray:
    """Return the patches (N, P, P) of ``ref`` centred at the rounded ``pts`` (inside the frame)."""
    win = np.lib.stride_tricks.sliding_window_view(ref, (2 * half + 1, 2 * half + 1))
    x0 = np.rint(pts[:, 0]).astype(np.intp) - half
    y0 = np.rint(pts[:, 1]).astype(np.intp) - half
    return win[y0, x0].astype(dtype, copy=False)


def _local_affine(h: np.ndarray, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return ``h`` at ``pts`` and its 2x2 Jacobian there (analytic, eq. P).

    ``h(p + q) = c + J q + O(|h_20| q^2)``.
    """
    c = apply_h(h, pts)
    w = h[2, 0] * pts[:, 0] + h[2, 1] * pts[:, 1] + h[2, 2]
    j = np.empty((len(pts), 2, 2))
    j[:, 0, 0] = (h[0, 0] - c[:, 0] * h[2, 0]) / w
    j[:, 0, 1] = (h[0, 1] - c[:, 0] * h[2, 1]) / w
    j[:, 1, 0] = (h[1, 0] - c[:, 1] * h[2, 0]) / w
    j[:, 1, 1] = (h[1, 1] - c[:, 1] * h[2, 1]) / w
    return c, j


def _correlate_batch(win: np.ndarray, tpl: np.ndarray) -> np.ndarray:
    """Cross-correlate each window with its own template (valid part), all points at once.

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
    # chunks keep the unfolded copy ~2 MB (cache-sized)
    step = max(1, int(5e5 // (b * k * pp)))
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

    Parameters
    ----------
    ref, mov : ndarray
        Reference and moving frames (float32), one pyramid level.
    pts_ref : ndarray, shape (N, 2)
        Reference points (x, y), rounded to integers.
    h_mr : ndarray, shape (3, 3)
        Moving -> reference homography at this level.
    half : int
        Template half-size (px): templates are ``2 half + 1`` square.
    radius : int
        Search radius (px).
    min_ncc : float
        Least accepted peak NCC.
    pred_mov : ndarray, shape (N, 2), optional
        Each point's own predicted moving position (e.g. its match one pyramid level up,
        scaled), which replaces the centre ``H^-1 p`` of its search window (``H`` still gives
        the window's rotation, scale and perspective):
        ``W(q) = mov(H^-1 (p + q) - H^-1 p + pred)``. Points whose prediction is not finite
        use ``H^-1 p``.

    Returns
    -------
    pts_ref, pts_mov : ndarray, shape (M, 2)
        The accepted points and their matches: peak NCC ``>= min_ncc``, peak not on the border
        of the search window (the true match could lie outside), finite.
    score : ndarray, shape (M,)
        Peak NCC.

    Notes
    -----
    For each reference point ``p`` the moving frame is resampled onto reference coordinates
    ``p + q`` (``W(q) = mov(H^-1 (p + q))``, bilinear) over a ``(2 half + 1 + 2 radius)^2``
    window; the NCC of the zero-mean template ``T0`` with every ``(2 radius + 1)^2`` offset
    ``d`` is ``sum(T0 W_d) / (|T0| |W_d - mean W_d|)`` [2]_. The peak is refined by a parabola
    per axis. A match means ``ref(p) ~ mov(H^-1 (p + d))``.
    """
    n = pts_ref.shape[0]
    if n == 0:
        empty = np.zeros((0, 2))
        return empty, empty, np.zeros(0)
    p = np.rint(pts_ref)
    tpl = _ref_patches(ref, p, half, np.float32)
    tpl0 = tpl - tpl.mean(axis=(1, 2), keepdims=True)
    tpl_norm = np.sqrt(np.einsum("nij,nij->n", tpl0, tpl0).astype(np.float64))
    hinv = np.linalg.inv(h_mr)
    windows, off = _search_windows(mov, p, hinv, half + radius, pred_mov)
    ncc = _ncc_surface(windows, tpl0, tpl_norm, half, radius)
    dx, dy, best, inner = _ncc_peak(ncc, radius)
    ok = inner & (best >= min_ncc) & (tpl_norm > 1e-6)
    q = np.stack([p[:, 0] + dx, p[:, 1] + dy], axis=1)
    pm = apply_h(hinv, q) + off
    ok &= np.isfinite(pm).all(axis=1)
    return p[ok], pm[ok], best[ok]


def _search_windows(mov, p, hinv, big: int, pred_mov):
    """Resample ``mov`` on the ``(2 big + 1)^2`` reference grid about each point ``p``.

    Returns the windows (N, B, B) float32 and each point's offset from ``H^-1 p`` to its own
    prediction (zero without one).
    """
    n = len(p)
    qx, qy = (q.astype(np.float32) for q in _patch_grid(big))
    # Window positions H^-1(p + q) by the local affine expansion about p (second-order term
    # ~1e-3 px over the window, below remap's 1/32 px position quantisation).
    centre, jm = _local_affine(hinv, p)
    off = np.zeros((n, 2))
    if pred_mov is not None:
        off = np.asarray(pred_mov, dtype=np.float64) - centre
        off[~np.isfinite(off).all(axis=1)] = 0.0
    cc = (centre + off).astype(np.float32)
    jm = jm.astype(np.float32)
    mx = cc[:, 0, None, None] + jm[:, 0, 0, None, None] * qx + jm[:, 0, 1, None, None] * qy
    my = cc[:, 1, None, None] + jm[:, 1, 0, None, None] * qx + jm[:, 1, 1, None, None] * qy
    return sample_linear_cv(mov, mx, my), off


def _ncc_surface(windows, tpl0, tpl_norm, half: int, radius: int) -> np.ndarray:
    """Return the NCC (N, K, K) of each zero-mean template with every offset in its window."""
    n = len(windows)
    pp = 2 * half + 1
    k = 2 * radius + 1
    b = pp + 2 * radius
    # Numerator sum(T0 W_d) for all (2r+1)^2 offsets d at once (:func:`_correlate_batch`).
    num = _correlate_batch(windows, tpl0).astype(np.float64)
    # Local sums of W and W^2 over each offset window: box filters over the windows stacked
    # vertically (anchor top-left, so a sum never crosses into the next window), on
    # mean-removed float32 values.
    wc = (windows - windows.mean(axis=(1, 2), keepdims=True)).reshape(n * b, b)
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
    den = tpl_norm[:, None, None] * np.sqrt(var)
    return np.where(den > 1e-9, num / np.maximum(den, 1e-12), -1.0)


def _ncc_peak(ncc: np.ndarray, radius: int):
    """Locate each surface's peak, refined by a parabola per axis.

    Returns the offsets ``dx, dy`` (px), the peak values and whether the peak is inside the
    window (not on its border).
    """
    n = len(ncc)
    k = 2 * radius + 1
    flat = ncc.reshape(n, -1)
    idx = flat.argmax(axis=1)
    iy, ix = np.divmod(idx, k)
    best = flat[np.arange(n), idx]
    inner = (iy > 0) & (iy < k - 1) & (ix > 0) & (ix < k - 1)
    iyc, ixc = np.clip(iy, 1, k - 2), np.clip(ix, 1, k - 2)
    ar = np.arange(n)
    c0 = ncc[ar, iyc, ixc]

    def parabola(minus, plus):
        curv = minus - 2 * c0 + plus
        return np.where(curv < 0, 0.5 * (minus - plus) / np.where(curv < 0, curv, -1.0), 0.0)

    sx = parabola(ncc[ar, iyc, ixc - 1], ncc[ar, iyc, ixc + 1])
    sy = parabola(ncc[ar, iyc - 1, ixc], ncc[ar, iyc + 1, ixc])
    dx = ixc - radius + np.clip(sx, -0.5, 0.5)
    dy = iyc - radius + np.clip(sy, -0.5, 0.5)
    return dx, dy, best, inner


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
    """Refine tie points to sub-pixel by Gauss-Newton on patch translation.

    Parameters
    ----------
    ref, mov : ndarray
        Reference and moving frames (float32), one pyramid level.
    pts_ref : ndarray, shape (N, 2)
        Reference points (x, y), rounded to integers.
    pts_mov : ndarray, shape (N, 2)
        Their current matches in the moving frame (the seed ``d0``).
    h_mr : ndarray, shape (3, 3)
        Moving -> reference homography at this level.
    half : int
        Template half-size (px).
    iterations : int
        Most iterations.
    tol : float
        A point stops iterating once its step is below this (px).

    Returns
    -------
    pts_mov : ndarray, shape (N, 2)
        Refined moving points ``H^-1 (p + d)``.
    converged : ndarray of bool, shape (N,)
        Finite, well-conditioned, last step below ``tol``, ``|d - d0|`` below 1 px.

    Notes
    -----
    The moving frame warped to the reference grid, ``W(x) = mov(H^-1 x)`` (bicubic,
    ``cv2.remap``; ``H^-1`` linearised about ``p``, ~6e-4 px over the patch), is sampled at
    ``p + d + q`` for the template grid ``q``; both patches are normalised to zero mean and
    unit norm (gain/offset invariance) and ``d`` is updated by::

        delta = (G^T G)^-1 G^T (T - S_d),   G = (grad S_d + grad T) / 2

    (central differences, px^-1; the efficient second-order minimisation [1]_), each
    component clipped to 0.5 px.
    """
    n = pts_ref.shape[0]
    if n == 0:
        return pts_mov.copy(), np.zeros(0, bool)
    p = np.rint(pts_ref)
    tpl, tpl_grad = _normalised_template(ref, p, half)
    d = apply_h(h_mr, pts_mov) - p  # current displacement in reference px
    d0 = d.copy()
    hinv = np.linalg.inv(h_mr)
    bx, by, jac = _patch_positions(hinv, p, half + 1)
    good = np.ones(n, bool)
    done = np.zeros(n, bool)
    for _ in range(iterations):
        act = np.nonzero(good & ~done)[0]  # points still iterating
        if act.size == 0:
            break
        sh = np.einsum("nij,nj->ni", jac[act], d[act]).astype(np.float32)
        mx = bx[act]
        mx += sh[:, 0, None, None]
        my = by[act]
        my += sh[:, 1, None, None]
        dx, dy, ok = _esm_step(sample_cubic_cv(mov, mx, my), tpl[act], tpl_grad[act], half)
        d[act] += np.stack([dx, dy], axis=1)
        good[act] &= ok & np.isfinite(d[act]).all(axis=1) & (np.hypot(*(d[act] - d0[act]).T) < 1.0)
        done[act] = np.hypot(dx, dy) < tol
    good &= done
    pm = apply_h(hinv, p + d)
    return pm, good


def _patch_positions(hinv, p, big: int):
    """Return the moving-frame positions (x, y; float32) of the patch grid about each ``p``.

    Also the local Jacobian ``J`` (n, 2, 2) of ``H^-1`` at ``p``: d(moving x, y) / d(d_x, d_y).
    """
    qx, qy = _patch_grid(big)
    # Sampling positions H^-1(p + d + q) = c + J (q + d) + O(|c_h| |q + d|^2): the local affine
    # expansion of H^-1 about p (c = H^-1 p, J its Jacobian, c_h the perspective row of H^-1).
    # The second-order term is ~6e-4 px for |q| <= 8 px and |c_h| ~ 1e-5 px^-1, and even in q,
    # so it does not move the patch's centre; remap quantises positions to 1/32 px anyway.
    c, jac = _local_affine(hinv, p)
    c, jq = c.astype(np.float32), jac.astype(np.float32)
    qx, qy = qx.astype(np.float32), qy.astype(np.float32)
    bx = c[:, 0, None, None] + jq[:, 0, 0, None, None] * qx + jq[:, 0, 1, None, None] * qy
    by = c[:, 1, None, None] + jq[:, 1, 0, None, None] * qx + jq[:, 1, 1, None, None] * qy
    return bx, by, jac


def _normalised_template(ref, p, half: int):
    """Return the zero-mean unit-norm templates (float32) and their normalised gradients (x, y)."""
    tf = _ref_patches(ref, p, half + 1)  # template with a 1 px border for its gradient
    t = tf[:, 1:-1, 1:-1]
    t = t - t.mean(axis=(1, 2), keepdims=True)
    tnrm = np.maximum(np.sqrt((t * t).sum(axis=(1, 2), keepdims=True)), 1e-12)
    t = t / tnrm
    gt = np.stack([tf[:, 1:-1, 2:] - tf[:, 1:-1, :-2], tf[:, 2:, 1:-1] - tf[:, :-2, 1:-1]], axis=1)
    gt = (gt / (2 * tnrm[:, None])).astype(np.float32)  # template gradient (x, y), normalised
    return t.astype(np.float32), gt


def _esm_step(s, tpl, tpl_grad, half: int):
    """Return one ESM step ``(dx, dy)`` (clipped to 0.5 px) per patch and the solvable mask.

    ``s``: the sampled moving patches with a 1 px border (m, P + 2, P + 2).
    """
    m = len(s)
    pp = (2 * half + 1) ** 2
    inner = s[:, 1:-1, 1:-1]
    z = inner - inner.mean(axis=(1, 2), keepdims=True)
    nrm = np.sqrt(np.einsum("nij,nij->n", z, z))
    nrm = np.maximum(nrm, np.float32(1e-12))[:, None, None]
    # ESM Jacobian: the mean of the warped patch's and the template's normalised gradients.
    g = np.empty((m, 2, 2 * half + 1, 2 * half + 1), np.float32)
    np.subtract(s[:, 1:-1, 2:], s[:, 1:-1, :-2], out=g[:, 0])
    np.subtract(s[:, 2:, 1:-1], s[:, :-2, 1:-1], out=g[:, 1])
    g /= 4 * nrm[:, None]
    g += 0.5 * tpl_grad
    g = g.reshape(m, 2, pp)
    e = (tpl - z / nrm).reshape(m, pp, 1)
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
    return dx, dy, ok
