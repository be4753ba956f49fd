"""Checks on decoded frames: finite samples, a stream's frame format changing."""

from __future__ import annotations

from typing import Any

import numpy as np

from .encodings import ImageConversionError


def finite_fraction(image: np.ndarray) -> float:
    """Fraction (0..1) of samples that are finite (not NaN/Inf); 1.0 for integer images."""
    a = np.asarray(image)
    if a.size == 0:
        raise ImageConversionError("finite_fraction of an empty image")
    if not np.issubdtype(a.dtype, np.floating):
        return 1.0
    return float(np.count_nonzero(np.isfinite(a))) / a.size


def require_finite(image: np.ndarray, min_fraction: float = 1.0, what: str = "image") -> np.ndarray:
    """Return ``image`` if at least ``min_fraction`` of its samples are finite, else raise.

    Callers use it to reject float (e.g. 32FC1) frames with NaN/Inf before
    numerical work; the error names the measured fraction.
    """
    if not 0.0 <= min_fraction <= 1.0:
        raise ValueError(f"min_fraction must be in [0, 1], got {min_fraction}")
    frac = finite_fraction(image)
    if frac < min_fraction:
        raise ImageConversionError(
            f"{what} has non-finite samples (NaN/Inf): {100.0 * frac:.3f}% finite, need >= {100.0 * min_fraction:.3f}%"
        )
    return image


class FrameFormatTracker:
    """Notices when the size or encoding of a stream's frames changes mid-stream.

    ``update(height, width, encoding)`` returns ``None`` for the first frame and
    for frames in the current format, and a one-line description
    (``"frame format changed mid-stream: 1920x1080 bgr8 -> 1280x720 bgr8"``)
    when it changes; the new format then becomes current and ``changes``
    counts the switches. Callers decide what to do (typically: log it and
    reset state that depends on the frame size, e.g. the previous frame).
    """

    def __init__(self) -> None:
        self.current: tuple[int, int, str] | None = None
        self.changes = 0

    def update(self, height: int, width: int, encoding: str) -> str | None:
        """Record the format of the next frame; return a description if it changed, else None."""
        fmt = (int(height), int(width), str(encoding))
        if self.current is None or fmt == self.current:
            self.current = fmt
            return None
        old, self.current = self.current, fmt
        self.changes += 1
        return (
            f"frame format changed mid-stream: {old[1]}x{old[0]} {old[2]} -> {fmt[1]}x{fmt[0]} {fmt[2]} "
            f"(width x height)"
        )

    def update_from(self, msg: Any) -> str | None:
        """:meth:`update` with the fields of an Image message."""
        return self.update(msg.height, msg.width, msg.encoding)
