"""The result record of the shift estimator."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Optional, Tuple

import numpy as np


@dataclass
class ShiftResult:
    """Outcome of :func:`~subpix_ros.core.shift.estimate_shift`.

    Attributes
    ----------
    ok : bool
        True when a shift was measured.
    reason : str
        Why not, when ``ok`` is False.
    u, v : float or None
        Shift in pixels (rows, columns): scene content moved from the reference to the
        moving frame (sign convention of :mod:`subpix_ros.core.shift`). None when not ``ok``.
    z : float or None
        Intensity offset, moving minus reference (input digital numbers).
    cov : ndarray or None
        2x2 covariance of ``(u, v)`` in px^2 (None if unknown).
    u_std, v_std : float or None
        Square roots of the diagonal of ``cov`` (px).
    cond : float or None
        2-norm condition number of the normal matrix.
    n_pixels : int
        Pixels in the final sums.
    iterations : int
        Fine Gauss-Newton solves.
    converged : bool
        The last update was below the tolerance.
    residual_rms : float or None
        RMS of the final residual (DN).
    misfit : bool
        The translation model does not fit (local shifts across the frame disagree, e.g.
        rotation).
    misfit_px : float or None
        RMS spread of the local shifts about the global one (px).
    warning : str
        A human-readable note on ``misfit``.
    method : str
        The method that gave the result.
    coarse : tuple of float or None
        The coarse stage's ``(u, v)`` (px), when it ran.
    """

    ok: bool
    reason: str = ""
    u: Optional[float] = None
    v: Optional[float] = None
    z: Optional[float] = None
    cov: Optional[np.ndarray] = None
    u_std: Optional[float] = None
    v_std: Optional[float] = None
    cond: Optional[float] = None
    n_pixels: int = 0
    iterations: int = 0
    converged: bool = False
    residual_rms: Optional[float] = None
    misfit: bool = False
    misfit_px: Optional[float] = None
    warning: str = ""
    method: str = "default"
    coarse: Optional[Tuple[float, float]] = None

    @property
    def shift(self) -> Optional[Tuple[float, float]]:
        """``(u, v)`` or None."""
        return None if self.u is None else (self.u, self.v)

    def as_dict(self) -> dict:
        """Return a JSON-ready dict (numpy arrays and scalars converted)."""
        fields = asdict(self)
        fields["cov"] = None if self.cov is None else np.asarray(self.cov, dtype=float).tolist()
        fields["coarse"] = None if self.coarse is None else [float(x) for x in self.coarse]
        for key, val in list(fields.items()):
            if isinstance(val, np.generic):
                fields[key] = val.item()
        return fields


def _fail(reason: str, method: str, **fields) -> ShiftResult:
    """Return a failed result (``ok=False``, ``u = v = z = None``) saying why."""
    return ShiftResult(ok=False, reason=reason, method=method, **fields)
