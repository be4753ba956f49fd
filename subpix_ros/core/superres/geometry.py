"""Registration inside super-resolution: shift refinement and the check for non-translations.

:func:`_refine_shifts` refines every frame's sub-pixel shift against the reference by
Lucas-Kanade on low-passed frames and gives a multi-frame noise estimate;
:func:`detect_geometry` registers tiles to tell whether the frames are related by more
than a translation and fits an affine per frame if so.

References
----------
.. [1] B. D. Lucas and T. Kanade, "An iterative image registration technique with an
   application to stereo vision", Proc. IJCAI 1981, pp. 674-679.
"""

from __future__ import annotations

import numpy as np

from ..shift.batch import lk_inner_region, lk_window_context, lucas_kanade_batch
from .lowpass import _lowpass_window, _WholeLowpass
from .model import gaussian_kernel, translation_homography
from .validation import stored

__all__ = ["detect_geometry"]


def _refine_shifts(
    frames: np.ndarray,
    ishift: np.ndarray,
    resid: np.ndarray,
    lp_sigma: float = 1.0,
    border: int = 8,
    iters: int = 3,
    max_region: int = 256,
    lowpassed: _WholeLowpass | None = None,
) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
    """Refine each frame's sub-pixel shift against frame 0 by Lucas-Kanade on low-passed frames.

    Parameters
    ----------
    frames : numpy.ndarray
        (N, H, W) frames, frame 0 the reference.
    ishift, resid : numpy.ndarray
        (N, 2) integer and sub-pixel parts of the starting shifts (LR px).
    lp_sigma : float, optional
        Gaussian low-pass std (LR px): the fit uses the band where aliasing is weak.
    border : int, optional
        Px kept from the frame edges.
    iters : int, optional
        Most Gauss-Newton steps.
    max_region : int, optional
        Side of the central region fitted (px): the cost is bounded.
    lowpassed : _WholeLowpass or None, optional
        Shared whole-frame low-passes.

    Returns
    -------
    resid : numpy.ndarray
        (N, 2) refined sub-pixel shifts.
    sigma : numpy.ndarray
        (N,) std of each (LR px; 0 for frame 0, inf where the fit diverged: > 0.5 px).
    noise : float
        Per-pixel noise std (DN): the median over frames of the residual's noise.
    noise_var : numpy.ndarray
        (N,) per-frame noise variances (NaN for frame 0 and failed frames).

    Notes
    -----
    With R the low-passed reference moved by the current shift s (content moves by +s),
    the model ``F ~ R - d . grad R`` gives the step ``d = -(G^T G)^-1 G^T (F - R)``
    (:func:`~subpix_ros.core.shift.lucas_kanade_batch`). For white noise through
    the separable low-pass g, ``var(F - R) = 2 sigma^2 (sum g^2)^2``: a multi-frame noise
    estimate that texture does not bias, unlike single-frame ones.
    """
    n, h, w = frames.shape
    g = gaussian_kernel(lp_sigma)
    out = resid.copy()
    sig = np.zeros(n)
    resvar = np.full(n, np.nan)
    rh, rw = min(h - 2 * border, max_region), min(w - 2 * border, max_region)
    region = (slice((h - rh) // 2, (h - rh) // 2 + rh), slice((w - rw) // 2, (w - rw) // 2 + rw))
    ctx = lk_window_context(region, h, w)
    i0 = (int(ishift[0, 0]), int(ishift[0, 1]))
    whole = _WholeLowpass.getter(lowpassed, lp_sigma)
    ref = _lowpass_window(stored(frames, 0), g, i0, (0, 0), *ctx, whole=whole(0))

    def mov_window(i: int, iu: int, iv: int) -> np.ndarray:
        return _lowpass_window(
            stored(frames, i),
            g,
            (int(ishift[i, 0]), int(ishift[i, 1])),
            (iu, iv),
            *ctx,
            whole=whole(i),
        )

    if n > 1:  # all frames against the reference at once
        s_all, sg_all, rv_all = lucas_kanade_batch(
            [ref],
            np.zeros(n - 1, dtype=int),
            mov_window,
            np.arange(1, n),
            resid[1:],
            lk_inner_region(region, ctx),
            g,
            iters=iters,
        )
        _accept(out, sig, resvar, resid, s_all, sg_all, rv_all)
    noise = float(np.sqrt(np.nanmedian(resvar))) if np.isfinite(resvar).any() else float("nan")
    return out, sig, noise, resvar


def _accept(
    out: np.ndarray,
    sig: np.ndarray,
    resvar: np.ndarray,
    resid: np.ndarray,
    s_all: np.ndarray,
    sg_all: np.ndarray,
    rv_all: np.ndarray,
) -> None:
    """Take each frame's refined shift, or flag it (std inf) when it moved 0.5 px or failed."""
    for i in range(1, out.shape[0]):  # per frame: accept or flag
        s, sg, rv = s_all[i - 1], sg_all[i - 1], rv_all[i - 1]
        if np.isfinite(sg) and np.abs(s - resid[i]).max() < 0.5:
            out[i], sig[i], resvar[i] = s, sg, rv
        else:
            sig[i] = np.inf


def detect_geometry(
    frames: np.ndarray,
    shifts: np.ndarray,
    tiles: int = 3,
    lp_sigma: float = 1.0,
    tol: float = 0.05,
    tile_max: int = 64,
    lowpassed: _WholeLowpass | None = None,
) -> tuple[np.ndarray | None, np.ndarray, float]:
    """Check whether frames are related by more than a translation; fit affines if so.

    Parameters
    ----------
    frames : numpy.ndarray
        (N, H, W) frames, frame 0 the reference.
    shifts : numpy.ndarray
        (N, 2) starting shifts ``(u, v)`` (LR px) relative to frame 0.
    tiles : int, optional
        Tiles per side.
    lp_sigma : float, optional
        Gaussian low-pass std of the registration (LR px).
    tol : float, optional
        LR px a tile centre must move under the non-translational part to count.
    tile_max : int, optional
        Largest registration window side (px).
    lowpassed : _WholeLowpass or None, optional
        Shared whole-frame low-passes.

    Returns
    -------
    homographies : numpy.ndarray or None
        (N, 3, 3) per-frame affines (reference -> frame LR pixel coordinates, as
        :class:`~subpix_ros.core.superres.model.FrameOperator` takes them), or None when
        a translation fits every frame.
    tile_shifts : numpy.ndarray
        (N, tiles^2, 2) shifts of the tile centres (NaN where the fit failed).
    noise : float
        Multi-frame noise estimate (DN) from the lower quartile of the tiles' residual
        variances (the tiles a local translation fits best; rotation inflates the others).

    Notes
    -----
    Each frame is registered to frame 0 in ``tiles x tiles`` windows of one shape (the
    smallest tile, at most ``tile_max`` px), at each tile's centre, moved inwards where
    its 16 px context would leave the frame, all tiles and frames in one batch. The tile
    shifts ``d(r, c)`` are fitted by ``d = s + J (r - r0, c - c0)`` (least squares,
    (r0, c0) the frame centre); the frames are related by more than a translation when
    ``J`` moves any tile centre by more than ``tol``.
    """
    n, h, w = frames.shape
    wins = _tile_windows(h, w, tiles, tile_max)
    centres = np.array(
        [
            ((sl[0].start + sl[0].stop - 1) / 2.0, (sl[1].start + sl[1].stop - 1) / 2.0)
            for sl in wins
        ]
    )
    rel = centres - np.array([(h - 1) / 2.0, (w - 1) / 2.0])
    tshift, resvar_t = _register_tiles(frames, shifts, wins, lp_sigma, lowpassed)
    # residual variances in the order the frames and tiles were visited before (frame-major)
    resvars = [v for v in resvar_t[1:].ravel() if np.isfinite(v)]
    affines, nonlinear = _fit_affines(tshift, shifts, rel, (h, w), tol)
    noise = float(np.sqrt(np.percentile(resvars, 25))) if resvars else float("nan")
    return (affines if nonlinear else None), tshift, noise


_CTX_PAD = 16  # context px around a registration window (lk_window_context's default)


def _tile_windows(h: int, w: int, tiles: int, tile_max: int) -> list[tuple[slice, slice]]:
    """Return one window of one shape per tile, moved inwards so its context fits the frame."""
    ty = np.linspace(0, h, tiles + 1).astype(int)
    tx = np.linspace(0, w, tiles + 1).astype(int)
    ha, wa = min(int(np.diff(ty).min()), tile_max), min(int(np.diff(tx).min()), tile_max)
    wins = []
    for a in range(tiles):  # tiles, not pixels
        for b in range(tiles):
            ra, ca = (ty[a] + ty[a + 1] - ha) // 2, (tx[b] + tx[b + 1] - wa) // 2
            if h >= ha + 2 * _CTX_PAD:
                ra = min(max(ra, _CTX_PAD), h - _CTX_PAD - ha)
            if w >= wa + 2 * _CTX_PAD:
                ca = min(max(ca, _CTX_PAD), w - _CTX_PAD - wa)
            wins.append((slice(ra, ra + ha), slice(ca, ca + wa)))
    return wins


def _register_tiles(
    frames: np.ndarray,
    shifts: np.ndarray,
    wins: list[tuple[slice, slice]],
    lp_sigma: float,
    lowpassed: _WholeLowpass | None,
) -> tuple[np.ndarray, np.ndarray]:
    """Register every tile window of every frame to frame 0: shifts (N, T, 2), variances (N, T).

    Tiles whose context windows share one shape are registered together, all tiles x
    frames in one :func:`~subpix_ros.core.shift.lucas_kanade_batch`.
    """
    n, h, w = frames.shape
    g = gaussian_kernel(lp_sigma)
    whole = _WholeLowpass.getter(lowpassed, lp_sigma)
    tshift = np.zeros((n, len(wins), 2))
    resvar_t = np.full((n, len(wins)), np.nan)
    groups: dict[tuple, list[tuple[int, tuple[slice, slice]]]] = {}
    for k, sl in enumerate(wins):  # tiles
        ctx = lk_window_context(sl, h, w, _CTX_PAD)
        inner = lk_inner_region(sl, ctx)
        key = (
            ctx[0].stop - ctx[0].start,
            ctx[1].stop - ctx[1].start,
            inner[0].start,
            inner[0].stop,
            inner[1].start,
            inner[1].stop,
        )
        groups.setdefault(key, []).append((k, ctx))
    for key, members in groups.items():  # tiles with one window shape: tiles x frames at once
        refs = [
            _lowpass_window(stored(frames, 0), g, (0, 0), (0, 0), *ctx, whole=whole(0))
            for _, ctx in members
        ]
        pair_tile = np.repeat(np.arange(len(members)), n - 1)
        pair_frame = np.tile(np.arange(1, n), len(members))
        ctxs = [ctx for _, ctx in members]

        def mov_window(m: int, iu: int, iv: int) -> np.ndarray:
            i = int(pair_frame[m])
            return _lowpass_window(
                stored(frames, i), g, (0, 0), (iu, iv), *ctxs[pair_tile[m]], whole=whole(i)
            )

        s0 = np.asarray(shifts, dtype=np.float64)[pair_frame]
        inner = (slice(key[2], key[3]), slice(key[4], key[5]))
        s_all, sg_all, rv_all = lucas_kanade_batch(
            refs, pair_tile, mov_window, np.arange(pair_tile.size), s0, inner, g
        )
        for m in range(pair_tile.size):  # tile x frame pairs
            kk, i = members[pair_tile[m]][0], pair_frame[m]
            tshift[i, kk] = s_all[m] if np.isfinite(sg_all[m]) else np.nan
            resvar_t[i, kk] = rv_all[m]
    return tshift, resvar_t


def _fit_affines(
    tshift: np.ndarray,
    shifts: np.ndarray,
    rel: np.ndarray,
    shape: tuple[int, int],
    tol: float,
) -> tuple[np.ndarray, bool]:
    """Fit ``d = s + J (r - r0, c - c0)`` to each frame's tile shifts; return the affines.

    ``rel`` holds the tile centres relative to the frame centre. A frame with fewer than 4
    registered tiles keeps its translation. Also returns whether any frame's ``J`` moves a
    tile centre by more than ``tol`` LR px.
    """
    n = tshift.shape[0]
    r0, c0 = (shape[0] - 1) / 2.0, (shape[1] - 1) / 2.0
    design = np.concatenate([np.ones((len(rel), 1)), rel], axis=1)  # (T, 3)
    nonlinear = False
    affines = np.zeros((n, 3, 3))
    affines[0] = np.eye(3)
    for i in range(1, n):  # loop over frames
        ok = np.isfinite(tshift[i, :, 0])
        if ok.sum() < 4:
            affines[i] = translation_homography(*shifts[i])
            continue
        coef, *_ = np.linalg.lstsq(design[ok], tshift[i, ok], rcond=None)  # (3, 2): s, J rows
        s = coef[0]
        jac = coef[1:].T  # jac[out, in]: d(u, v) / d(r, c)
        if np.max(np.abs(rel @ jac.T)) > tol:
            nonlinear = True
        affines[i] = np.array(
            [
                [1 + jac[1, 1], jac[1, 0], s[1] - jac[1, 0] * r0 - jac[1, 1] * c0],
                [jac[0, 1], 1 + jac[0, 0], s[0] - jac[0, 0] * r0 - jac[0, 1] * c0],
                [0.0, 0.0, 1.0],
            ]
        )
    return affines, nonlinear
