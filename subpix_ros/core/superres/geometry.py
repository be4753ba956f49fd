"""Registration inside super-resolution: shift refinement and the check for non-translations.

:func:`_refine_shifts` refines every frame's sub-pixel shift against the
reference and gives a multi-frame noise estimate; :func:`detect_geometry`
registers tiles to tell whether the frames are related by more than a
translation and fits an affine per frame if so.
"""

from __future__ import annotations

import numpy as np

from .lowpass import _lowpass_window, _WholeLowpass
from .lucas_kanade import _lk_batch, _lk_context, _lk_inner
from .model import gaussian_kernel, translation_homography

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
    """Refine each frame's sub-pixel shift against frame 0 (Lucas-Kanade on low-passed frames).

    Both frames are low-passed (Gaussian, ``lp_sigma`` LR px) so the fit uses
    the band where aliasing is weak. With ``R`` the low-passed reference
    moved by the current shift ``s`` (Fourier shift, content moves by +s),
    the first-order model ``F ~ R - d . grad R`` gives the Gauss-Newton step
    ``d = -(G^T G)^-1 G^T (F - R)`` over the central region (at most
    ``max_region`` px square, ``border`` px from the edges: cost bounded; only
    that region, with its context, is low-passed and Fourier-shifted).
    Returns refined residual shifts (N, 2), each one's std (LR px) from
    ``var(residual) (G^T G)^-1``, and the per-pixel noise std (DN) implied by
    the residual: ``var(F - R) = 2 sigma^2 (sum g^2)^2`` for white noise
    through the separable low-pass g (median over frames) — a multi-frame
    noise estimate that texture does not bias, unlike single-frame ones —
    and the per-frame noise variances themselves (NaN for frame 0). Frames whose fit diverges (|step| > 0.5 px)
    keep their shift and get std = inf.
    """
    n, h, w = frames.shape
    g = gaussian_kernel(lp_sigma)
    out = resid.copy()
    sig = np.zeros(n)
    resvar = np.full(n, np.nan)
    rh, rw = min(h - 2 * border, max_region), min(w - 2 * border, max_region)
    region = (slice((h - rh) // 2, (h - rh) // 2 + rh), slice((w - rw) // 2, (w - rw) // 2 + rw))
    ctx = _lk_context(region, h, w)
    i0 = (int(ishift[0, 0]), int(ishift[0, 1]))
    whole = _WholeLowpass.getter(lowpassed, lp_sigma)
    ref = _lowpass_window(frames[0], g, i0, (0, 0), *ctx, whole=whole(0))

    def mov_window(i: int, iu: int, iv: int) -> np.ndarray:
        return _lowpass_window(
            frames[i], g, (int(ishift[i, 0]), int(ishift[i, 1])), (iu, iv), *ctx, whole=whole(i)
        )

    if n > 1:  # all frames against the reference at once
        s_all, sg_all, rv_all = _lk_batch(
            [ref],
            np.zeros(n - 1, dtype=int),
            mov_window,
            np.arange(1, n),
            resid[1:],
            _lk_inner(region, ctx),
            g,
            iters=iters,
        )
        for i in range(1, n):  # per frame: accept or flag
            s, sg, rv = s_all[i - 1], sg_all[i - 1], rv_all[i - 1]
            if np.isfinite(sg) and np.abs(s - resid[i]).max() < 0.5:
                out[i], sig[i], resvar[i] = s, sg, rv
            else:
                sig[i] = np.inf
    noise = float(np.sqrt(np.nanmedian(resvar))) if np.isfinite(resvar).any() else float("nan")
    return out, sig, noise, resvar


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

    Each frame is registered to frame 0 in ``tiles x tiles`` tiles (Lucas-
    Kanade on low-passed frames, started from ``shifts``, over one window
    shape for all tiles — the smallest tile, at most ``tile_max`` px square —
    at each tile's centre, moved inwards where its 16 px context would leave
    the frame, so all tiles and frames are registered in one batch; only
    those windows are low-passed, and each reference tile is Fourier-
    transformed once for all frames); the tile shifts
    ``d(r, c)`` (at the window centres) are fitted by
    ``d = s + J (r - r0, c - c0)`` (least squares, (r0, c0) the frame centre). If the
    non-translational part ``J`` moves any
    tile centre by more than ``tol`` LR px, the affine of every frame is
    returned as a homography (reference -> frame LR pixel coordinates, as
    :class:`FrameOperator` takes them), else None. Also returns the tile
    shifts (N, tiles^2, 2) and the multi-frame noise estimate (DN): from
    the lower quartile of the tiles' residual variances (the tiles a local
    translation fits best; rotation inflates the others).
    """
    n, h, w = frames.shape
    g = gaussian_kernel(lp_sigma)
    whole = _WholeLowpass.getter(lowpassed, lp_sigma)
    ty = np.linspace(0, h, tiles + 1).astype(int)
    tx = np.linspace(0, w, tiles + 1).astype(int)
    ctx_pad = 16  # _lk_context's default
    # one window shape for all tiles (the smallest tile, at most tile_max), each window moved inwards
    # where needed so that its context lies inside the frame: all tiles x frames form one batch
    ha, wa = min(int(np.diff(ty).min()), tile_max), min(int(np.diff(tx).min()), tile_max)
    wins = []
    for a in range(tiles):  # tiles, not pixels
        for b in range(tiles):
            ra, ca = (ty[a] + ty[a + 1] - ha) // 2, (tx[b] + tx[b + 1] - wa) // 2
            if h >= ha + 2 * ctx_pad:
                ra = min(max(ra, ctx_pad), h - ctx_pad - ha)
            if w >= wa + 2 * ctx_pad:
                ca = min(max(ca, ctx_pad), w - ctx_pad - wa)
            wins.append((slice(ra, ra + ha), slice(ca, ca + wa)))
    centres = np.array(
        [
            ((sl[0].start + sl[0].stop - 1) / 2.0, (sl[1].start + sl[1].stop - 1) / 2.0)
            for sl in wins
        ]
    )
    r0, c0 = (h - 1) / 2.0, (w - 1) / 2.0
    rel = centres - np.array([r0, c0])
    design = np.concatenate([np.ones((len(rel), 1)), rel], axis=1)  # (T, 3)
    tshift = np.zeros((n, len(rel), 2))
    resvar_t = np.full((n, len(rel)), np.nan)
    groups: dict[tuple, list[tuple[int, tuple[slice, slice]]]] = {}
    for k, sl in enumerate(wins):  # tiles
        ctx = _lk_context(sl, h, w, ctx_pad)
        inner = _lk_inner(sl, ctx)
        key = (
            ctx[0].stop - ctx[0].start,
            ctx[1].stop - ctx[1].start,
            inner[0].start,
            inner[0].stop,
            inner[1].start,
            inner[1].stop,
        )
        groups.setdefault(key, []).append((k, ctx))
    for (
        key,
        members,
    ) in groups.items():  # tiles whose windows have one shape: all tiles x frames at once
        refs = [
            _lowpass_window(frames[0], g, (0, 0), (0, 0), *ctx, whole=whole(0))
            for _, ctx in members
        ]
        pair_tile = np.repeat(np.arange(len(members)), n - 1)
        pair_frame = np.tile(np.arange(1, n), len(members))
        ctxs = [ctx for _, ctx in members]

        def mov_window(m: int, iu: int, iv: int) -> np.ndarray:
            i = int(pair_frame[m])
            return _lowpass_window(
                frames[i], g, (0, 0), (iu, iv), *ctxs[pair_tile[m]], whole=whole(i)
            )

        s0 = np.asarray(shifts, dtype=np.float64)[pair_frame]
        inner = (slice(key[2], key[3]), slice(key[4], key[5]))
        s_all, sg_all, rv_all = _lk_batch(
            refs, pair_tile, mov_window, np.arange(pair_tile.size), s0, inner, g
        )
        for m in range(pair_tile.size):  # tile x frame pairs
            kk, i = members[pair_tile[m]][0], pair_frame[m]
            tshift[i, kk] = s_all[m] if np.isfinite(sg_all[m]) else np.nan
            resvar_t[i, kk] = rv_all[m]
    # residual variances in the order the frames and tiles were visited before (frame-major)
    resvars = [v for v in resvar_t[1:].ravel() if np.isfinite(v)]
    nonlinear = False
    affines = np.zeros((n, 3, 3))
    affines[0] = np.eye(3)
    for i in range(1, n):  # loop over frames
        ok = np.isfinite(tshift[i, :, 0])
        if ok.sum() < 4:
            affines[i] = translation_homography(*shifts[i])
            continue
        coef, *_ = np.linalg.lstsq(design[ok], tshift[i, ok], rcond=None)  # (3, 2): s, then J rows
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
    noise = float(np.sqrt(np.percentile(resvars, 25))) if resvars else float("nan")
    return (affines if nonlinear else None), tshift, noise
