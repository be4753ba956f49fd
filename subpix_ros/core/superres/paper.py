"""The paper's own reconstructions (METHODS.md B, eqs. 4, 6, 7), kept as references.

All three work on the *interleaved* observation of eq. 3: frames shifted by
whole sub-pixels (k/p, l/q of an LR pixel) fill one array ``y`` on the HR
grid, ``y[k, l] = sum_{a<p, b<q} x[k+a, l+b]`` (sums, as in the paper; see
:func:`interleave` to build it from frames, which carry means).

Why the MAP estimate is the default instead (docs/design-notes.md, "Super-resolution"):

* eq. 4 (recursion) is exact on noise-free data but accumulates every error
  along each stride-p chain;
* eq. 6 (pseudo-inverse) is the least-norm exact solution; it amplifies noise
  and costs O(n^3) in the side length;
* eq. 7 (windowed) is one fixed separable filter per HR pixel; as written it
  has a DC (brightness) gain error for even factors; :func:`windowed_filter`
  normalises it to unit DC gain by default.

References
----------
.. [1] S. A. Stankevich, S. V. Shklyar, N. S. Lubskyi, "Increasing the spatial
   resolution of aerial imaging by sub-pixel image registration", 2013
   (docs/METHODS.md, B: eqs. 3-7).
"""

from __future__ import annotations

import functools

import cv2
import numpy as np

from .model import box_sum

__all__ = [
    "band_matrix",
    "recursive_solution",
    "pinv_solution",
    "windowed_filter",
    "windowed_solution",
    "grid_offsets",
    "interleave",
]


def band_matrix(n: int, p: int) -> np.ndarray:
    """Return ``T1`` of eq. 5: n x (n+p-1), ones on p diagonals (``T[i, i..i+p-1] = 1``)."""
    t = np.zeros((n, n + p - 1))
    idx = np.arange(n)
    for a in range(p):  # p diagonals, not a loop over pixels
        t[idx, idx + a] = 1.0
    return t


def _unbox_1d(y: np.ndarray, p: int, head: np.ndarray) -> np.ndarray:
    """Invert a 1-D valid box sum along axis 0 given the first p-1 unknowns.

    From eq. 4 in 1-D: ``x[i+p-1] = y[i] - sum_{k=i}^{i+p-2} x[k]``, i.e.
    ``x[i+p-1] = x[i-1] + y[i] - y[i-1]``: a recursion of stride p, evaluated for all chains
    at once with a cumulative sum along each residue class.
    """
    n = y.shape[0]
    m = n + p - 1
    x = np.zeros((m,) + y.shape[1:])
    x[: p - 1] = head
    x[p - 1] = y[0] - head.sum(axis=0)
    if n > 1:
        d = np.diff(y, axis=0)  # d[i-1] = y[i] - y[i-1], sets x[i+p-1] - x[i-1]
        for r in range(p):  # residue chains of x indices r, r+p, ...
            start = r if r < p - 1 else p - 1
            # x indices in this chain beyond the seed: start + p, start + 2p, ...
            idx = np.arange(start + p, m, p)
            if idx.size:
                x[idx] = x[start] + np.cumsum(d[idx - p], axis=0)
    return x


def recursive_solution(y: np.ndarray, p: int, q: int, boundary: np.ndarray) -> np.ndarray:
    """Solve eq. 3 exactly by the recursion of eq. 4, given its boundary.

    Parameters
    ----------
    y : numpy.ndarray
        (n_x, n_y) interleaved box-sum observation (sums).
    p, q : int
        Factors along rows and columns.
    boundary : numpy.ndarray
        (n_x + p - 1, n_y + q - 1); its first p-1 rows and q-1 columns are the recursion's
        starting values (the other entries are ignored).

    Returns
    -------
    numpy.ndarray
        (n_x + p - 1, n_y + q - 1) sub-pixels.

    Notes
    -----
    Eq. 4 is separable (``Y = T1 (X T2)``), so it runs as a stride-p recursion along rows
    then a stride-q recursion along columns, each a cumulative sum. Exact on noise-free
    data; noise accumulates along every chain.
    """
    y = np.asarray(y, dtype=np.float64)
    b = np.asarray(boundary, dtype=np.float64)
    nx, ny = y.shape
    if b.shape != (nx + p - 1, ny + q - 1):
        raise ValueError(f"boundary must be {(nx + p - 1, ny + q - 1)}, got {b.shape}")
    # Z = X T2 (column-direction box sums); its first p-1 rows come from the boundary rows.
    z_head = box_sum(b[: p - 1], 1, q) if p > 1 else np.zeros((0, ny))
    z = _unbox_1d(y, p, z_head) if p > 1 else y.copy()
    x_head = b[:, : q - 1].T if q > 1 else np.zeros((0, nx + p - 1))
    return (_unbox_1d(z.T, q, x_head) if q > 1 else z.T.copy()).T


def pinv_solution(y: np.ndarray, p: int, q: int) -> np.ndarray:
    """Solve eq. 5 by eq. 6: ``X = pinv(T1) Y pinv(T2)``, the least-norm solution.

    Requires the paper's divisibility condition: ``n_x + p - 1`` a multiple of p and
    ``n_y + q - 1`` a multiple of q (ValueError otherwise). Dense pseudo-inverses: O(n^3) in
    the side length; unstable under noise.
    """
    y = np.asarray(y, dtype=np.float64)
    nx, ny = y.shape
    if (nx + p - 1) % p or (ny + q - 1) % q:
        raise ValueError(
            "eq. 6 needs n_x+p-1 divisible by p and n_y+q-1 by q "
            f"(got n_x={nx}, p={p}, n_y={ny}, q={q})"
        )
    t1 = band_matrix(nx, p)
    t2 = band_matrix(ny, q).T
    return np.linalg.pinv(t1) @ y @ np.linalg.pinv(t2)


@functools.lru_cache(maxsize=64)
def windowed_filter(p: int, w: int, normalise: bool = True) -> tuple[np.ndarray, int]:
    """Return the 1-D filter of eq. 7, the sliding-window pseudo-inverse, and its centre.

    Parameters
    ----------
    p : int
        Factor.
    w : int
        Window of observations (``w + p - 1`` odd, ``w >= p``).
    normalise : bool, optional
        Scale the taps to unit DC gain (``p sum(g) = 1``); eq. 7 as written has
        ``p sum(g) != 1`` for even p.

    Returns
    -------
    g : numpy.ndarray
        Taps (read-only, cached).
    c : int
        Centre index ``(w + p - 2) / 2``.

    Notes
    -----
    In a window of ``w`` observations and ``w + p - 1`` unknowns, the least-norm solution for
    the central unknown is row c of ``pinv(T1)``: ``x[k] = sum_j g[j] y[k - c + j]``.
    """
    if (w + p - 1) % 2 == 0:
        raise ValueError(f"eq. 7 needs w+p-1 odd (w={w}, p={p})")
    if w < p:
        raise ValueError(f"window w={w} must be >= p={p}")
    c = (w + p - 2) // 2
    g = np.linalg.pinv(band_matrix(w, p))[c].copy()
    if normalise:
        g = g / (p * g.sum())
    g.setflags(write=False)
    return g, c


def windowed_solution(
    y: np.ndarray, p: int, q: int, w: int = 6, u: int | None = None, normalise: bool = True
) -> np.ndarray:
    """Apply eq. 7 as one fixed separable filter on the interleaved ``y``.

    Parameters
    ----------
    y : numpy.ndarray
        Interleaved observation (sums), on the HR grid.
    p, q : int
        Factors along rows and columns.
    w, u : int, optional
        Windows along rows and columns (``u`` defaults to ``w``).
    normalise : bool, optional
        Unit DC gain (:func:`windowed_filter`).

    Returns
    -------
    numpy.ndarray
        float64, y's shape: the windowed least-norm estimate of the sub-pixels ``x[k, l]``
        (``x[k]`` is the first sub-pixel of box ``y[k]``), by ``cv2.sepFilter2D`` (reflected
        border; a float32 ``y`` is read as is).
    """
    u = w if u is None else u
    gr, cr = windowed_filter(p, w, normalise)
    gc, cc = windowed_filter(q, u, normalise)
    src = np.asarray(y)
    if src.dtype not in (np.float32, np.float64):
        src = src.astype(np.float64)
    return cv2.sepFilter2D(
        src, cv2.CV_64F, gc, gr, anchor=(cc, cr), borderType=cv2.BORDER_REFLECT_101
    )


def grid_offsets(shifts: np.ndarray, p: int, q: int, tol: float = 0.1) -> np.ndarray | None:
    """Return the sub-pixel grid offsets of the shifts, or None if they are off the grid.

    ``(t_r, t_c) = round(p u, q v)`` (int64, (N, 2)) when every shift lies on the k/p, l/q
    grid within ``tol`` sub-pixels.
    """
    s = np.asarray(shifts, dtype=np.float64) * np.array([p, q])
    t = np.rint(s)
    if np.max(np.abs(s - t)) > tol:
        return None
    return t.astype(np.int64)


def interleave(
    frames: list[np.ndarray], offsets: np.ndarray, p: int, q: int, dtype: type = np.float64
) -> tuple[np.ndarray, np.ndarray]:
    """Build the interleaved eq. 3 observation (sums) from grid-shifted frames.

    Parameters
    ----------
    frames : list of numpy.ndarray
        N 2-D frames of one shape (means over their pixels).
    offsets : numpy.ndarray
        (N, 2) integer sub-pixel offsets ``(t_r, t_c)`` (:func:`grid_offsets`).
    p, q : int
        Factors along rows and columns.
    dtype : type, optional
        dtype of the result.

    Returns
    -------
    y : numpy.ndarray
        ``(p H, q W)`` interleaved box sums.
    filled : numpy.ndarray
        bool, the entries some frame observed.

    Notes
    -----
    Frame n's pixel (i, j) is the mean over the HR box starting at
    ``(p i - t_r, q j - t_c)``, so it fills ``y[p i - t_r, q j - t_c] = p q frame[i, j]``.
    Frames sharing a phase are averaged. Unfilled entries (missing phases, or the border
    strip a shifted frame does not reach) are copied from the nearest filled entry along
    rows, then columns (:func:`_fill_holes`); 0 if none is within reach.
    """
    h, w = frames[0].shape
    hh, ww = h * p, w * q
    y = np.empty((hh, ww), dtype=dtype)  # every entry is written: by a frame, a hole fill, or 0
    filled = np.zeros((hh, ww), dtype=bool)
    offsets = np.asarray(offsets, dtype=np.int64)
    phases: dict[tuple[int, int], list[int]] = {(a, b): [] for a in range(p) for b in range(q)}
    for n_, (tr, tc) in enumerate(offsets):  # group frames by sub-pixel phase (first HR row/col)
        phases[(-int(tr)) % p, (-int(tc)) % q].append(n_)
    holes_r, holes_c = [], []
    for (first_r, first_c), members in phases.items():  # loop over phases / frames, not pixels
        if len(members) == 1:
            one = members[0]
            holes = _write_single(y, filled, frames[one], offsets[one], (p, q), (first_r, first_c))
            if holes is None:
                continue  # the frame covers its whole phase plane: no holes
        else:
            holes = _write_mean(y, filled, frames, offsets, members, (p, q), (first_r, first_c))
        holes_r.append(first_r + p * holes[0])
        holes_c.append(first_c + q * holes[1])
    if not holes_r:  # every phase plane covered by its frame (e.g. all shifts <= 0)
        return y, filled
    hr, hc = np.concatenate(holes_r).astype(np.intp), np.concatenate(holes_c).astype(np.intp)
    if hr.size:
        _fill_holes(y, filled, hr, hc, p, q)
    return y, filled


def _span(t: int, n: int, f: int) -> tuple[slice, slice]:
    """Return the LR indices i with ``0 <= f i - t < n f`` and the matching strided HR slice."""
    i0 = max(0, -(-t // f))
    i1 = min(n, (n * f - 1 + t) // f + 1)
    k0 = f * i0 - t
    return slice(i0, max(i0, i1)), slice(k0, k0 + f * max(0, i1 - i0), f)


def _write_single(
    y: np.ndarray,
    filled: np.ndarray,
    frame: np.ndarray,
    offset: np.ndarray,
    factors: tuple[int, int],
    first: tuple[int, int],
) -> tuple[np.ndarray, np.ndarray] | None:
    """Write a phase observed by one frame straight into ``y``; return its holes or None.

    Holes are (row, column) indices on the phase plane outside the frame's rectangle:
    whole rows outside it, then the columns outside it of the rows inside.
    """
    p, q = factors
    first_r, first_c = first
    h, w = frame.shape
    hh, ww = y.shape
    hp_, wp_ = len(range(first_r, hh, p)), len(range(first_c, ww, q))
    (ri, rk), (ci, ck) = _span(int(offset[0]), h, p), _span(int(offset[1]), w, q)
    # the factor in y's own precision (exact: small integer): the product runs in that precision
    np.multiply(np.asarray(frame)[ri, ci], y.dtype.type(p * q), out=y[rk, ck], casting="unsafe")
    filled[rk, ck] = True
    a0, a1 = (rk.start - first_r) // p, (rk.start - first_r) // p + (ri.stop - ri.start)
    b0, b1 = (ck.start - first_c) // q, (ck.start - first_c) // q + (ci.stop - ci.start)
    if a1 <= a0 or b1 <= b0:
        a0 = a1 = b0 = b1 = 0
    if a0 == 0 and a1 == hp_ and b0 == 0 and b1 == wp_:
        return None
    out_rows = np.concatenate((np.arange(a0), np.arange(a1, hp_)))
    out_cols = np.concatenate((np.arange(b0), np.arange(b1, wp_)))
    rr = np.concatenate((np.repeat(out_rows, wp_), np.tile(np.arange(a0, a1), out_cols.size)))
    cc = np.concatenate((np.tile(np.arange(wp_), out_rows.size), np.repeat(out_cols, a1 - a0)))
    return rr, cc


def _write_mean(
    y: np.ndarray,
    filled: np.ndarray,
    frames: list[np.ndarray],
    offsets: np.ndarray,
    members: list[int],
    factors: tuple[int, int],
    first: tuple[int, int],
) -> tuple[np.ndarray, np.ndarray]:
    """Write the mean of the frames ``members`` (none or several) on one phase; return its holes."""
    p, q = factors
    first_r, first_c = first
    h, w = frames[0].shape
    hh, ww = y.shape
    hp_, wp_ = len(range(first_r, hh, p)), len(range(first_c, ww, q))
    plane = (slice(first_r, None, p), slice(first_c, None, q))
    acc = np.zeros((hp_, wp_))
    cnt = np.zeros((hp_, wp_))
    for n_ in members:
        (ri, rk), (ci, ck) = _span(int(offsets[n_, 0]), h, p), _span(int(offsets[n_, 1]), w, q)
        rs = slice((rk.start - first_r) // p, (rk.start - first_r) // p + (ri.stop - ri.start))
        cs = slice((ck.start - first_c) // q, (ck.start - first_c) // q + (ci.stop - ci.start))
        acc[rs, cs] += p * q * np.asarray(frames[n_], dtype=np.float64)[ri, ci]
        cnt[rs, cs] += 1
    y[plane] = np.where(cnt > 0, acc / np.maximum(cnt, 1), 0.0)
    filled[plane] = cnt > 0
    return np.nonzero(cnt == 0)


def _fill_holes(
    y: np.ndarray, filled: np.ndarray, hr: np.ndarray, hc: np.ndarray, p: int, q: int
) -> None:
    """Fill the holes ``(hr, hc)`` of ``y`` from the nearest filled entry (in place).

    Passes over offsets d = 1..p along rows, then 1..q along columns, each taking from d
    entries before, then after (cyclically), twice over; each step reads the values as they
    were before it (as a cyclic roll of the array would); 0 if none is within reach.
    """
    hh, ww = y.shape
    have = filled.copy()
    for axis, f in ((0, p), (1, q), (0, p), (1, q)):  # a few passes over offsets, not pixels
        for d in range(1, f + 1):
            for sgn in (1, -1):
                if axis == 0:
                    sr, sc = (hr - sgn * d) % hh, hc
                else:
                    sr, sc = hr, (hc - sgn * d) % ww
                take = have[sr, sc]
                if take.any():
                    y[hr[take], hc[take]] = y[sr[take], sc[take]]
                    have[hr[take], hc[take]] = True
                    hr, hc = hr[~take], hc[~take]
            if hr.size == 0:
                break
        if hr.size == 0:
            break
    y[hr, hc] = 0.0  # no filled sample within reach
