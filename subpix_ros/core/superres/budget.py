"""Super-resolution within a memory budget: fewer frames per set, or tiles with overlap.

The Fourier-domain MAP reconstruction (:func:`subpix_ros.core.superres.reconstruct`)
holds every frame of a set at once, in float64 and as single-precision
spectra, and its working memory grows with the number of frames ``N`` and the
frame area ``H W``. :func:`plan_reconstruction` predicts that working memory
with :func:`estimate_peak_mb` and, when it exceeds ``max_memory_mb``, plans a
reconstruction that fits:

1. tiles first: the common valid rectangle of the set is cut into a grid of
   tiles, each reconstructed with ``overlap`` extra LR px of context on every
   inner side (the context is discarded), so only one tile's working memory
   is alive at a time besides the stitched output; all frames still
   contribute, so the resolution gain is kept;
2. then fewer frames: once the tiles are at their minimum side
   (``min_tile`` LR px without the overlap), the set is cut to its first
   ``n`` frames (the reference is always frame 0), down to ``min_frames``;
3. if even that does not fit, the reference is bicubic-upscaled (the output
   image alone is what is left) and the result says why.

:func:`reconstruct_within_budget` runs the plan through
:func:`subpix_ros.core.superres.reconstruct_aligned` and returns the
result together with the plan, whose ``reductions`` say what was given up.

Notes
-----
Memory model (working memory beyond the input frames, bytes, fitted with
``tracemalloc`` on 1080p and 540x960 colour and mono sets of 4, 8 and 16 frames,
factors 2 to 4, and rounded up so that every measured case lies below it;
figures in docs/design-notes.md, "Onboard budget")::

    M(N, H, W, p) = H W (7 N + c(p, colour)) + 28 MB

with ``c = 165, 345, 660`` B per LR px for colour at p = 2, 3, 4 and
``70, 120, 255`` for mono (refitted when the frames stopped being held as one float64
stack: 10 % above every measured case). A tile reconstruction costs ``M`` of its extent
(tile plus overlap) plus the stitched output, ``H W p^2 C`` values: float32, or the
integer type each tile is rounded into as it is placed (``out_dtype``).
OpenCV-internal scratch (not traced) comes on top, a few frame-sized buffers.

Tiles differ from the whole-set reconstruction only where the per-set
estimates differ: the spectrum prior is fitted per tile (on its central
crop); the noise level is estimated on the first (central) tile and passed
to the others so that the tiles agree. Within a tile the solution is the same
eq. 9 solve; the tile borders use the reconstruction's consistent padding,
whose effect fades within ``overlap`` px.

References
----------
.. [1] docs/METHODS.md, B (super-resolution, the MAP estimate of eq. 9).
.. [2] docs/design-notes.md, "Onboard budget" (the measured memory model).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Sequence

import cv2
import numpy as np

from ..validity import common_region
from .masks import bicubic_outside, reconstruct_aligned
from .result import (
    NonFiniteImageError,
    SRResult,
    bicubic_integer,
    bicubic_upscale,
    to_integer_image,
)

__all__ = ["BudgetPlan", "estimate_peak_mb", "plan_reconstruction", "reconstruct_within_budget"]

#: B per LR px of the set's frame-independent working memory, (factor, colour) -> bytes.
_FIXED_B = {
    (2, True): 165,
    (3, True): 345,
    (4, True): 660,
    (2, False): 70,
    (3, False): 120,
    (4, False): 255,
}
_PER_FRAME_B = 7  # B per LR px per frame
_BASE_MB = 28.0  # fixed overheads (caches, small arrays)


def estimate_peak_mb(n_frames: int, shape: tuple[int, int], factor: int, colour: bool) -> float:
    """Predict the working memory of one MAP reconstruction (MB, 1e6 B).

    Parameters
    ----------
    n_frames : int
        Frames in the set, the reference included.
    shape : (int, int)
        LR rows and columns reconstructed (the whole frame, or a tile with its overlap).
    factor : int
        Resolution factor, 2 to 4.
    colour : bool
        BGR frames (luminance reconstructed, chroma upscaled) rather than mono.

    Returns
    -------
    float
        ``M = H W (7 N + c(p, colour)) / 1e6 + 28`` (see the module notes).
    """
    p = int(min(max(factor, 2), 4))
    hw = float(shape[0]) * float(shape[1])
    return hw * (_PER_FRAME_B * n_frames + _FIXED_B[(p, bool(colour))]) / 1e6 + _BASE_MB


def _output_mb(shape: tuple[int, int], factor: int, colour: bool, out_bytes: int = 4) -> float:
    """Return the size of the stitched HR output of a tiled reconstruction, MB.

    ``out_bytes`` per value: 4 for the float32 image, 1 or 2 when each tile is rounded into
    uint8 or uint16 as it is placed (``out_dtype``).
    """
    return float(shape[0]) * shape[1] * factor * factor * (3 if colour else 1) * out_bytes / 1e6


@dataclass
class BudgetPlan:
    """How a set is reconstructed within ``max_memory_mb`` (see :func:`plan_reconstruction`).

    Attributes
    ----------
    n_frames : int
        Frames used (the first ones of the set).
    grid : (int, int)
        Tiles along rows and columns ((1, 1): the whole frame at once).
    overlap : int
        Context LR px on each inner side of a tile.
    estimate_mb : float
        Predicted working memory of the plan.
    unbounded_mb : float
        Predicted working memory of the whole set at once.
    max_memory_mb : float or None
        The budget.
    bicubic : bool
        Nothing fits: the reference is upscaled.
    reductions : list of str
        What was given up, in words (empty: nothing).
    """

    n_frames: int
    grid: tuple[int, int] = (1, 1)
    overlap: int = 0
    estimate_mb: float = 0.0
    unbounded_mb: float = 0.0
    max_memory_mb: float | None = None
    bicubic: bool = False
    reductions: list[str] = field(default_factory=list)

    @property
    def reduced(self) -> bool:
        """Whether the plan gives anything up."""
        return bool(self.reductions)

    def as_dict(self) -> dict:
        """Return the plan as a JSON-friendly dict (memory figures rounded to 0.1 MB)."""
        return {
            "n_frames": self.n_frames,
            "grid": list(self.grid),
            "overlap": self.overlap,
            "estimate_mb": round(self.estimate_mb, 1),
            "unbounded_mb": round(self.unbounded_mb, 1),
            "max_memory_mb": self.max_memory_mb,
            "bicubic": self.bicubic,
            "reductions": list(self.reductions),
        }


def _tiled_mb(
    n: int,
    shape: tuple[int, int],
    grid: tuple[int, int],
    overlap: int,
    factor: int,
    colour: bool,
    out_bytes: int = 4,
) -> float:
    """Predict a tiled plan's working memory: the largest tile with its overlap, plus the output."""
    th = -(-shape[0] // grid[0]) + (2 * overlap if grid[0] > 1 else 0)
    tw = -(-shape[1] // grid[1]) + (2 * overlap if grid[1] > 1 else 0)
    tile = estimate_peak_mb(n, (min(th, shape[0]), min(tw, shape[1])), factor, colour)
    return tile + _output_mb(shape, factor, colour, out_bytes)


def plan_reconstruction(
    n_frames: int,
    shape: tuple[int, int],
    factor: int,
    max_memory_mb: float | None,
    *,
    colour: bool = True,
    min_frames: int = 2,
    overlap: int = 32,
    min_tile: int = 128,
    out_bytes: int = 4,
) -> BudgetPlan:
    """Plan a reconstruction of ``n_frames`` frames of ``shape`` within ``max_memory_mb``.

    Parameters
    ----------
    n_frames : int
        Frames in the set (reference included), >= 2.
    shape : (int, int)
        LR size of the region reconstructed by the MAP solver.
    factor : int
        Resolution factor.
    max_memory_mb : float or None
        Budget for the working memory (MB, 1e6 B); None or <= 0: unbounded.
    colour : bool
        BGR rather than mono frames.
    min_frames : int
        Fewest frames a reduced set may keep (>= 2).
    overlap : int
        Context LR px around each tile (on inner sides).
    min_tile : int
        Smallest tile side (LR px, without the overlap) before frames are dropped.
    out_bytes : int
        Bytes per value of the stitched output: 4 (float32, the default), or 1 / 2 when
        the tiles are rounded into uint8 / uint16 as they are placed.

    Returns
    -------
    BudgetPlan
        Tiles are preferred to dropping frames (they keep every frame's information);
        the grid with the fewest tiles that fits, nearly square tiles first.

    Notes
    -----
    A plan is accepted when its :func:`estimate_peak_mb` is at most ``max_memory_mb``.
    """
    if n_frames < 2:
        raise ValueError(f"n_frames must be >= 2, got {n_frames}")
    h, w = int(shape[0]), int(shape[1])
    unbounded = estimate_peak_mb(n_frames, (h, w), factor, colour)
    plan = BudgetPlan(n_frames, (1, 1), 0, unbounded, unbounded, max_memory_mb)
    if max_memory_mb is None or max_memory_mb <= 0 or unbounded <= max_memory_mb:
        return plan
    min_frames = int(min(max(2, min_frames), n_frames))
    grids = _tile_grids(h, w, min_tile)
    for n in range(n_frames, min_frames - 1, -1):  # all frames first, then fewer
        whole = estimate_peak_mb(n, (h, w), factor, colour)
        options = [((1, 1), whole)] + [
            (g, _tiled_mb(n, (h, w), g, overlap, factor, colour, out_bytes)) for g in grids
        ]
        for g, mb in options:
            if mb <= max_memory_mb:
                red = []
                if n < n_frames:
                    red.append(f"{n} of {n_frames} frames")
                if g != (1, 1):
                    red.append(f"{g[0]}x{g[1]} tiles with {overlap} px overlap")
                return BudgetPlan(
                    n, g, overlap if g != (1, 1) else 0, mb, unbounded, max_memory_mb, False, red
                )
    mb = _output_mb((h, w), factor, colour, out_bytes)
    return BudgetPlan(
        1,
        (1, 1),
        0,
        mb,
        unbounded,
        max_memory_mb,
        True,
        [
            f"bicubic upscale of the reference: no plan with >= {min_frames} frames and "
            f"{min_tile} px tiles fits {max_memory_mb:g} MB"
        ],
    )


def _tile_grids(h: int, w: int, min_tile: int) -> list[tuple[int, int]]:
    """Return the grids other than (1, 1) with tiles >= ``min_tile``: fewest, squarest first."""
    max_r, max_c = max(1, h // min_tile), max(1, w // min_tile)
    return sorted(
        ((r, c) for r in range(1, max_r + 1) for c in range(1, max_c + 1) if (r, c) != (1, 1)),
        key=lambda g: (g[0] * g[1], abs(h / g[0] - w / g[1])),
    )


def _spans(n: int, parts: int) -> list[tuple[int, int]]:
    """Return ``parts`` contiguous spans covering 0..n (sizes differ by at most one)."""
    edges = np.linspace(0, n, parts + 1).round().astype(int)
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]


def reconstruct_within_budget(
    frames: Sequence[np.ndarray],
    shifts: np.ndarray,
    factor: int,
    masks: Sequence[np.ndarray] | None = None,
    *,
    boxes: Sequence[tuple[int, int, int, int]] | None = None,
    max_memory_mb: float | None = None,
    min_frames: int = 2,
    overlap: int = 32,
    min_tile: int = 128,
    out_dtype=None,
    **kw,
) -> tuple[SRResult, BudgetPlan]:
    """Reconstruct with ``reconstruct_aligned``, planned to fit a memory budget.

    Parameters
    ----------
    frames, shifts, factor, masks
        As :func:`~subpix_ros.core.superres.reconstruct_aligned` (frame 0 is the reference;
        ``shifts`` (N, 2) ``(u, v)`` LR px: content at (r, c) in frame 0 is at
        (r + u, c + v) in frame n).
    boxes : sequence of (int, int, int, int), optional
        Instead of ``masks``, when each frame's valid pixels are a rectangle
        ``(r0, r1, c0, c1)`` (frames aligned by integer crops): the same result, without
        frame-sized masks; as :func:`~subpix_ros.core.superres.reconstruct_aligned`.
    max_memory_mb : float or None
        Working-memory budget (MB); None or <= 0: unbounded (the plain reconstruction).
    min_frames, overlap, min_tile
        As :func:`plan_reconstruction`.
    out_dtype : numpy dtype, optional
        ``numpy.uint8`` or ``numpy.uint16``: the image is returned rounded and clipped to it
        (:func:`~subpix_ros.core.superres.result.to_integer_image`, as a node publishes it);
        tiles are converted as they are placed, so a tiled set's float image never exists
        whole. Default None: the float image.
    **kw
        Passed to the reconstruction (method, geometry, refine_shifts, noise_sigma, ...).

    Returns
    -------
    result : SRResult
        On the usual output grid (LR pixel i of frame 0 covers output pixels
        ``factor i .. factor i + factor - 1``). A tiled result reports the first tile's
        weights, shifts and noise level, and ``fell_back`` with the reason if any tile fell
        back to bicubic.
    plan : BudgetPlan
        The plan it followed.

    Raises
    ------
    NonFiniteImageError
        With ``out_dtype``, if the reconstruction has a NaN or infinite pixel (nothing is
        rounded into an image then).

    Notes
    -----
    Tiles are cut from the rectangle valid in every frame (the whole frame without masks);
    outside it the output is the bicubic upscale of the reference, as in
    ``reconstruct_aligned``. Masks that are not a rectangle cannot be tiled (the masked CG
    solver); such a set is only reduced in frames.
    """
    if frames is None or len(frames) < 2:
        raise ValueError("need at least 2 frames")
    ref = np.asarray(frames[0])
    colour = ref.ndim == 3
    h, w = ref.shape[:2]
    box = common_region((h, w), masks, boxes)
    region = (h, w) if box is None else (box[1] - box[0], box[3] - box[2])
    plan = plan_reconstruction(
        len(frames),
        region,
        factor,
        max_memory_mb,
        colour=colour,
        min_frames=min_frames,
        overlap=overlap,
        min_tile=min_tile if box is not None else max(h, w) + 1,
        out_bytes=4 if out_dtype is None else np.dtype(out_dtype).itemsize,
    )
    if plan.bicubic:
        res = _bicubic_result(ref, len(frames), shifts, factor, plan, out_dtype)
        return _as_dtype(res, out_dtype), plan
    n = plan.n_frames
    frames_n = list(frames[:n])
    shifts_n = np.asarray(shifts, dtype=np.float64)[:n]
    masks_n = None if masks is None else list(masks[:n])
    boxes_n = None if boxes is None else list(boxes[:n])
    if plan.grid == (1, 1):
        res = reconstruct_aligned(
            frames_n, shifts_n, factor, masks=masks_n, boxes=boxes_n, out_dtype=out_dtype, **kw
        )
        return _as_dtype(res, out_dtype), plan
    return _reconstruct_tiles(
        frames_n, shifts_n, factor, box, plan, out_dtype=out_dtype, **kw
    ), plan


def _finite_integer(img: np.ndarray, dtype) -> np.ndarray:
    """Round ``img`` into ``dtype``; NonFiniteImageError if a pixel is NaN or infinite."""
    if not np.isfinite(img).all():
        raise NonFiniteImageError("reconstruction produced non-finite pixels")
    return to_integer_image(img, dtype)


def _as_dtype(res: SRResult, dtype) -> SRResult:
    """Return ``res`` with its image rounded into ``dtype`` (unchanged for None)."""
    if dtype is None or res.image.dtype == np.dtype(dtype):
        return res
    res.image = _finite_integer(res.image, dtype)
    return res


def _bicubic_result(
    ref: np.ndarray, n: int, shifts: np.ndarray, factor: int, plan: BudgetPlan, out_dtype=None
) -> SRResult:
    """Return the bicubic upscale of the reference as the result of a plan that fits nothing.

    With an integer ``out_dtype`` it is made in bands straight into that type (the float
    image never whole: the plan has no room for it).
    """
    h, w = ref.shape[:2]
    if out_dtype is not None and np.issubdtype(np.dtype(out_dtype), np.integer):
        up = bicubic_integer(ref, factor, out_dtype)
    elif ref.ndim != 3:
        up = bicubic_upscale(ref, factor)
    else:  # float32, as the colour reconstruction returns (half the memory of float64)
        up = cv2.resize(
            ref.astype(np.float32), (w * factor, h * factor), interpolation=cv2.INTER_CUBIC
        )
    return SRResult(
        up,
        "bicubic",
        True,
        plan.reductions[0],
        weights=np.r_[1.0, np.zeros(n - 1)],
        shifts=np.asarray(shifts, float),
        shift_sigma=np.zeros(n),
        factor=factor,
    )


def _reconstruct_tiles(
    frames: list[np.ndarray],
    shifts: np.ndarray,
    factor: int,
    box: tuple[int, int, int, int],
    plan: BudgetPlan,
    out_dtype=None,
    **kw,
) -> SRResult:
    """Reconstruct the box tile by tile with ``plan.overlap`` px of context; stitch the tiles.

    The central tile goes first: its noise estimate (and the shifts it used where it
    disputed the given ones) is passed to the others, so the tiles agree. Outside the box
    the output is the bicubic upscale of the reference.
    """
    ref = np.asarray(frames[0])
    colour = ref.ndim == 3
    h, w = ref.shape[:2]
    r0, r1, c0, c1 = box
    p, overlap = factor, plan.overlap
    rows, cols = _spans(r1 - r0, plan.grid[0]), _spans(c1 - c0, plan.grid[1])
    order = sorted(
        ((i, j) for i in range(len(rows)) for j in range(len(cols))),
        key=lambda t: abs(t[0] - (len(rows) - 1) / 2) + abs(t[1] - (len(cols) - 1) / 2),
    )
    out = None
    first: SRResult | None = None
    fell = []
    for i, j in order:
        a0, a1 = rows[i][0] + r0, rows[i][1] + r0  # tile, LR px of the frame
        b0, b1 = cols[j][0] + c0, cols[j][1] + c0
        e0, e1 = max(r0, a0 - overlap), min(r1, a1 + overlap)  # with its context, inside the box
        f0, f1 = max(c0, b0 - overlap), min(c1, b1 + overlap)
        tkw = dict(kw)
        if first is not None and tkw.get("noise_sigma") is None and np.isfinite(first.noise_sigma):
            tkw["noise_sigma"] = float(first.noise_sigma)
        # each tile rounded into out_dtype by the core as it assembles it (band by band: no
        # float colour tile), the values the whole float image would hold
        res = reconstruct_aligned(
            [np.asarray(f)[e0:e1, f0:f1] for f in frames],
            shifts,
            factor,
            out_dtype=out_dtype,
            **tkw,
        )
        if out is None:
            out = np.empty((p * h, p * w) + res.image.shape[2:], res.image.dtype)
        out[p * a0 : p * a1, p * b0 : p * b1] = res.image[
            p * (a0 - e0) : p * (a1 - e0), p * (b0 - f0) : p * (b1 - f0)
        ]
        if res.fell_back:
            fell.append(f"tile ({i}, {j}): {res.reason}")
        if first is None and res.shifts_disputed and np.shape(res.shifts) == np.shape(shifts):
            shifts = np.asarray(shifts, dtype=np.float64)[0] + res.shifts  # the tile's, for all
        if first is None:
            first = replace(res, image=np.empty(0, np.float32))  # its figures, not its pixels
        del res
    if (r0, r1, c0, c1) != (0, h, 0, w):
        convert = None
        if out_dtype is not None:  # strips rounded as the float image would hold them
            float_dtype = np.float32 if colour else np.float64

            def convert(vals: np.ndarray) -> np.ndarray:
                return to_integer_image(vals.astype(float_dtype, copy=False), out_dtype)

        bicubic_outside(out, ref, p, box, convert)
    reason = "; ".join(fell) if fell else first.reason
    return replace(first, image=out, fell_back=bool(fell) or first.fell_back, reason=reason)
