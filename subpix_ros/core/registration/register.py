"""Public entry point :func:`register`: the full pipeline and the tracking path."""

from __future__ import annotations

import time

import cv2
import numpy as np

from .coarse import (
    CoarseResult,
    coarse_orb,
    coarse_overlap,
    gradient_magnitude,
    orb_features,
    orientation_hypotheses,
)
from .fit import check_homography
from .frames import ReferenceFrame, _levels, _prepare_pair, prepare_reference, to_gray32
from .geometry import _scale_h, _valid_ref_points, apply_h
from .harris import select_spread
from .passes import _final_stage
from .points import ncc_match
from .result import RegistrationResult
from .robust import _robust
from .state import _Options, _Pass, _Seeds
from .tiepoints import _candidates, _per_point


# long: the numpydoc Parameters of 17 options; the body is ~30 lines
def register(
    reference: np.ndarray | ReferenceFrame,
    moving: np.ndarray | ReferenceFrame,
    *,
    model: str = "projective",
    distortion: bool | float = True,
    n_points: int = 700,
    coarse_size: int = 128,
    detect_size: int = 1000,
    template_half: int = 7,
    inlier_px: float = 1.5,
    min_inliers: int = 16,
    min_spread: float = 0.25,
    coarse_method: str = "orb",
    angles: list[float] | None = None,
    prior: np.ndarray | None = None,
    track_radius: int = 4,
    track_min_fraction: float = 0.1,
    want_inliers: int = 200,
) -> RegistrationResult:
    """Register ``moving`` to ``reference`` (pipeline and conventions: :mod:`.registration`).

    Parameters
    ----------
    reference : ndarray or ReferenceFrame
        A frame, or a :class:`ReferenceFrame` from :func:`prepare_reference` (its luminance,
        pyramid, Harris points and coarse features are then reused, not recomputed).
    moving : ndarray or ReferenceFrame
        A frame, or a prepared one (a strip: each frame prepared once serves as the moving
        frame of one pair and the reference of the next).
    model : {"projective", "affine"}
        METHODS C, eq. P, or its affine case (the shift paper's choice).
    distortion : bool or float
        ``True`` estimates the radial term (division model, one lambda for both frames) from
        this pair's tie points (needs >= 40 inliers; kept only if it lowers the RMS residual);
        a float is a fixed camera calibration lambda (e.g. from :func:`calibrate_distortion`),
        only ``H_u`` is fitted; ``False`` (or 0.0) fits the projective model alone.
    n_points : int
        Tie points searched.
    coarse_size, detect_size : int
        Sizes (px, larger side) of the coarse and detection pyramid levels.
    template_half : int
        NCC template half-size at the detection level (px).
    inlier_px : float
        Inlier threshold on the transfer residual (reference px, at input resolution).
    min_inliers : int
        Fewest inliers accepted.
    min_spread : float
        Least fraction of 6x6 overlap cells holding an inlier.
    coarse_method : {"orb", "fragments"}
        Stage 1: ORB + MAGSAC similarity, or the paper's fragment search.
    angles : list of float, optional
        Rotation hypotheses (radians) to use instead of the orientation-histogram ones.
    prior : ndarray, shape (3, 3), optional
        Tracking: a homography (moving -> reference px) predicting this frame (e.g. the
        previous frame's result). The coarse stage and the pyramid are skipped: the tie points
        are matched within ``track_radius`` px of the prior's prediction, then fitted and
        checked as usual, and also required to be at least ``track_min_fraction`` inliers and
        to depart from the prior by less than ``track_radius``. If tracking fails, the full
        pipeline runs.
    track_radius : int
        Search radius of the tracking path (input px, 1-64).
    track_min_fraction : float
        Least fraction of inliers among the searched points when tracking.
    want_inliers : int
        When the first pass at input resolution ends with fewer inliers (weak texture),
        further Harris points are searched in the second pass (0 disables it): up to
        ``2 n_points`` of the detection level, or, for inputs more than twice the detection
        size, 15 per missing inlier (``n_points / 2`` to ``3 n_points``) of the next finer
        level.

    Returns
    -------
    RegistrationResult
        ``ok=False`` with a reason for blank / textureless frames, no confirmed overlap, too
        few or badly spread tie points, a degenerate or insane fit. ``tracked`` says which
        path gave the result and ``track_failure`` why tracking failed.

    Raises
    ------
    ValueError
        For bad frames or options.
    """
    # the keyword options, read before any other local exists
    options = {k: v for k, v in locals().items() if k not in ("reference", "moving", "prior")}
    t0 = time.perf_counter()
    opts = _check_options(**options)
    if prior is not None:
        prior = _check_prior(prior)
        if not (isinstance(track_radius, (int, np.integer)) and 1 <= track_radius <= 64):
            raise ValueError(f"track_radius must be an integer in [1, 64], got {track_radius!r}")
    ps = _Pass(*_prepare(reference, moving, prior, coarse_size, detect_size), opts, t0)
    if ps.ref.blank:
        return ps.fail(_blank("reference", ps.ref.gray))
    if ps.mov.blank:
        return ps.fail(_blank("moving", ps.mov.gray))
    track_failure = ""
    if prior is not None:
        res = _register_tracked(ps, prior)
        if res.ok:
            return res
        track_failure = res.reason
    res = _register_full(ps)
    res.track_failure = track_failure
    return res


def _check_options(*, model, distortion, coarse_method, want_inliers, **rest) -> _Options:
    """Validate :func:`register`'s options (its keyword arguments but the frames and prior).

    Raises
    ------
    ValueError
        For a bad distortion lambda, model or coarse method.
    """
    if isinstance(distortion, (bool, np.bool_)):
        fixed_lam = None if distortion else 0.0
    else:
        fixed_lam = float(distortion)
        if not (np.isfinite(fixed_lam) and abs(fixed_lam) < 0.3):
            raise ValueError(
                f"distortion lambda must be finite and |lambda| < 0.3, got {distortion!r}"
            )
    if model not in ("projective", "affine"):
        raise ValueError(f"model must be 'projective' or 'affine', got {model!r}")
    if coarse_method not in ("orb", "fragments"):
        raise ValueError(f"coarse_method must be 'orb' or 'fragments', got {coarse_method!r}")
    return _Options(
        model=model,
        fixed_lam=fixed_lam,
        distortion=distortion,
        want_inliers=int(want_inliers),
        coarse_method=coarse_method,
        **rest,
    )


def _prepare(reference, moving, prior, coarse_size: int, detect_size: int):
    """Return both frames prepared (a one-off pair of arrays: at the same time, two threads)."""
    if (
        prior is None
        and not isinstance(reference, ReferenceFrame)
        and not isinstance(moving, ReferenceFrame)
    ):
        return _prepare_pair(reference, moving, coarse_size, detect_size)
    ref = prepare_reference(reference, coarse_size=coarse_size, detect_size=detect_size)
    if isinstance(moving, ReferenceFrame):  # prepared once, e.g. a strip frame (next reference)
        return ref, moving
    return ref, ReferenceFrame.of(to_gray32(moving, "moving"))


def _check_prior(prior) -> np.ndarray:
    """Return the prior normalised to ``H[2, 2] = 1``; ValueError if it is not a homography."""
    p = np.asarray(prior, dtype=np.float64)
    if p.shape != (3, 3) or not np.isfinite(p).all() or abs(p[2, 2]) < 1e-12:
        raise ValueError(
            f"prior must be a finite 3x3 homography with H[2, 2] != 0, got shape {p.shape}"
        )
    return p / p[2, 2]


def _coarse_stage(ps: _Pass, n_lev: int, det_lev: int, mid_lev: int):
    """Run stage 1 (coarse overlap); return the coarse result, the method used and its level.

    ORB + MAGSAC similarity at the middle level; the paper's fragment search (METHODS C
    stage 1, under rotation hypotheses) when asked for or when ORB finds too little; as a last
    resort 5000 weaker ORB corners one level finer.
    """
    ref, mov, opts = ps.ref, ps.mov, ps.opts
    used = opts.coarse_method
    coarse: CoarseResult | None = None
    h_lev = n_lev
    if opts.coarse_method == "orb":
        coarse = coarse_orb(
            ref.level(mid_lev),
            mov.level(mid_lev),
            ref_features=ref.orb(mid_lev),
            mov_features=mov.orb(mid_lev),
        )
        h_lev = mid_lev
    if opts.coarse_method == "fragments" or not coarse.ok:
        gc_r = gradient_magnitude(cv2.GaussianBlur(ref.level(n_lev), (3, 3), 0))
        gc_m = gradient_magnitude(cv2.GaussianBlur(mov.level(n_lev), (3, 3), 0))
        if opts.angles is not None:
            hyps = [float(a) for a in opts.angles]
        else:  # histogram peaks, plus "no rotation" (the usual case between consecutive frames)
            hyps = orientation_hypotheses(ref.level(mid_lev), mov.level(mid_lev))
            if min(abs(((a + np.pi) % (2 * np.pi)) - np.pi) for a in hyps) > np.deg2rad(7):
                hyps.append(0.0)
        frag = coarse_overlap(gc_r, gc_m, hyps)
        if opts.coarse_method == "fragments" or frag.ok:
            coarse, used, h_lev = frag, "fragments", n_lev
    if opts.coarse_method == "orb" and not coarse.ok:
        # last resort (both above failed, e.g. ~20 % overlap on weak infrared texture)
        lev = max(det_lev, mid_lev - 1)
        rich = coarse_orb(
            ref.level(lev),
            mov.level(lev),
            ref_features=orb_features(ref.level(lev), 5000, fast_threshold=10),
            mov_features=orb_features(mov.level(lev), 5000, fast_threshold=10),
        )
        if rich.ok:
            coarse, used, h_lev = rich, "orb", lev
    return coarse, used, h_lev


def _pyramid_stage(ps: _Pass, h, h_lev: int, top: int, det_lev: int) -> _Seeds | str:
    """Run stage 2: NCC tie points and MAGSAC at each level from ``top`` to ``det_lev``.

    Returns the seeds of the input-resolution stage, or the reason of a failure.
    """
    ref, mov, opts = ps.ref, ps.mov, ps.opts
    half = opts.template_half
    pts_det = pred_det = extra_det = None
    first = True
    for lev in range(top, det_lev - 1, -1):
        h = _scale_h(h, 2.0 ** (h_lev - lev))
        h_lev = lev
        ref_l, mov_l = ref.level(lev), mov.level(lev)
        # first level: the coarse similarity is off by up to ~10 level px over the overlap
        radius = 8 if first else 4
        first = False
        margin = half + radius + 2
        valid = _valid_ref_points(ref_l.shape, mov_l.shape, h, margin, margin)
        if valid.sum() < 64:
            return "no overlap: the predicted overlap is empty"
        if lev == det_lev:
            pts, extra_det = _candidates(ref.peaks(lev), valid, opts.n_points, opts.want_inliers)
        else:
            pts = select_spread(ref.peaks(lev), valid, n_target=150)
        p_r, p_m, _ = ncc_match(ref_l, mov_l, pts, h, half=half, radius=radius)
        hn, inl = _robust(p_m, p_r, 1.0 if lev > det_lev else 1.5, opts.affine)
        if hn is None or inl.sum() < max(8, opts.min_inliers // 2):
            return (
                f"too few tie points at pyramid level {lev} ({int(inl.sum())} consistent matches)"
            )
        reason = check_homography(hn, mov_l.shape)
        if reason:
            return reason
        h = hn
        pts_det = pts
        pred_det = _per_point(pts, p_r, p_m)
    if pts_det is None:  # no refinement level (tiny input): detect at the input level directly
        h = _scale_h(h, 2.0**h_lev)
        h_lev = 0
        valid = _valid_ref_points(ps.ref.gray.shape, ps.mov.gray.shape, h, half + 6, half + 6)
        pts_det = select_spread(ref.peaks(0), valid, n_target=opts.n_points)
    # the level's per-point matches predict to ~0.5 level px
    radius = 1 + int(2.0**h_lev) if pred_det is None else 2 + int(2.0**h_lev) // 2
    return _Seeds(pts_det, h, h_lev, radius, pred_det, extra_det)


def _register_full(ps: _Pass) -> RegistrationResult:
    """Run the full pipeline: coarse stage, pyramid refinement, :func:`.passes._final_stage`."""
    gr, gm = ps.ref.gray, ps.mov.gray
    opts = ps.opts
    n_lev = max(0, int(np.ceil(np.log2(max(max(gr.shape), max(gm.shape)) / opts.coarse_size))))
    _, det_lev, mid_lev = _levels(gr.shape, opts.coarse_size, opts.detect_size)
    det_lev, mid_lev = min(n_lev, det_lev), min(n_lev, mid_lev)
    for lev in range(n_lev + 1):  # the moving pyramid down to the top level, built in order
        ps.mov.level(lev)
    coarse, used, h_lev = _coarse_stage(ps, n_lev, det_lev, mid_lev)
    if not coarse.ok:
        return ps.fail(coarse.reason)
    h = coarse.transform
    if not np.isfinite(h).all():
        return ps.fail("degenerate coarse fit")
    top = min(h_lev, max(mid_lev, det_lev)) if used == "orb" else h_lev - 1
    seeds = _pyramid_stage(ps, h, h_lev, top, det_lev)
    if isinstance(seeds, str):
        return ps.fail(seeds)
    return _final_stage(ps, seeds)[0]


def _track_seeds(ps: _Pass, prior: np.ndarray, radius: int) -> _Seeds | str:
    """Match the tie points around ``prior``'s prediction at the detection level.

    Returns the seeds of the input-resolution stage, or the reason tracking failed.
    """
    ref, mov, opts = ps.ref, ps.mov, ps.opts
    reason = check_homography(prior, mov.gray.shape)
    if reason:
        return f"prior rejected: {reason}"
    _, det_lev, _ = _levels(ref.gray.shape, opts.coarse_size, opts.detect_size)
    scale = 2.0**det_lev
    h_det = _scale_h(prior, 1.0 / scale)
    r_det = int(np.ceil(radius / scale)) + 1  # the NCC peak must be inside the window
    mov_l = mov.level(det_lev)
    ref_l = ref.level(det_lev)
    margin = opts.template_half + r_det + 2
    valid = _valid_ref_points(ref_l.shape, mov_l.shape, h_det, margin, margin)
    if valid.sum() < 64:
        return "no overlap: the prior's predicted overlap is empty"
    pts, extra = _candidates(ref.peaks(det_lev), valid, opts.n_points, opts.want_inliers)
    p_r, p_m, _ = ncc_match(ref_l, mov_l, pts, h_det, half=opts.template_half, radius=r_det)
    hn, inl = _robust(p_m, p_r, 1.5, opts.affine)
    need = max(8, opts.min_inliers // 2, opts.track_min_fraction * len(pts))
    if hn is None or inl.sum() < need:
        return f"tracking lost: {int(inl.sum())} of {len(pts)} tie points consistent with the prior"
    reason = check_homography(hn, mov_l.shape)
    if reason:
        return reason
    return _Seeds(pts, hn, det_lev, 2 + int(scale) // 2, _per_point(pts, p_r, p_m), extra)


def _register_tracked(ps: _Pass, prior: np.ndarray) -> RegistrationResult:
    """Run the tracking path: tie points matched around ``prior``'s prediction, no coarse stage.

    At the detection level only (no pyramid descent): the reference's Harris points inside the
    overlap predicted by ``prior`` (moving -> reference px) are matched by NCC within
    ``track_radius`` input px of the prediction and a homography fitted robustly, then
    :func:`.passes._final_stage` runs as in the full pipeline. Extra acceptance checks (a
    wrong prior must not give a result): at least ``track_min_fraction`` of the searched
    points are inliers, and the model departs from the prior by less than
    ``track_radius + 1`` px over the inliers.
    """
    radius, min_fraction = int(ps.opts.track_radius), ps.opts.track_min_fraction
    seeds = _track_seeds(ps, prior, radius)
    if isinstance(seeds, str):
        return ps.fail(seeds)
    res, n_try = _final_stage(ps, seeds)
    if not res.ok:
        return res
    if res.inliers < min_fraction * n_try:
        return ps.fail(
            f"tracking lost: {res.inliers} of {n_try} tie points are inliers "
            f"(need {min_fraction:.0%})"
        )
    pm = res.points[:, 2:]
    # projective parts only
    dev = float(np.max(np.hypot(*(apply_h(res.homography, pm) - apply_h(prior, pm)).T)))
    if not dev < radius + 1:
        return ps.fail(
            f"tracking lost: the model departs {dev:.1f} px from the prior (search radius {radius})"
        )
    res.tracked = True
    return res


def _blank(which: str, gray: np.ndarray) -> str:
    """Return why a frame is blank; a frame scaled to 0..1 (a float image) is named as such."""
    sub = gray[::2, ::2]
    lo, hi, std = float(sub.min()), float(sub.max()), float(sub.std())
    text = f"no texture: the {which} frame is blank (std {std:.3g} < 1 DN)"
    if hi <= 1.0 and std > 0.0:
        text += (
            f"; its values lie within {lo:.3g}..{hi:.3g}: a float image scaled to 1? "
            "frames are read in DN: publish them as 0..255 (or 16-bit)"
        )
    return text
