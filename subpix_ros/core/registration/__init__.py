"""Automatic co-registration of two overlapping frames (METHODS.md C, and A's pre-registration).

Pipeline (all stages vectorised over pixels / points):

1. Coarse overlap on a low pyramid level (:mod:`.coarse`, METHODS C stage 1): ORB features +
   MAGSAC similarity by default (``coarse_method="orb"``), the paper's gradient-magnitude
   fragment search with the reverse-search consistency check (under rotation hypotheses from
   the gradient-orientation histograms) as ``coarse_method="fragments"`` and as a fallback.
2. Pyramid refinement (:mod:`.register`): at every level down to the detection level, Harris
   tie points (:mod:`.harris`, METHODS C stage 2, with a grid quota over the overlap) are
   matched by NCC around the current prediction (:mod:`.points`) and a homography is fitted
   robustly (OpenCV USAC/MAGSAC, :mod:`.robust`).
3. Input resolution (:mod:`.passes`): the detection-level matches, scaled up, start the
   Gauss-Newton sub-pixel refinement; outliers are rejected by MAGSAC, the projective model
   (METHODS C, eq. P; :mod:`.fit`) is fitted by Levenberg-Marquardt from the identity (the
   paper), then refitted on the inliers, optionally jointly with one radial-distortion term
   (division model, shared by both frames). A second pass searches the points the first one
   missed around this model's prediction, and the model is refitted.

Tracking (``prior=``, video rate against a fixed reference): stages 1-2 are replaced by one
NCC search at the detection level around the prior's prediction; stage 3 is unchanged;
failure falls back to the full pipeline. :func:`prepare_reference` keeps the reference's
luminance, pyramid, Harris maxima and coarse features for reuse across frames.

Deviations from the paper (measured in benchmarks/bench_registration.py; docs/design-notes.md,
"Registration"): ORB before the fragment search (camera yaw between frames), MAGSAC before
the LM fit (the paper has no outlier rejection), the optional radial term (``distortion``).

Conventions: pixel coordinates are ``(x, y) = (column, row)``, pixel centres at integers.
``homography`` (3x3 float64) maps MOVING pixel coordinates to REFERENCE pixel coordinates,
``[x_r, y_r, 1]^T ~ H [x_m, y_m, 1]^T``; with a radial term the full model is
``D(H_u(U(x)))`` (:meth:`RegistrationResult.transfer`). Shifts handed to the shift estimator
are ``(u, v)`` = (rows, cols) in px: content at (r, c) in the reference appears at
(r + u, c + v) in the other frame.

References
----------
.. [1] Ryzhikov, Kuznetsov, "Operational forming of overview images from aerial photography"
   (docs/METHODS.md C, the seed).
.. [2] C. Harris and M. Stephens, "A combined corner and edge detector", Proc. Alvey Vision
   Conference, 147-151, 1988. https://doi.org/10.5244/C.2.23
.. [3] D. Barath, J. Noskova, M. Ivashechkin and J. Matas, "MAGSAC++, a fast, reliable and
   accurate robust estimator", Proc. CVPR, 1304-1312, 2020.
   https://doi.org/10.1109/CVPR42600.2020.00138
.. [4] A. W. Fitzgibbon, "Simultaneous linear estimation of multiple view geometry and lens
   distortion", Proc. CVPR, I-125-I-132, 2001. https://doi.org/10.1109/CVPR.2001.990465
"""

from .align import AlignResult, align
from .coarse import CoarseResult, coarse_orb, coarse_overlap, orb_features
from .fit import (
    Normaliser,
    check_homography,
    distort_points,
    fit_homography_distortion_lm,
    fit_homography_lm,
    undistort_points,
)
from .frames import ReferenceFrame, prepare_reference, to_gray32
from .geometry import apply_h, centre_shift, overlap_fraction
from .harris import harris_peaks, harris_points, harris_response, select_spread
from .points import ncc_match, refine_gauss_newton, sample_bicubic, sample_linear_cv
from .register import register
from .result import RegistrationResult
from .robust import calibrate_distortion

__all__ = [
    "RegistrationResult",
    "AlignResult",
    "ReferenceFrame",
    "prepare_reference",
    "register",
    "align",
    "calibrate_distortion",
    "to_gray32",
    "overlap_fraction",
    "apply_h",
    "centre_shift",
    "Normaliser",
    "distort_points",
    "undistort_points",
    "fit_homography_lm",
    "fit_homography_distortion_lm",
    "check_homography",
    "CoarseResult",
    "coarse_orb",
    "coarse_overlap",
    "orb_features",
    "harris_response",
    "harris_peaks",
    "harris_points",
    "select_spread",
    "ncc_match",
    "refine_gauss_newton",
    "sample_bicubic",
    "sample_linear_cv",
]
