"""Pyramid levels and working tiles of the Gauss-Newton stage, and 16x16 block sums."""

from __future__ import annotations

import math
from typing import Optional, Tuple

import cv2
import numpy as np

from .prefilter import fractional_shift_kernel

_BLOCK = 16  # block size (px) of the sandwich covariance and the misfit grid
_TILE = 128  # tile size (px) when only the most textured max_pixels are used


def _block_sum(image: np.ndarray, bs: int) -> np.ndarray:
    """Sum a 2-D float32 array over ``bs x bs`` blocks (the last row/column may be partial)."""
    h, w = image.shape
    ph, pw = -h % bs, -w % bs
    if ph or pw:  # a partial last block row/column: zero padding adds nothing to its sums
        image = cv2.copyMakeBorder(image, 0, ph, 0, pw, cv2.BORDER_CONSTANT, value=0)
        h, w = image.shape
    means = cv2.resize(image, (w // bs, h // bs), interpolation=cv2.INTER_AREA)
    return means.astype(np.float64) * (bs * bs)


def _block_counts(shape: Tuple[int, int], bs: int) -> np.ndarray:
    """Count the pixels per ``bs x bs`` block of an array of ``shape`` (as :func:`_block_sum`)."""

    def extent(n: int) -> np.ndarray:
        out = np.full(-(-n // bs), float(bs))
        if n % bs:
            out[-1] = float(n % bs)
        return out

    return np.outer(extent(shape[0]), extent(shape[1]))


def _dilate_invalid(valid: Optional[np.ndarray], before: int, after: int) -> Optional[np.ndarray]:
    """Return the pixels x whose window ``x - before .. x + after`` (both axes) is all valid."""
    if valid is None:
        return None
    invalid = (~valid).astype(np.uint8)
    n = before + after + 1
    return cv2.dilate(invalid, np.ones((n, n), np.uint8), anchor=(before, before)) == 0


class _Level:
    """One pyramid level: frames, validity, and stacked tiles for Gauss-Newton.

    The working pixels are one rectangle (the whole overlap) or, above ``max_pixels``, the
    most textured ``_TILE``-sized tiles spread over a 3x3 grid of the frame. Tiles are stacked
    vertically (each with its filter margin) so every filter and product is one OpenCV call.

    Parameters
    ----------
    reference, moving : ndarray
        The level's frames (uint8, uint16 or float32).
    ref_valid, mov_valid : ndarray of bool or None
        Validity (None: all valid); dilated here by the filter supports.
    taps, sigma, band : int, float, float
        The designed filter (:func:`.fractional_shift_kernel`).
    max_pixels : int or None
        Pixel budget above which tiles are used.
    score : callable or None
        ``score(r0, r1, c0, c1)`` -> texture score of regions, to choose tiles.
    kmax : int
        The tile lattice stays valid for integer shifts ``|k| <= kmax``.
    """

    def __init__(
        self,
        reference,
        moving,
        ref_valid,
        mov_valid,
        taps,
        sigma,
        band,
        max_pixels,
        score=None,
        kmax=2,
    ):
        self.reference, self.moving = reference, moving
        self.taps, self.sigma, self.band = taps, sigma, band
        self.h, self.w = reference.shape
        self.half = half = taps // 2
        self.margin = half + 1  # reference margin: filter (half) + gradient (1)
        self.max_pixels = max_pixels
        self.score = score
        self.ref_valid = _dilate_invalid(ref_valid, half + 1, half + 1)
        self.mov_valid = _dilate_invalid(mov_valid, half - 1, half)
        self._ref_key = None
        self._rects_cache = {}
        self.kmax = int(kmax)
        self.blocks = False  # True on the level whose final sums need 16x16 block statistics
        self._tiles = None

    # -- geometry ---------------------------------------------------------
    def rects(self, k0: int, k1: int, border: int):
        """Return the working rectangles ``(r0, r1, c0, c1)`` at integer shift (k0, k1), cached."""
        key = (k0, k1, border)
        if key not in self._rects_cache:
            self._rects_cache[key] = self._rects(k0, k1, border)
        return self._rects_cache[key]

    def _rects(self, k0: int, k1: int, border: int):
        """Compute :meth:`rects`: the whole overlap, or the tiles that fit; None if too small."""
        half, bs = self.half, _BLOCK
        r0 = max(border, self.margin, -k0 + half - 1)
        r1 = min(self.h - border, self.h - self.margin, self.h - k0 - half)
        c0 = max(border, self.margin, -k1 + half - 1)
        c1 = min(self.w - border, self.w - self.margin, self.w - k1 - half)
        if r1 - r0 < bs or c1 - c0 < bs:
            return None
        # the whole overlap is used (the last block row/column may be partial)
        if self.max_pixels is None or (r1 - r0) * (c1 - c0) <= self.max_pixels:
            return ((r0, r1, c0, c1),)
        # tiles: chosen once on a lattice valid for |k| <= kmax, then the ones that
        # fit at this k are used (so the reference side is prepared once)
        if self._tiles is None:
            self._tiles = self._choose_tiles(border)
        fitting = [
            t
            for t in self._tiles
            if t[0] + k0 - half + 1 >= 0
            and t[1] + k0 + half <= self.h
            and t[2] + k1 - half + 1 >= 0
            and t[3] + k1 + half <= self.w
        ]
        return tuple(fitting) if fitting else None

    def _choose_tiles(self, border: int):
        """Choose the most textured tiles, ``ceil(n / 9)`` per cell of a 3x3 grid at most."""
        half, size = self.half, _TILE
        edge = max(border, self.margin, self.kmax + half + 1)
        r0, r1, c0, c1 = edge, self.h - edge, edge, self.w - edge
        rows = np.arange(r0, r1 - size + 1, size)
        cols = np.arange(c0, c1 - size + 1, size)
        if rows.size == 0 or cols.size == 0:
            return []
        rows = rows + ((r1 - r0) - rows.size * size) // 2
        cols = cols + ((c1 - c0) - cols.size * size) // 2
        tile_rows, tile_cols = np.meshgrid(rows, cols, indexing="ij")
        tile_rows, tile_cols = tile_rows.ravel(), tile_cols.ravel()
        n_tiles = max(1, int(self.max_pixels // (size * size)))
        if n_tiles >= tile_rows.size:
            return [
                (int(r), int(r) + size, int(c), int(c) + size) for r, c in zip(tile_rows, tile_cols)
            ]
        texture = (
            self.score(tile_rows, tile_rows + size, tile_cols, tile_cols + size)
            if self.score
            else np.zeros(tile_rows.size)
        )
        cell = np.minimum(((tile_rows + size / 2) * 3 / self.h).astype(int), 2) * 3 + np.minimum(
            ((tile_cols + size / 2) * 3 / self.w).astype(int), 2
        )
        per_cell = int(math.ceil(n_tiles / 9))
        chosen = []
        for c in range(9):
            idx = np.flatnonzero(cell == c)
            chosen.extend(idx[np.argsort(-texture[idx])][:per_cell].tolist())
        chosen = sorted(chosen, key=lambda i: -texture[i])[:n_tiles]
        return [
            (
                int(tile_rows[i]),
                int(tile_rows[i]) + size,
                int(tile_cols[i]),
                int(tile_cols[i]) + size,
            )
            for i in sorted(chosen)
        ]

    # -- reference side (fixed while the tile set is fixed) -----------------
    def prepare_reference(self, rects):
        """Filter the reference with ``H_0`` and take its central-difference gradients.

        On the working rectangles ``rects``; kept until the rectangles change.
        """
        if self._ref_key == rects:
            return
        self._ref_key = rects
        margin = self.margin
        h0, anchor = fractional_shift_kernel(0.0, self.taps, self.sigma, self.band)
        wins = [
            self.reference[r0 - margin : r1 + margin, c0 - margin : c1 + margin]
            for r0, r1, c0, c1 in rects
        ]
        stack = wins[0] if len(wins) == 1 else np.concatenate(wins, axis=0)
        filtered = cv2.sepFilter2D(
            stack, cv2.CV_32F, h0, h0, anchor=(anchor, anchor), borderType=cv2.BORDER_REPLICATE
        )
        diff = np.float32([-0.5, 0.0, 0.5])
        one = np.float32([1.0])
        g0 = cv2.sepFilter2D(filtered, cv2.CV_32F, one, diff, borderType=cv2.BORDER_REPLICATE)
        g1 = cv2.sepFilter2D(filtered, cv2.CV_32F, diff, one, borderType=cv2.BORDER_REPLICATE)
        self.ref_filtered = self._interior(filtered, rects, margin, margin)
        self.g0 = self._interior(g0, rects, margin, margin)
        self.g1 = self._interior(g1, rects, margin, margin)
        if self.ref_valid is not None:
            self.ref_weight = self._interior_of(self.ref_valid, rects)
        else:
            self.ref_weight = None
        self._ref_sums = None

    @staticmethod
    def _interior(stack, rects, top, left):
        """Concatenate the interiors (rect shape) of stacked windows into one 2-D array."""
        if len(rects) == 1:
            r0, r1, c0, c1 = rects[0]
            return np.ascontiguousarray(stack[top : top + r1 - r0, left : left + c1 - c0])
        r0, r1, c0, c1 = rects[0]
        th, tw = r1 - r0, c1 - c0
        wh = stack.shape[0] // len(rects)
        s3 = stack.reshape(len(rects), wh, stack.shape[1])[:, top : top + th, left : left + tw]
        return np.ascontiguousarray(s3).reshape(len(rects) * th, tw)

    @staticmethod
    def _interior_of(full, rects, k0=0, k1=0):
        """Stack ``full``'s pixels of ``rects`` moved by (k0, k1)."""
        parts = [full[r0 + k0 : r1 + k0, c0 + k1 : c1 + k1] for r0, r1, c0, c1 in rects]
        return parts[0] if len(parts) == 1 else np.concatenate(parts, axis=0)

    # -- moving side ---------------------------------------------------------
    def sample_moving(self, rects, s):
        """Return ``(H_t * M)(x + k)`` on the rects for ``s = k + t`` (stacked as the reference)."""
        k = np.floor(s).astype(int)
        t = s - k
        h_row, anchor = fractional_shift_kernel(float(t[0]), self.taps, self.sigma, self.band)
        h_col, _ = fractional_shift_kernel(float(t[1]), self.taps, self.sigma, self.band)
        half = self.half
        k0, k1 = int(k[0]), int(k[1])
        wins = [
            self.moving[r0 + k0 - half + 1 : r1 + k0 + half, c0 + k1 - half + 1 : c1 + k1 + half]
            for r0, r1, c0, c1 in rects
        ]
        stack = wins[0] if len(wins) == 1 else np.concatenate(wins, axis=0)
        out = cv2.sepFilter2D(
            stack,
            cv2.CV_32F,
            h_col,
            h_row,
            anchor=(anchor, anchor),
            borderType=cv2.BORDER_REPLICATE,
        )
        return self._interior(out, rects, half - 1, half - 1)

    def weights(self, rects, s) -> Optional[np.ndarray]:
        """Return the pixels valid in both frames at shift ``s`` (None: all)."""
        k = np.floor(s).astype(int)
        weight = self.ref_weight
        if self.mov_valid is not None:
            mov_weight = self._interior_of(self.mov_valid, rects, int(k[0]), int(k[1]))
            weight = mov_weight if weight is None else (weight & mov_weight)
        return weight

    @staticmethod
    def block_centres(rects):
        """Return the centres (rows, cols; level px) of the 16x16 blocks of ``rects``.

        In block order (rect by rect, row-major). The rects are one region or equal tiles
        (:meth:`rects`), so one block layout serves all.
        """
        r = np.asarray(rects, dtype=np.int64).reshape(-1, 4)
        th, tw = int(r[0, 1] - r[0, 0]), int(r[0, 3] - r[0, 2])
        if not (np.all(r[:, 1] - r[:, 0] == th) and np.all(r[:, 3] - r[:, 2] == tw)):
            raise ValueError("block_centres: rects of unequal size")
        ra = np.arange(0, th, _BLOCK)
        ca = np.arange(0, tw, _BLOCK)
        rc = (ra + np.minimum(ra + _BLOCK, th)) / 2.0  # centre of a possibly partial block
        cc = (ca + np.minimum(ca + _BLOCK, tw)) / 2.0
        shape = (len(r), ra.size, ca.size)
        rr = np.broadcast_to(r[:, 0, None, None] + rc[None, :, None], shape)
        cl = np.broadcast_to(r[:, 2, None, None] + cc[None, None, :], shape)
        return rr.reshape(-1), cl.reshape(-1)


def _texture_scorer(image: np.ndarray, scale: float):
    """Return ``score(r0, r1, c0, c1)``: summed squared Sobel gradient of regions.

    The regions are in the coordinates of a level ``1 / scale`` times larger than ``image``
    (a small pyramid level); equal-length integer arrays in, one score per region out
    (integral image).
    """
    work = image.astype(np.float32)
    gx = cv2.Sobel(work, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(work, cv2.CV_32F, 0, 1, ksize=3)
    energy = cv2.add(cv2.multiply(gx, gx), cv2.multiply(gy, gy))
    integral = cv2.integral(energy, sdepth=cv2.CV_64F)
    height, width = energy.shape

    def score(r0, r1, c0, c1):
        a0 = np.clip((np.asarray(r0) * scale).astype(int), 0, height - 1)
        a1 = np.clip(np.ceil(np.asarray(r1) * scale).astype(int), a0 + 1, height)
        b0 = np.clip((np.asarray(c0) * scale).astype(int), 0, width - 1)
        b1 = np.clip(np.ceil(np.asarray(c1) * scale).astype(int), b0 + 1, width)
        return integral[a1, b1] - integral[a0, b1] - integral[a1, b0] + integral[a0, b0]

    return score


def _pyr(image: np.ndarray) -> np.ndarray:
    """Return 2x2 block means (an odd last row/column dropped: INTER_AREA's fast path)."""
    h, w = image.shape[0] // 2, image.shape[1] // 2
    return cv2.resize(image[: 2 * h, : 2 * w], (w, h), interpolation=cv2.INTER_AREA)


def _pyr_mask(valid: Optional[np.ndarray]) -> Optional[np.ndarray]:
    """Halve a validity mask: a coarse pixel is valid if all four fine ones are."""
    if valid is None:
        return None
    return _pyr(valid.astype(np.float32)) >= 0.999
