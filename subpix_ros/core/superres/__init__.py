"""Super-resolution reconstruction from sub-pixel shifted frames (METHODS.md B).

Modules, by concern:

* :mod:`.reconstruction`: the entry points :func:`reconstruct` and
  :func:`reconstruct_colour`, input validation and the fallback to bicubic;
* :mod:`.model`: the observation model (eq. 3) as spatial operators and as Fourier transfers;
* :mod:`.paper`: the paper's own solutions (eqs. 4, 6, 7) on the interleaved grid;
* :mod:`.fourier_map`, :mod:`.separable`: the Fourier-domain MAP solve of eq. 9;
* :mod:`.cg_map`: the same objective by conjugate gradients (homographies, masks);
* :mod:`.spectrum`: noise level and image prior fitted to the frames;
* :mod:`.geometry`, :mod:`.lowpass`: shift refinement and the check for more than a
  translation, with the shift package's batched estimator
  (:func:`subpix_ros.core.shift.lucas_kanade_batch`);
* :mod:`.masks`, :mod:`.budget`: border-strip masks on the fast path, and a memory budget;
* :mod:`.luma`: the frames' luminance, and set members packed as their luminance.
"""

from .budget import BudgetPlan, estimate_peak_mb, plan_reconstruction, reconstruct_within_budget
from .geometry import detect_geometry
from .luma import colour_luminance, pack_luminance
from .masks import bicubic_outside, reconstruct_aligned
from .model import FrameOperator, frame_transfer_1d, gaussian_kernel, translation_homography
from .paper import grid_offsets, interleave, pinv_solution, windowed_solution
from .reconstruction import (  # noqa: F401  (_reconstruct: the stages read its options)
    _reconstruct,
    reconstruct,
    reconstruct_colour,
)
from .result import BLUR_AUTO, MAX_FACTOR, METHODS, SRResult, bicubic_upscale, psnr
from .spectrum import estimate_noise_sigma, fit_rolloff_spectrum, fit_spectrum

__all__ = [
    "BLUR_AUTO",
    "BudgetPlan",
    "FrameOperator",
    "MAX_FACTOR",
    "METHODS",
    "SRResult",
    "bicubic_outside",
    "bicubic_upscale",
    "detect_geometry",
    "estimate_noise_sigma",
    "estimate_peak_mb",
    "fit_rolloff_spectrum",
    "fit_spectrum",
    "frame_transfer_1d",
    "gaussian_kernel",
    "grid_offsets",
    "interleave",
    "pinv_solution",
    "plan_reconstruction",
    "psnr",
    "reconstruct",
    "reconstruct_aligned",
    "reconstruct_colour",
    "colour_luminance",
    "pack_luminance",
    "reconstruct_within_budget",
    "translation_homography",
    "windowed_solution",
]
