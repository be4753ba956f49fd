"""Incremental overview mosaic with bounded memory (METHODS.md C).

Modules: :mod:`.geometry` (the pair model and each frame's drawing geometry,
eq. 3) and :mod:`.builder` (the :class:`Mosaic`: registration chain, canvas,
drawing, drift report).

Each new frame ``k`` is registered to the previous accepted frame
(:func:`subpix_ros.core.registration.register`), giving ``H_k`` (frame k px
-> frame k-1 px, METHODS C eq. P).

Transition h(y) (METHODS C, eq. 3). The paper draws frame k with

    F(x) = h(y) H_k(x) + (1 - h(y)) x,
    h(y) = 1 for y < H_k,  0 for y > H_(k+1),  1 - (y - H_k) / (H_(k+1) - H_k) between,

so the frame follows its predecessor's geometry where it overlaps it
(``h = 1``) and keeps its OWN geometry where the next frame will overlap it
(``h = 0``); the next frame's ``H_(k+1)``, measured against the frame's own
pixels, then applies there unchanged and perspective never accumulates
along the chain. Here, with a drone that yaws between frames, "y" is the
coordinate along the flight direction in frame k's pixels, and "own
geometry" is the frame placed by a similarity:

    D_k(x) = P_(k-1)( h(t) H_k(x) + (1 - h(t)) A_k(x) ),   P_k = P_(k-1) A_k   (eq. 3, generalised)

``A_k`` is the least-squares similarity (rotation, scale, translation)
closest to ``H_k`` over the frame, ``P_k`` the frame's placement (frame px
-> mosaic px, the first frame's pixels), ``t = (x - c_k) . d`` with ``d``
the unit flight direction in frame k (from the previous frame's centre,
mapped into frame k, to frame k's centre ``c_k``) and ``a`` the advance
(px). h is 1 for ``t <= t1``, 0 for ``t >= t2``, linear between, with

* ``t2 = t_min + a``: where the next frame's trailing edge will be, if it
  advances as this one did (a live mosaic does not know frame k+1 yet: the
  paper's ``H_(k+1)`` is predicted from steady flight);
* ``t1 = min(end of the overlap with frame k-1, t2 - (t2 - t_min)/2)``: the
  paper's ``H_k``; when the overlaps exceed 50 % (the paper assumed at most
  50 %) the transition band is kept at least half as wide as the part of the
  frame that stays visible, so the frame bends gently.

Where frame k overlaps frame k-1's own-geometry region, ``D_(k-1) =
P_(k-1)`` and ``D_k = P_(k-1) H_k``: the two agree at the seam up to the
registration residual.

Drawing: newest frame on top; ``D_k`` is inverted per canvas pixel by a
fixed-point iteration on a coarse grid (every 8 canvas px, bilinear in
between) and the frame resampled with ``cv2.remap``; across its border the
frame's weight ramps linearly from 0 to 1 over ``blend_px`` canvas px.

Bounded memory: the canvas never exceeds ``max_size_px`` on either side.
When the flight leaves it, the canvas grows (padding) up to that size, and
beyond it the whole canvas is downscaled by the needed factor (the scale,
and so the metres/pixel, coarsens) -- never a full-resolution canvas that
grows without bound. Per frame only its geometry (a few 3x3 matrices) is
kept.

Drift report: ``seam_residual_px`` is the RMS disagreement
``|D_(k-1)(x_prev) - P_(k-1) H_k(x_new)|`` over the tie points: the
predecessor as drawn against the new frame's geometry at its seam (where
``h_k = 1``), in frame k's pixels (divided by the scale of ``P_(k-1)``). It
holds the registration residual plus any mismatch left by the predecessor's
transition inside the overlap. ``overlap_residual_px`` is
``|D_(k-1)(x_prev) - D_k(x_new)|``: it adds the intended bending
``(1 - h) |H_k - A_k|`` in the hidden part of the overlap.
"""

from subpix_ros.core.mosaic.builder import Mosaic, MosaicUpdate
from subpix_ros.core.mosaic.geometry import FrameGeometry, PairModel

__all__ = ["Mosaic", "MosaicUpdate", "FrameGeometry", "PairModel"]
