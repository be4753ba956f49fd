"""One registration pass at input resolution (stage 3 of :func:`.register`), as objects.

A :class:`.state._Pass` owns what every step of registering one moving frame to one reference
needs (the prepared frames, the validated options, the start time); :class:`_InputStage` owns
the state of the input-resolution stage (scales, tie points, the model being fitted) and runs its
steps: first matching, robust start, sub-pixel refinement and fit with the radial term, the
second pass over the points the first one missed, the final checks.
"""

from __future__ import annotations

import time

import numpy as np

from .fit import (
    Normaliser,
    check_homography,
    distort_points,
    fit_homography_distortion_lm,
    fit_homography_lm,
    undistort_points,
)
from .geometry import _inside, _scale_h, apply_h, overlap_fraction
from .points import ncc_match
from .result import RegistrationResult
from .robust import (
    _fit_fixed_lambda,
    _full_residuals,
    _model_residuals,
    _refit_distortion,
    _residuals,
    _robust,
    _spread,
)
from .state import _Pass, _Seeds
from .tiepoints import _finer_candidates, _point_key, _refine_levels


class _InputStage:
    """State and steps of the input-resolution stage of one pass (:func:`_final_stage`)."""

    def __init__(self, ps: _Pass, seeds: _Seeds):
        tmpl = ps.opts.template_half
        self.ps = ps
        self.gr, self.gm = ps.ref.gray, ps.mov.gray
        self.scale = 2.0**seeds.level
        self.h = _scale_h(seeds.h, self.scale)
        # Above the detection size the texture per pixel is finer and blurrier: the template
        # keeps its ground footprint of the detection level's double (ncc_level, where NCC runs)
        self.half = int(round(tmpl * max(1.0, self.scale / 2)))
        self.ncc_level = max(0, seeds.level - 1)
        self.ncc_scale = 2.0**self.ncc_level
        self.ncc_half = tmpl if self.ncc_level > 0 else self.half
        self.margin = self.half + seeds.radius + 3
        self.norm = Normaliser.for_shape(self.gr.shape)
        # thresholds before the radial term is fitted grow with the resolution above the
        # detection level's double: the unmodelled lens distortion (and parallax) grows with it
        self.threshold_scale = max(1.0, self.scale / 2)
        self.hu, self.lam = None, 0.0

    def residuals(self, p_m: np.ndarray, p_r: np.ndarray) -> np.ndarray:
        """Return the residuals of the current model (full once the radial term is fitted)."""
        return _model_residuals(self.h, self.hu, self.lam, self.norm, p_m, p_r)

    def seed_positions(self, seeds: _Seeds):
        """Return the input-px points inside both frames, their predictions and seeded mask."""
        pts0 = np.rint(seeds.pts * self.scale)
        pred = apply_h(np.linalg.inv(self.h), pts0)
        seeded = np.zeros(len(pts0), bool)
        if seeds.pred is not None:
            own = seeds.pred * self.scale
            near = np.hypot(*(own - pred).T) <= 2 * seeds.radius
            seeded = np.isfinite(own).all(axis=1) & near
            pred[seeded] = own[seeded]
        ok_in = _inside(pts0, self.gr.shape, self.margin) & _inside(
            pred, self.gm.shape, self.margin
        )
        return pts0[ok_in], pred[ok_in], seeded[ok_in]

    def match_unseeded(self, pts0, pred, seeded, radius: int):
        """Match the points without a detection-level match by NCC at level ``ncc_level``.

        The detection-level matches (to ~0.2 level px) start the refinement directly.
        """
        ncc_scale = self.ncc_scale
        q_r, q_m, _ = ncc_match(
            self.ps.ref.level(self.ncc_level),
            self.ps.mov.level(self.ncc_level),
            pts0[~seeded] / ncc_scale,
            _scale_h(self.h, 1.0 / ncc_scale),
            half=self.ncc_half,
            radius=int(np.ceil(radius / ncc_scale)),
            pred_mov=pred[~seeded] / ncc_scale,
        )
        return np.vstack([pts0[seeded], q_r * ncc_scale]), np.vstack(
            [pred[seeded], q_m * ncc_scale]
        )

    def robust_start(self, p_r, p_m) -> str | tuple:
        """Reject outliers by MAGSAC, then fit by LM from the identity (METHODS C), guarded.

        The LM fit from MAGSAC's estimate replaces the one from the identity if it fits
        better. Returns the reason of a failure, or the inlier points ``(p_r, p_m)``.
        """
        opts = self.ps.opts
        hn, inl = _robust(p_m, p_r, 2.0 * self.threshold_scale, opts.affine)
        if hn is None or inl.sum() < opts.min_inliers:
            return (
                f"too few tie points: {int(inl.sum())} consistent matches (need {opts.min_inliers})"
            )
        p_r, p_m = p_r[inl], p_m[inl]
        h_id = fit_homography_lm(p_m, p_r, self.norm, opts.affine)
        h_rb = fit_homography_lm(p_m, p_r, self.norm, opts.affine, h0=hn)
        rms_id = np.sqrt(np.mean(_residuals(h_id, p_m, p_r) ** 2))
        self.h = (
            h_id if rms_id <= np.sqrt(np.mean(_residuals(h_rb, p_m, p_r) ** 2)) + 1e-9 else h_rb
        )
        return p_r, p_m

    def refine_and_fit(self, p_r, p_m) -> str | None:
        """Refine the tie points to sub-pixel and fit the final model (with the radial term).

        Sets ``p_r``, ``p_m``, ``h``, ``hu``, ``lam``, ``res``, ``inl``; returns the reason of
        a failure or None.
        """
        opts = self.ps.opts
        affine, norm = opts.affine, self.norm
        # seeds from the detection level start up to ~0.5 level px off: up to 10 iterations
        p_m2, conv = _refine_levels(
            self.ps, p_r, p_m, self.h, self.ncc_level, 0, self.half, iterations=10
        )
        p_r, p_m = p_r[conv], p_m2[conv]
        if len(p_r) < opts.min_inliers:
            return f"too few tie points after sub-pixel refinement ({len(p_r)})"
        h = fit_homography_lm(p_m, p_r, norm, affine, h0=self.h)
        inl = _residuals(h, p_m, p_r) <= 2 * opts.inlier_px * self.threshold_scale
        h = fit_homography_lm(p_m[inl], p_r[inl], norm, affine, h0=h)
        lam, hu = 0.0, None
        res = _residuals(h, p_m, p_r)
        if opts.fixed_lam is not None and opts.fixed_lam != 0.0:
            # shared calibration: lambda known, only H_u fitted
            lam = opts.fixed_lam
            hu = _fit_fixed_lambda(p_m[inl], p_r[inl], lam, norm, affine, h)
            res = _full_residuals(hu, lam, norm, p_m, p_r)
        elif opts.fixed_lam is None and opts.distortion and inl.sum() >= 40:
            hu_c, lam_c = fit_homography_distortion_lm(p_m[inl], p_r[inl], norm, h, affine)
            if np.isfinite(lam_c) and abs(lam_c) < 0.3:
                res_c = _full_residuals(hu_c, lam_c, norm, p_m, p_r)
                if np.sqrt(np.mean(res_c[inl] ** 2)) < np.sqrt(np.mean(res[inl] ** 2)):
                    lam, hu, res = lam_c, hu_c, res_c
        inl = res <= opts.inlier_px
        if lam != 0.0 and inl.sum() >= (8 if opts.fixed_lam is not None else 40):
            hu, lam = _refit_distortion(p_m[inl], p_r[inl], lam, hu, opts.fixed_lam, norm, affine)
            res = _full_residuals(hu, lam, norm, p_m, p_r)
            inl = res <= opts.inlier_px
        if inl.sum() >= 8:
            h = fit_homography_lm(p_m[inl], p_r[inl], norm, affine, h0=h)
        self.p_r, self.p_m, self.h, self.hu, self.lam, self.res, self.inl = (
            p_r,
            p_m,
            h,
            hu,
            lam,
            res,
            inl,
        )
        return None

    def missed_points(self, pts0, extra) -> np.ndarray:
        """Return the points without an inlier match, plus further candidates on weak texture."""
        opts = self.ps.opts
        miss = pts0[~np.isin(_point_key(pts0), _point_key(self.p_r[self.inl]))]
        if self.inl.sum() < opts.want_inliers:
            if self.ncc_level > 0:  # input finer than the detection level's double
                # as many as the deficit needs, 15 per missing inlier (design notes)
                deficit = opts.want_inliers - self.inl.sum()
                n_fine = int(np.clip(15 * deficit, opts.n_points // 2, 3 * opts.n_points))
                ex = _finer_candidates(self.ps, self.ncc_level, self.h, pts0, n_fine, self.margin)
            else:
                ex = np.zeros((0, 2)) if extra is None else np.rint(extra * self.scale)
            ex = ex[_inside(ex, self.gr.shape, self.margin)]
            miss = np.vstack([miss, ex[~np.isin(_point_key(ex), _point_key(miss))]])
        return miss

    def match_missed(self, miss: np.ndarray):
        """Search ``miss`` by NCC around the model's prediction, refine; return new tie points."""
        inlier_px = self.ps.opts.inlier_px
        lam, hu, norm, ncc_scale = self.lam, self.hu, self.norm, self.ncc_scale
        if lam != 0.0 and hu is not None:
            pred2 = distort_points(
                apply_h(np.linalg.inv(hu), undistort_points(miss, lam, norm)), lam, norm
            )
        else:
            pred2 = apply_h(np.linalg.inv(self.h), miss)
        inside = _inside(pred2, self.gm.shape, self.margin)
        miss, pred2 = miss[inside], pred2[inside]
        r2, m2, _ = ncc_match(
            self.ps.ref.level(self.ncc_level),
            self.ps.mov.level(self.ncc_level),
            miss / ncc_scale,
            _scale_h(self.h, 1.0 / ncc_scale),
            half=self.ncc_half,
            radius=2,
            pred_mov=pred2 / ncc_scale,
        )
        r2, m2 = r2 * ncc_scale, m2 * ncc_scale
        if self.ncc_level > 0:
            # refined first at the NCC level (cheap); only matches that can be inliers (0.5 px
            # to spare for that level's precision) are refined at the input resolution
            m2, c = _refine_levels(self.ps, r2, m2, self.h, self.ncc_level, 1, self.half)
            r2, m2 = r2[c], m2[c]
            near = self.residuals(m2, r2) <= inlier_px + 0.5
        else:
            # Gauss-Newton moves a point by less than 1 px (it rejects larger moves), so a match
            # further than inlier_px + 1 px from the model cannot become an inlier
            near = self.residuals(m2, r2) <= inlier_px + 1.5
        r2, m2 = r2[near], m2[near]
        m2, conv2 = _refine_levels(self.ps, r2, m2, self.h, 0, 0, self.half, iterations=10)
        return r2[conv2], m2[conv2]

    def second_pass(self, pts0, extra) -> None:
        """Search the points the first pass missed around this model, and refit if any fit.

        The coarser level's projective prediction was a few px off for them (e.g. at the frame
        edges under lens distortion), so their NCC peak fell outside the window.
        """
        opts = self.ps.opts
        if self.inl.sum() < opts.min_inliers:
            return
        miss = self.missed_points(pts0, extra)
        if not len(miss):
            return
        r2, m2 = self.match_missed(miss)
        if not (self.residuals(m2, r2) <= opts.inlier_px).any():
            return
        keep_old = ~np.isin(_point_key(self.p_r), _point_key(r2))
        self.p_r = np.vstack([self.p_r[keep_old], r2])
        self.p_m = np.vstack([self.p_m[keep_old], m2])
        p_r, p_m, norm, affine = self.p_r, self.p_m, self.norm, opts.affine
        inl = self.residuals(p_m, p_r) <= opts.inlier_px
        if self.hu is not None:
            self.hu, self.lam = _refit_distortion(
                p_m[inl], p_r[inl], self.lam, self.hu, opts.fixed_lam, norm, affine
            )
        else:
            self.h = fit_homography_lm(p_m[inl], p_r[inl], norm, affine, h0=self.h)
        self.res = self.residuals(p_m, p_r)
        self.inl = self.res <= opts.inlier_px
        self.h = fit_homography_lm(p_m[self.inl], p_r[self.inl], norm, affine, h0=self.h)

    def result(self) -> RegistrationResult:
        """Check the final model and return the result."""
        ps, opts = self.ps, self.ps.opts
        p_r, p_m, inl, h, hu, lam, res = (
            self.p_r,
            self.p_m,
            self.inl,
            self.h,
            self.hu,
            self.lam,
            self.res,
        )
        n_in = int(inl.sum())
        if n_in < opts.min_inliers:
            return ps.fail(f"too few inliers: {n_in} (need {opts.min_inliers})")
        reason = check_homography(h, self.gm.shape)
        if reason:
            return ps.fail(reason)
        spread = _spread(p_r[inl], h, self.gr.shape, self.gm.shape)
        if spread < opts.min_spread:
            return ps.fail(
                f"tie points badly spread: {spread:.2f} of the overlap cells "
                f"(need {opts.min_spread})"
            )
        rms_full = float(np.sqrt(np.mean(res[inl] ** 2)))
        rms_proj = float(np.sqrt(np.mean(_residuals(h, p_m[inl], p_r[inl]) ** 2)))
        if opts.fixed_lam is None and lam != 0.0 and rms_full > rms_proj:
            # the estimated term was fitted on an earlier inlier set: refit it on the final one
            # from the projective fit and lambda = 0 (LM only accepts improvements)
            hu, lam = fit_homography_distortion_lm(p_m[inl], p_r[inl], self.norm, h, opts.affine)
            res = _full_residuals(hu, lam, self.norm, p_m, p_r)
            rms_full = float(np.sqrt(np.mean(res[inl] ** 2)))
        return RegistrationResult(
            ok=True,
            homography=h,
            inliers=n_in,
            rms_px=rms_full,
            overlap=overlap_fraction(h, self.gr.shape, self.gm.shape),
            points=np.hstack([p_r[inl], p_m[inl]]),
            model=opts.model,
            distortion=float(lam),
            homography_undistorted=hu,
            rms_px_projective=rms_proj,
            median_px=float(np.median(res[inl])),
            spread=spread,
            ref_shape=self.gr.shape,
            mov_shape=self.gm.shape,
            time_s=time.perf_counter() - ps.t0,
        )


def _final_stage(ps: _Pass, seeds: _Seeds) -> tuple[RegistrationResult, int]:
    """Run the input-resolution stage of :func:`.register` (stage 3).

    MAGSAC, LM, Gauss-Newton, final LM with the radial term, second pass, checks.

    Parameters
    ----------
    ps : _Pass
        The pass.
    seeds : _Seeds
        Tie points and model at their pyramid level. The matches ``seeds.pred``, scaled to
        input resolution, seed the Gauss-Newton refinement directly (coarse to fine from level
        ``seeds.level - 1``); the points without one are matched by NCC within
        ``seeds.radius`` input px of the model's prediction.

    Returns
    -------
    result : RegistrationResult
    n_try : int
        Tie points of the first pass.

    Notes
    -----
    The second pass searches the points without an inlier match (and, when the first pass
    has fewer than ``want_inliers`` inliers, further candidates: ``seeds.extra``, or, when
    the input is finer than the detection level's double, Harris maxima of level
    ``seeds.level - 1``) by NCC at level ``seeds.level - 1`` around the model's prediction,
    refines them and refits. It also runs when tracking: without it the frame edges, where
    the projective prior misses the lens distortion by a few px, keep almost no tie points.
    """
    stage = _InputStage(ps, seeds)
    pts0, pred, seeded = stage.seed_positions(seeds)
    n_try = len(pts0)
    p_r, p_m = stage.match_unseeded(pts0, pred, seeded, seeds.radius)
    start = stage.robust_start(p_r, p_m)
    if isinstance(start, str):
        return ps.fail(start), n_try
    why = stage.refine_and_fit(*start)
    if why:
        return ps.fail(why), n_try
    stage.second_pass(pts0, seeds.extra)
    return stage.result(), n_try
