"""Per-bin MAP solve of super-resolution when every frame's noise is white (eq. 9).

The transfer of a translated frame is separable in rows and columns, so the Gram
matrix of every LR frequency bin is built from small matrix products (or, with the
frames' shifts known, from outer products), and the factor^2 x factor^2 Hermitian
systems are solved by a Cholesky factorisation vectorised over bins, in single
precision.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np

from .dft import _as_c2
from .spectrum import rolloff_precision


def _solve_separable(
    spec: np.ndarray,
    ay: np.ndarray,
    ax: np.ndarray,
    fy: np.ndarray,
    fx: np.ndarray,
    c: float,
    alpha: float,
    reg: float,
    noise_power: float,
    block_bins: int = 1 << 16,
    shifts: np.ndarray | None = None,
    prior_gain: list | None = None,
    rolloff: float = 0.0,
) -> np.ndarray:
    """Solve eq. 9 per LR bin (normal equations) when every frame's noise is white.

    Parameters
    ----------
    spec : numpy.ndarray
        complex64 (N, hp, wc): the frames' half spectra.
    ay, ax : numpy.ndarray
        (N, p, hp) and (N, p, wc) row and column transfers of each frame
        (:func:`~subpix_ros.core.superres.model.frame_transfer_1d`).
    fy, fx : numpy.ndarray
        (p, hp) and (p, wc) signed HR frequencies of the aliases (cycles / HR px).
    c, alpha : float
        Prior ``P(f) = c |f|^-alpha`` (HR DFT units).
    reg, noise_power : float
        Prior strength multiplier; noise variance v of every bin (DFT units).
    block_bins : int, optional
        Bins per block of whole spectrum rows (cache-sized working arrays).
    shifts : numpy.ndarray, optional
        (N, 2) fractional shifts (LR px) that ``ay``/``ax`` were built with: the Gram
        entries are then outer products (:func:`_rank_one_gram_factors`).
    prior_gain : list, optional
        Per alias ``j = p m1 + m2`` a function ``g(r0, r1) -> (r1 - r0, wc)`` scaling the
        prior of those spectrum rows (``P -> g P``; default 1): how the motion blur enters
        (:func:`~subpix_ros.core.superres.fourier_map._solve_bins`).
    rolloff : float, optional
        ``k`` of the prior's Gaussian roll-off ``P(f) = c |f|^-alpha exp(-k |f|^2)``
        (:func:`~subpix_ros.core.superres.spectrum.rolloff_coefficient`; default 0: none).

    Returns
    -------
    numpy.ndarray
        complex64 (p, p, hp, wc): the alias components X of every bin.

    Notes
    -----
    Per LR bin (k = p^2 aliases m = (m1, m2)):
    ``(A^H A / v + reg diag(|f_m|^alpha / c)) X = A^H Y / v`` with
    ``a_nm = ay[n, m1] ax[n, m2]`` (alias (0, 0) at bin (0, 0), the DC, unregularised).
    Because ``a`` is separable, each Gram entry
    ``G[m, m'](ky, kx) = sum_n (conj(ay[n,m1]) ay[n,m1'])(ky) (conj(ax[n,m2]) ax[n,m2'])(kx)``
    is a (rows x N) @ (N x wc) matrix product: only the k (k+1) / 2 lower-triangle entries
    are formed, one complex ``cv2.gemm`` per row-factor pair. The right-hand side is
    ``sum_n conj(ay[n,m1]) (conj(ax[n,m2]) Y_n)``, a batched product per spectrum row.
    """
    n, p, hp = ay.shape
    wc = ax.shape[2]
    xs = np.empty((p, p, hp, wc), np.complex64)
    rows = max(1, min(hp, block_bins // max(wc, 1)))
    ay32 = ay.astype(np.complex64)
    ax32 = ax.astype(np.complex64)
    cay = np.conj(ay32) * np.float32(1.0 / noise_power)  # 1/v folded into the row factors
    cax = np.conj(ax32)
    col_fac = (
        _column_factors(cax, ax32)
        if shifts is None
        else _rank_one_gram_factors(ay, ax, fy, fx, np.asarray(shifts, np.float64), noise_power)
    )
    idx = [(m1, m2) for m1 in range(p) for m2 in range(p)]
    lam_cols = [(fy[m1].astype(np.float64) ** 2, fx[m2].astype(np.float64) ** 2) for m1, m2 in idx]
    for r0 in range(0, hp, rows):  # blocks of spectrum rows (cache), not pixels
        r1 = min(hp, r0 + rows)
        _solve_separable_block(
            spec[:, r0:r1],
            ay32[:, :, r0:r1],
            cay[:, :, r0:r1],
            cax,
            col_fac,
            lam_cols,
            r0,
            r1,
            alpha,
            np.float32(reg / c),
            xs[:, :, r0:r1],
            prior_gain,
            rolloff,
        )
    return xs


def _column_factors(cax: np.ndarray, ax32: np.ndarray) -> dict:
    """Return the column factors of the lower-triangle Gram entries, grouped by row pair.

    Entry ``i = (a1, a2) >= j = (b1, b2)``: ``conj(ax[:, a2]) ax[:, b2]``; per row pair
    ``(a1, b1)`` the list of column pairs and their factors side by side (N, len wc), as
    OpenCV's 2-channel matrix.
    """
    p = cax.shape[1]
    col_fac = {}
    for a1 in range(p):
        for b1 in range(a1 + 1):
            cols = [(a2, b2) for a2 in range(p) for b2 in range(p) if a1 * p + a2 >= b1 * p + b2]
            w = np.concatenate([cax[:, a2] * ax32[:, b2] for a2, b2 in cols], axis=1)
            col_fac[a1, b1] = (cols, _as_c2(w))
    return col_fac


@dataclass
class _RankOneGram:
    """Rank-one Gram entries of :func:`_solve_separable`.

    ``entries[i, j] = (gy, cls_y, gx, cls_x, T)``: ``G[i, j] = gy gx^T T[cls_y][:, cls_x]``.
    """

    entries: dict


def _alias_classes(f: np.ndarray, p: int, m: int, mp: int) -> tuple[np.ndarray, np.ndarray]:
    """Return the integer classes ``p (f[m] - f[mp])`` per bin: (distinct values, index per bin).

    ``f`` is a frequency table (``frame_transfer_1d``'s, a function of its length and p
    only): the classes are cached per table content and (p, m, mp), read-only.
    """
    f = np.ascontiguousarray(f, dtype=np.float64)
    return _alias_classes_cached(f.tobytes(), f.shape, p, m, mp)


@functools.lru_cache(maxsize=256)
def _alias_classes_cached(
    fb: bytes, shape: tuple, p: int, m: int, mp: int
) -> tuple[np.ndarray, np.ndarray]:
    """Compute :func:`_alias_classes` from the table's bytes (hashable, for the cache)."""
    f = np.frombuffer(fb, dtype=np.float64).reshape(shape)
    d = np.rint(p * (f[m] - f[mp])).astype(np.int64)
    vals, inv = np.unique(d, return_inverse=True)
    inv = inv.ravel()
    vals.flags.writeable = False
    inv.flags.writeable = False
    return vals, inv


def _rank_one_gram_factors(
    ay: np.ndarray,
    ax: np.ndarray,
    fy: np.ndarray,
    fx: np.ndarray,
    shifts: np.ndarray,
    noise_power: float,
) -> _RankOneGram:
    """Return the factors of the rank-one Gram entries (lower triangle), given the shifts.

    With ``a[n, m] = h[m] exp(-2 pi i f_m p s_n)`` the frame-dependent factor
    ``exp(2 pi i (f_m - f_m') p s_n)`` depends on the bin only through the integer class
    ``p (f_m - f_m')`` (one value per alias pair for even p, two for odd p), so
    ``G[m, m'](ky, kx) = gy(ky) gx(kx) T[cls_y(ky), cls_x(kx)]`` with the small table
    ``T[cy, cx] = sum_n exp(2 pi i (cy u_n + cx v_n)) / v``: an outer product instead of a
    rank-N matrix product (the same values to round-off).
    """
    p = ay.shape[1]
    u, v = shifts[:, 0], shifts[:, 1]
    # shift-free transfers h[m] = a[0, m] exp(+2 pi i f_m p s_0) (frame 0's phase removed)
    hy = ay[0] * np.exp(2j * np.pi * fy * p * u[0])
    hx = ax[0] * np.exp(2j * np.pi * fx * p * v[0])
    entries = {}
    for a1 in range(p):
        for a2 in range(p):
            for b1 in range(p):
                for b2 in range(p):
                    i, j = a1 * p + a2, b1 * p + b2
                    if i < j:
                        continue
                    vy, cy = _alias_classes(fy, p, a1, b1)
                    vx, cx = _alias_classes(fx, p, a2, b2)
                    table = (
                        np.exp(2j * np.pi * (vy[:, None, None] * u + vx[None, :, None] * v)).sum(
                            axis=2
                        )
                        / noise_power
                    )
                    entries[i, j] = (
                        (np.conj(hy[a1]) * hy[b1]).astype(np.complex64),
                        cy,
                        (np.conj(hx[a2]) * hx[b2]).astype(np.complex64),
                        cx,
                        table.astype(np.complex64),
                    )
    return _RankOneGram(entries)


def _solve_separable_block(
    spec: np.ndarray,
    ay32: np.ndarray,
    cay: np.ndarray,
    cax: np.ndarray,
    col_fac,
    lam_cols: list,
    r0: int,
    r1: int,
    alpha: float,
    lam_scale: np.float32,
    out: np.ndarray,
    prior_gain: list | None = None,
    rolloff: float = 0.0,
) -> None:
    """Solve spectrum rows ``r0 .. r1`` of :func:`_solve_separable`; write ``out`` (p, p, R, wc).

    ``spec``, ``ay32`` and ``cay`` are cut to the block; ``lam_scale = reg / c``;
    ``prior_gain`` and ``rolloff`` as in :func:`_solve_separable`.
    """
    n, p, nr = ay32.shape
    wc = cax.shape[2]
    gram = _block_gram(col_fac, cay, ay32, r0, r1, wc)
    # right-hand side b[m1, m2] = sum_n cay[n, m1] (cax[n, m2] Y_n)
    t = spec.transpose(1, 0, 2)[:, :, None, :] * cax[None, :, :, :]  # (R, n, p, wc)
    rhs = np.matmul(cay.transpose(2, 1, 0), t.reshape(nr, n, p * wc))  # (R, p, p wc)
    del t
    low, dinv = _cholesky_block(
        gram, lam_cols, r0, r1, alpha, lam_scale, p * p, prior_gain, rolloff
    )
    _substitute(rhs, low, dinv, out)


def _block_gram(col_fac, cay: np.ndarray, ay32: np.ndarray, r0: int, r1: int, wc: int) -> dict:
    """Return the lower-triangle Gram entries ``gram[i, j]`` (R, wc) of a block of rows."""
    p = ay32.shape[1]
    gram: dict[tuple[int, int], np.ndarray] = {}
    if isinstance(col_fac, _RankOneGram):  # rank-one entries: outer products
        for (i, j), (gy, cy, gx, cx, table) in col_fac.entries.items():
            gyb, cyb = gy[r0:r1], cy[r0:r1]
            if table.size == 1:
                gram[i, j] = np.multiply.outer(gyb * table[0, 0], gx)
            else:
                gram[i, j] = np.multiply.outer(gyb, gx) * table[cyb][:, cx]
        return gram
    for (a1, b1), (cols, w2) in col_fac.items():  # one product per row-factor pair
        u = (cay[:, a1] * ay32[:, b1]).T  # (R, n)
        prod = cv2.gemm(_as_c2(u), w2, 1.0, None, 0.0).view(np.complex64)[..., 0]
        for q, (a2, b2) in enumerate(cols):
            gram[a1 * p + a2, b1 * p + b2] = prod[:, q * wc : (q + 1) * wc]
    return gram


def _cholesky_block(
    gram: dict,
    lam_cols: list,
    r0: int,
    r1: int,
    alpha: float,
    lam_scale: np.float32,
    k: int,
    prior_gain: list | None = None,
    rolloff: float = 0.0,
) -> tuple[dict, list]:
    """Factor ``gram + diag(reg |f|^alpha e^(kr |f|^2) / (c g)) = L L^H`` per bin, over k x k.

    ``g`` is the prior gain of each alias (``prior_gain``, :func:`_solve_separable`; 1 if
    None), ``kr`` the roll-off (``rolloff``; the exponent capped,
    :func:`~subpix_ros.core.superres.spectrum.rolloff_precision`).

    Returns the strictly lower entries ``low[i, j]`` (in place on ``gram``) and the
    inverse diagonal ``dinv[j]`` (float32), each (R, wc).
    """
    nr, wc = gram[0, 0].shape
    tmp_r = np.empty((nr, wc), np.float32)
    tmp_c = np.empty((nr, wc), np.complex64)
    tmp_e = np.empty((nr, wc), np.float32) if rolloff > 0 else None
    low: dict[tuple[int, int], np.ndarray] = {}
    dinv: list[np.ndarray] = []
    for j in range(k):  # Cholesky over the k x k index, vectorised over bins
        fy2, fx2 = lam_cols[j]
        # prior precision reg / P(f) = reg |f|^alpha / c, |f|^alpha = (fy^2 + fx^2)^(alpha/2)
        np.add(fy2[r0:r1, None], fx2[None, :], out=tmp_r, casting="same_kind")
        d = cv2.pow(tmp_r, alpha / 2.0)
        d *= lam_scale
        if tmp_e is not None:  # the roll-off: precision times exp(k |f|^2)
            d *= rolloff_precision(tmp_r, np.float32(rolloff), out=tmp_e)
        if prior_gain is not None:
            d /= prior_gain[j](r0, r1)
        if j == 0 and r0 == 0:
            d[0, 0] = 0.0  # alias (0, 0) at bin (0, 0) is the HR DC term
        d += gram[j, j].real
        for q in range(j):
            lq = low[j, q]
            d -= lq.real**2
            d -= lq.imag**2
        np.maximum(d, np.float32(1e-30), out=d)
        np.sqrt(d, out=d)
        np.divide(np.float32(1.0), d, out=d)
        dinv.append(d)
        dc = d.astype(np.complex64)
        for i in range(j + 1, k):
            v = gram[i, j]  # a view into this block's own product: updated in place
            for q in range(j):
                np.multiply(low[i, q], np.conj(low[j, q]), out=tmp_c)
                v -= tmp_c
            v *= dc
            low[i, j] = v
    return low, dinv


def _substitute(rhs: np.ndarray, low: dict, dinv: list, out: np.ndarray) -> None:
    """Solve ``L L^H x = b`` per bin: forward, then back substitution into ``out``.

    ``rhs`` (R, p, p wc) is overwritten by the forward pass; ``out`` is (p, p, R, wc).
    """
    p = out.shape[0]
    k = p * p
    wc = out.shape[3]
    idx = [(m1, m2) for m1 in range(p) for m2 in range(p)]
    tmp_c = np.empty(out.shape[2:], np.complex64)
    z: list[np.ndarray] = []
    for i in range(k):  # forward substitution (in place on the right-hand side)
        m1, m2 = idx[i]
        v = rhs[:, m1, m2 * wc : (m2 + 1) * wc]
        for q in range(i):
            np.multiply(low[i, q], z[q], out=tmp_c)
            v -= tmp_c
        v *= dinv[i]
        z.append(v)
    for i in reversed(range(k)):  # back substitution with L^H, written into the result
        v = z[i]
        for q in range(i + 1, k):
            np.multiply(np.conj(low[q, i]), out[idx[q]], out=tmp_c)
            v -= tmp_c
        np.multiply(v, dinv[i], out=out[idx[i]])
