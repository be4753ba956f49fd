"""Scoring a flight of the independent degradation model: estimated shifts, gain over bicubic.

Shared by ``bench_superres_blind.py`` and the tests that use ``degrade_independent.py``
(kept apart from that module, which must not depend on the package's own code).
"""

from __future__ import annotations

import numpy as np

from subpix_ros.core.shift import estimate_shift
from subpix_ros.core.superres import bicubic_upscale, psnr


def gain(flight, image: np.ndarray) -> float:
    """Return the PSNR gain (dB) of ``image`` over bicubic of frame 0 (interior: 4 factor px cut)."""
    b = 4 * flight.factor
    bicubic = bicubic_upscale(flight.frames[0], flight.factor)
    return psnr(image, flight.truth, b) - psnr(bicubic, flight.truth, b)


def est_shifts(frames) -> np.ndarray:
    """Return (N, 2) shifts of every frame against frame 0 (``estimate_shift``; NaN if it failed)."""
    out = []
    for f in frames:
        r = estimate_shift(frames[0], f)
        out.append((r.u, r.v) if r.ok else (np.nan, np.nan))
    return np.array(out)
