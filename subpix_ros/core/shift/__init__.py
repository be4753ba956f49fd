"""Sub-pixel shift between two frames (METHODS.md A), at the accuracy limit.

Sign convention (used everywhere in subpix_ros): ``(u, v)`` = (rows, columns) in pixels is
how far the scene content moved from the ``reference`` frame to the ``moving`` frame: a
feature at ``(r, c)`` in the reference appears at ``(r + u, c + v)`` in the moving frame,
i.e. ``moving(x + s) = reference(x) + z`` with ``s = (u, v)`` and ``z`` an intensity offset
(moving minus reference, in the input's digital numbers).

Methods of :func:`estimate_shift`:

``"seed"``
    The published estimator exactly (:mod:`.seed`): one closed-form solve of ``A C = B``;
    :func:`seed_solve` returns the raw ``C``, ``u = -4 c_u``, ``v = -4 c_v``.
``"seed-iterated"``
    The seed re-solved after warping the moving frame by the estimate (OpenCV INTER_CUBIC).
``"default"``
    1. Coarse (:mod:`.coarse`): a pyramid (INTER_AREA halvings while the larger side exceeds
       ``coarse_size``), phase correlation on its coarsest level unless a ``prior`` is given,
       then a few Gauss-Newton iterations on each level of at most 2^18 px.
    2. Fine (:mod:`.gauss_newton`): Gauss-Newton on ``(u, v, z)`` at full resolution with the
       reference-side Jacobian, minimising
       ``sum w ((H_t * M)(x + k) - (H_0 * R)(x) - z)^2`` (``k = floor(s)``, ``t = s - k``),
       ``H_t`` a short separable FIR filter (:func:`fractional_shift_kernel`) whose
       response approximates ``G(w) exp(i w t)``: a Gaussian prefilter ``G`` (both frames
       see the same one) against the aliasing that biases translation estimators, combined
       with an accurate fractional delay. Above ``max_pixels`` only the most textured
       128x128 tiles (spread over a 3x3 grid) enter.
    3. Noise-limited pairs (standard error above 0.005 px), unless ``prefilter_sigma`` is
       given: the prefilter is re-chosen by the smallest variance predicted by
       :func:`predicted_shift_variance`, the tile budget grows 4x, and the fine stage re-runs.
    4. Quality (:mod:`.covariance`): a cluster-robust sandwich covariance over 16x16-pixel
       blocks and a misfit test from local shifts on a 3x3 grid.

:func:`lucas_kanade_batch` (:mod:`.batch`) estimates many small low-passed window pairs at
once (a few Gauss-Newton steps each, with each pair's residual noise variance): the
super-resolution's frame screening, joint noise estimate and tile geometry use it.

Failure: textureless, constant, all-NaN, too small or non-overlapping input gives ``ok=False``
with a ``reason`` and ``u = v = z = None`` (never NaN or a made-up number). Wrong argument
types or shapes raise ``ValueError``. Measured figures and rejected alternatives:
docs/design-notes.md, "Shift estimation".

References
----------
.. [1] S. A. Stankevich, S. V. Shklyar, A. R. Lysenko, "Software module for estimating the
   sub-pixel shift of images acquired from a quadcopter", 2018 (METHODS.md A, the seed).
.. [2] B. D. Lucas and T. Kanade, "An iterative image registration technique with an
   application to stereo vision", Proc. IJCAI, 674-679, 1981.
"""

from .batch import lk_inner_region, lk_window_context, lucas_kanade_batch
from .coarse import coarse_shift
from .estimate import METHODS, estimate_shift
from .prefilter import fractional_shift_kernel, predicted_shift_variance
from .result import ShiftResult
from .seed import seed_solve, seed_system

__all__ = [
    "ShiftResult",
    "estimate_shift",
    "seed_system",
    "seed_solve",
    "fractional_shift_kernel",
    "coarse_shift",
    "predicted_shift_variance",
    "lucas_kanade_batch",
    "lk_window_context",
    "lk_inner_region",
    "METHODS",
]
