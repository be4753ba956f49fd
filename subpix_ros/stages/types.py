"""What the stages hand each other: frames, aligned frames, shifts, super-resolved images.

The same objects pass between the stages of :class:`~subpix_ros.stages.Pipeline`,
between the nodes of the single-process ``pipeline``, and (converted by
``subpix_ros.nodes.payloads``) travel as the documented ROS messages between
processes.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from subpix_ros.core.validity import box_mask


@dataclass
class Frame:
    """One camera frame: pixels as received (mono HxW or BGR HxWx3)."""

    stamp_ns: int
    image: np.ndarray
    frame_id: str = ""
    received: float = field(default_factory=time.monotonic)

    @property
    def stamp_s(self) -> float:
        """The stamp in seconds."""
        return self.stamp_ns * 1e-9


@dataclass
class Aligned:
    """A frame brought onto its reference frame's grid to pixel accuracy.

    ``mask`` is True where the pixel came from the moving frame, or None when
    those pixels are the rectangle ``box`` ``(r0, r1, c0, c1)`` (an integer
    crop: 2 MB less per 1080p frame held; :meth:`valid_mask` makes the mask
    when asked); ``reference`` the frame it is aligned to; ``homography`` maps
    the original moving frame's pixel coordinates (x = column, y = row) to the
    reference's; ``prior`` the sub-pixel (u, v) the homography predicts is
    left in. ``packed``: ``image`` is no longer the BGR frame but its luminance packed
    by :func:`~subpix_ros.core.superres.luma.pack_luminance` (a member held by the
    reconstruction: HxW, uint16 for uint8 BGR, float32 for uint16 BGR).
    """

    stamp_ns: int
    image: np.ndarray
    mask: np.ndarray | None
    reference: Frame
    homography: np.ndarray
    prior: tuple[float, float] | None = None
    frame_id: str = ""
    received: float = field(default_factory=time.monotonic)
    box: tuple[int, int, int, int] | None = None
    packed: bool = False  # image is the frame's luminance packed (core.superres.luma)

    def __post_init__(self) -> None:
        if self.mask is None and self.box is None:
            raise ValueError("an aligned frame needs a mask or a box")

    def valid_mask(self) -> np.ndarray:
        """Return the validity mask (made from ``box`` when no mask is held)."""
        if self.mask is not None:
            return self.mask
        return box_mask(self.image.shape[:2], self.box)


@dataclass
class Shift:
    """Sub-pixel shift of an aligned frame against its reference (project convention).

    Content at (r, c) in the reference appears at (r + u, c + v) in the
    aligned frame; ``z`` is the intensity offset.
    """

    stamp_ns: int
    reference_stamp_ns: int
    u: float
    v: float
    z: float
    u_std: float
    v_std: float
    frame_id: str = ""
    received: float = field(default_factory=time.monotonic)


@dataclass
class NewReference:
    """Registration started a new reference set with ``frame`` (``reason``: why)."""

    frame: Frame
    reason: str
    predicted: bool = False  # started from the predicted overlap, without a registration attempt

    @property
    def stamp_ns(self) -> int:
        """The stamp of the new reference frame, ns."""
        return self.frame.stamp_ns


@dataclass
class Skipped:
    """An input a stage did not use: ``reason`` is a short key, ``detail`` the full text."""

    stamp_ns: int
    reason: str
    detail: str = ""


@dataclass
class SuperResolved:
    """One super-resolved image and what it was made from.

    ``image`` is ``factor`` x the reference's size, of the input's type
    (uint16 for uint16 input, else uint8); ``bicubic`` the reference
    upsampled bicubically to the same size (computed on first access);
    ``shifts`` the shifts of the members besides the reference (their frames are
    released once the set is solved: nothing downstream reads them).
    Output pixel grid: low-resolution pixel i of the reference covers output
    pixels factor*i .. factor*i + factor - 1.
    """

    image: np.ndarray
    reference: Frame
    shifts: list[Shift]
    method: str
    fell_back: bool
    reason: str
    factor: int
    blur_sigma: float | None = None
    blur_source: str | None = None
    time_s: float = 0.0
    complete: bool = True  # False: an incomplete set (flushed or cut short by the next reference)
    noise_sigma: float = float("nan")
    result: Any = None  # the core's SRResult
    _bicubic: np.ndarray | None = field(default=None, repr=False)

    @property
    def stamp_ns(self) -> int:
        """The stamp of the reference frame, ns."""
        return self.reference.stamp_ns

    @property
    def n_frames(self) -> int:
        """Frames the image was made from, the reference included."""
        return 1 + len(self.shifts)

    @property
    def bicubic(self) -> np.ndarray:
        """The reference upsampled bicubically to the image's size and type (made on first use)."""
        if self._bicubic is None:
            self._bicubic = bicubic_upscale(self.reference.image, self.factor, self.image.dtype)
        return self._bicubic


def bicubic_upscale(image: np.ndarray, factor: int, dtype: Any, rows: int = 64) -> np.ndarray:
    """Return ``image`` upsampled ``factor`` x by bicubic interpolation, rounded to ``dtype``.

    On the super-resolved images' output grid (input pixel i covers output pixels
    ``factor*i .. factor*i + factor - 1``), as :attr:`SuperResolved.bicubic`
    (:func:`~subpix_ros.core.superres.result.bicubic_integer`).
    """
    from subpix_ros.core.superres.result import bicubic_integer

    return bicubic_integer(image, factor, dtype, rows)
