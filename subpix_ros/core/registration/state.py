"""State of one registration: the validated options, the pass, the seeds of its last stage."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .frames import ReferenceFrame
from .result import RegistrationResult, _fail


@dataclass(frozen=True)
class _Options:
    """The validated options of :func:`.register` (see there)."""

    model: str
    fixed_lam: float | None  # None: lambda estimated per pair; else a fixed camera lambda
    distortion: bool | float
    n_points: int
    coarse_size: int
    detect_size: int
    template_half: int
    inlier_px: float
    min_inliers: int
    min_spread: float
    want_inliers: int
    coarse_method: str
    angles: list[float] | None
    track_radius: int  # validated (an integer in [1, 64]) only when a prior is given
    track_min_fraction: float

    @property
    def affine(self) -> bool:
        """True for the affine model."""
        return self.model == "affine"


@dataclass
class _Pass:
    """One registration of ``mov`` to ``ref``: prepared frames, options, start time."""

    ref: ReferenceFrame
    mov: ReferenceFrame
    opts: _Options
    t0: float

    @property
    def shapes(self) -> tuple:
        """(reference shape, moving shape)."""
        return (self.ref.gray.shape, self.mov.gray.shape)

    def fail(self, reason: str) -> RegistrationResult:
        """Return a failed result saying why."""
        return _fail(reason, self.t0, self.shapes, self.opts.model)


@dataclass
class _Seeds:
    """Where the input-resolution stage starts: tie points and a model at pyramid level ``level``.

    ``pts``: reference tie points (x, y) at that level; ``h``: moving -> reference there;
    ``radius``: NCC search radius (input px) of the points without a match; ``pred``
    (optional, same length as ``pts``): each point's matched moving position at that level
    (NaN where it did not match); ``extra``: further candidates at that level for weak
    texture.
    """

    pts: np.ndarray
    h: np.ndarray
    level: int
    radius: int
    pred: np.ndarray | None = None
    extra: np.ndarray | None = None
