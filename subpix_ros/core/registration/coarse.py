"""Coarse overlap between two frames (METHODS.md C, stage 1), on a pyramid.

The paper replaces brightness by the Sobel gradient magnitude (so exposure
differences between frames do not matter), cuts frame k+1 into square
fragments, finds each fragment's offset in frame k by minimising the mean
absolute gradient difference, keeps only offsets confirmed by the reverse
search within 1 pixel, and averages them.

The paper's frames were translated only; a drone without gimbal also rotates
between frames (tens of degrees on the Seneca strip). So the fragment search
runs for a few rotation hypotheses, taken from the peaks of the circular
cross-correlation of the two frames' gradient-orientation histograms
(magnitude-weighted), and falls back to a sweep of angles when no hypothesis
is confirmed. For each hypothesis the moving gradient image is rotated (at
the coarse pyramid level only, so it is cheap), fragments are searched with
``cv2.matchTemplate`` (sum of squared differences, an L2 stand-in used to
find the candidate) and the candidate is confirmed by the paper's mean
absolute difference over its 3x3 neighbourhood, then by the reverse search.
The consistent fragment centres give a similarity (or translation) fit.

Units: pixels of the coarse level; transforms map MOVING (x, y) to REFERENCE
(x, y), as 3x3 matrices.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

__all__ = [
    "gradient_magnitude",
    "orientation_hypotheses",
    "CoarseResult",
    "coarse_overlap",
    "orb_features",
    "coarse_orb",
]


def gradient_magnitude(gray: np.ndarray) -> np.ndarray:
    """Compute the Sobel gradient magnitude ``sqrt(Gx^2 + Gy^2)`` (intensity/px), float32."""
    gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=3)
    return cv2.magnitude(gx, gy)


def _orientation_hist(gray: np.ndarray, bins: int) -> np.ndarray:
    gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=3)
    mag, ang = cv2.cartToPolar(gx, gy)  # ang in [0, 2 pi)
    idx = np.minimum((ang * (bins / (2 * np.pi))).astype(np.int32), bins - 1)
    h = np.bincount(idx.ravel(), weights=mag.ravel(), minlength=bins)
    # circular smoothing (about 3 bins)
    k = np.exp(-0.5 * (np.arange(-4, 5) / 1.5) ** 2)
    hp = np.concatenate([h[-4:], h, h[:4]])
    return np.convolve(hp, k / k.sum(), mode="valid")


def orientation_hypotheses(
    ref: np.ndarray, mov: np.ndarray, n: int = 4, bins: int = 180
) -> list[float]:
    """Return candidate rotation angles (radians) from moving to reference.

    Parameters
    ----------
    ref, mov : ndarray of float32
        The two frames at a coarse level.
    n : int
        Most hypotheses.
    bins : int
        Orientation histogram bins.

    Returns
    -------
    list of float
        The ``n`` strongest peaks of the histograms' cross-correlation, at least 20 degrees
        apart.

    Notes
    -----
    ``c(k) = sum_i h_m(i) h_r(i + k)`` (circular cross-correlation of the magnitude-weighted
    gradient-orientation histograms, via FFT). Rotation sign: the angle ``theta`` such that
    ``R(theta) = [[cos, -sin], [sin, cos]]`` (image coordinates, y down) turns moving
    directions into reference directions.
    """
    hr = _orientation_hist(ref, bins)
    hm = _orientation_hist(mov, bins)
    hr = hr - hr.mean()
    hm = hm - hm.mean()
    c = np.real(np.fft.ifft(np.conj(np.fft.fft(hm)) * np.fft.fft(hr)))
    order = np.argsort(-c)
    sep = int(round(20 * bins / 360))
    picked: list[int] = []
    for k in order[:bins]:  # a few iterations: stops once n peaks are picked
        if all(min(abs(k - j), bins - abs(k - j)) >= sep for j in picked):
            picked.append(int(k))
            if len(picked) == n:
                break
    return [2 * np.pi * k / bins for k in picked]


@dataclass
class CoarseResult:
    """Outcome of a coarse search: ``transform`` (3x3, coarse-level moving -> reference) or why not.

    ``n_consistent``: fragments or features that agree; ``mad``: their mean absolute gradient
    difference (fragments; 0 for ORB).
    """

    ok: bool
    reason: str
    transform: np.ndarray | None  # 3x3 coarse-level moving -> reference
    n_consistent: int
    mad: float


def _rotation_canvas(shape: tuple[int, int], theta: float) -> tuple[np.ndarray, tuple[int, int]]:
    """Affine 2x3 rotating a frame of ``shape`` by ``theta`` into a canvas holding all of it."""
    h, w = shape
    c, s = np.cos(theta), np.sin(theta)
    r = np.array([[c, -s], [s, c]])
    corners = np.array([[0, 0], [w - 1, 0], [w - 1, h - 1], [0, h - 1]], float) @ r.T
    lo = corners.min(axis=0)
    hi = corners.max(axis=0)
    a = np.hstack([r, -lo[:, None]])
    size = (int(np.ceil(hi[0] - lo[0])) + 1, int(np.ceil(hi[1] - lo[1])) + 1)
    return a, size


def _mad_refine(big: np.ndarray, frag: np.ndarray, x: int, y: int) -> tuple[int, int, float]:
    """Best position by mean absolute difference over the 3x3 neighbourhood of (x, y)."""
    f = frag.shape[0]
    hb, wb = big.shape
    best = (x, y, np.inf)
    ys = np.arange(max(y - 1, 0), min(y + 1, hb - f) + 1)
    xs = np.arange(max(x - 1, 0), min(x + 1, wb - f) + 1)
    sub = big[ys[0] : ys[-1] + f, xs[0] : xs[-1] + f]
    win = np.lib.stride_tricks.sliding_window_view(sub, (f, f))  # (ny, nx, f, f)
    mad = np.abs(win - frag).mean(axis=(2, 3))
    j, i = np.unravel_index(np.argmin(mad), mad.shape)
    if mad[j, i] < best[2]:
        best = (int(xs[i]), int(ys[j]), float(mad[j, i]))
    return best


def _fragment_search(
    gref: np.ndarray, gcan: np.ndarray, vcan: np.ndarray, frag: int, min_energy: float
):
    """Search fragments forward and backward.

    Returns the centres (moving canvas, reference) and the mean absolute differences of the
    fragments the reverse search confirms.
    """
    hc, wc = gcan.shape
    stride = max(int(frag * 0.75), 1)
    src, dst, mads = [], [], []
    ys = np.arange(0, hc - frag + 1, stride)
    xs = np.arange(0, wc - frag + 1, stride)
    # Fragments entirely inside the rotated frame's valid area, with texture.
    ii = np.pad(vcan.astype(np.float64), ((1, 0), (1, 0))).cumsum(0).cumsum(1)
    for y in ys:  # loop over a handful of fragments (<= ~40), each search is one OpenCV call
        for x in xs:
            cov = ii[y + frag, x + frag] - ii[y, x + frag] - ii[y + frag, x] + ii[y, x]
            if cov < frag * frag:
                continue
            f = gcan[y : y + frag, x : x + frag]
            if float(f.mean()) < min_energy:
                continue
            res = cv2.matchTemplate(gref, f, cv2.TM_SQDIFF)
            _, _, (bx, by), _ = cv2.minMaxLoc(res)
            bx, by, mad = _mad_refine(gref, f, bx, by)
            back = gref[by : by + frag, bx : bx + frag]
            rb = cv2.matchTemplate(gcan, back, cv2.TM_SQDIFF)
            _, _, (cx, cy), _ = cv2.minMaxLoc(rb)
            cx, cy, _ = _mad_refine(gcan, back, cx, cy)
            if abs(cx - x) <= 1 and abs(cy - y) <= 1:  # reverse search confirms within 1 px
                src.append((x + (frag - 1) / 2, y + (frag - 1) / 2))
                dst.append((bx + (frag - 1) / 2, by + (frag - 1) / 2))
                mads.append(mad)
    return np.array(src).reshape(-1, 2), np.array(dst).reshape(-1, 2), np.array(mads)


def _similarity_fit(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Fit the least-squares similarity ``dst = s R src + t`` (Umeyama, no reflection); 3x3."""
    ms, md = src.mean(axis=0), dst.mean(axis=0)
    a, b = src - ms, dst - md
    cov = b.T @ a / len(src)
    u, sv, vt = np.linalg.svd(cov)
    d = np.sign(np.linalg.det(u @ vt))
    dm = np.diag([1.0, d])
    r = u @ dm @ vt
    var = (a * a).sum() / len(src)
    s = float((sv * np.diag(dm)).sum() / var) if var > 0 else 1.0
    t = md - s * r @ ms
    out = np.eye(3)
    out[:2, :2] = s * r
    out[:2, 2] = t
    return out


def _consensus_similarity(
    src: np.ndarray, dst: np.ndarray, tol: float
) -> tuple[np.ndarray | None, np.ndarray]:
    """Find the similarity most fragment correspondences support (all pairs, vectorised).

    Each pair (i, j) defines ``z -> a z + b`` in complex notation
    (``a = (d_j - d_i) / (s_j - s_i)``); a fragment agrees when its transfer
    error is below ``tol`` px. Scales outside [0.6, 1.7] are not considered.
    Returns (3x3 LS similarity over the largest agreeing set, agree mask).
    """
    n = len(src)
    zs = src[:, 0] + 1j * src[:, 1]
    zd = dst[:, 0] + 1j * dst[:, 1]
    i, j = np.triu_indices(n, 1)
    ds = zs[j] - zs[i]
    ok = np.abs(ds) > 1e-9
    i, j, ds = i[ok], j[ok], ds[ok]
    if i.size == 0:
        return None, np.zeros(n, bool)
    a = (zd[j] - zd[i]) / ds
    b = zd[i] - a * zs[i]
    err = np.abs(a[:, None] * zs[None, :] + b[:, None] - zd[None, :])  # (pairs, n)
    agree = (err < tol) & ((np.abs(a) > 0.6) & (np.abs(a) < 1.7))[:, None]
    k = int(np.argmax(agree.sum(axis=1)))
    mask = agree[k]
    if mask.sum() < 2:
        return None, mask
    return _similarity_fit(src[mask], dst[mask]), mask


def coarse_overlap(
    gref: np.ndarray,
    gmov: np.ndarray,
    angles: list[float],
    frag_frac: float = 0.3,
    min_consistent: int = 3,
) -> CoarseResult:
    """Search fragments (METHODS C, stage 1) over rotation hypotheses ``angles``.

    Parameters
    ----------
    gref, gmov : ndarray of float32
        Coarse-level gradient magnitudes.
    angles : list of float
        Rotation hypotheses (radians).
    frag_frac : float
        Fragment side as a fraction of ``min(h, w)`` (the paper: half the expected overlap).
    min_consistent : int
        Fewest agreeing fragments.

    Returns
    -------
    CoarseResult

    Notes
    -----
    Fragments that pass the reverse check vote for a similarity (consensus over all pairs of
    fragments, :func:`_consensus_similarity`); the hypothesis with most agreeing fragments
    (ties: lower MAD) wins.
    """
    h, w = gmov.shape
    frag = max(8, int(round(frag_frac * min(h, w))))
    if min(gref.shape) < frag + 2:
        return CoarseResult(False, "frames too small for the coarse search", None, 0, np.inf)
    min_energy = 0.25 * float(np.median(gref))
    best: CoarseResult | None = None
    for theta in angles:
        a, size = _rotation_canvas((h, w), theta)
        gcan = cv2.warpAffine(gmov, a, size, flags=cv2.INTER_LINEAR)
        vcan = cv2.warpAffine(np.ones((h, w), np.uint8), a, size, flags=cv2.INTER_NEAREST) > 0
        src, dst, mads = _fragment_search(gref, gcan, vcan, frag, min_energy)
        if len(src) < min_consistent:
            continue
        fit, agree = _consensus_similarity(src, dst, tol=max(2.0, 0.1 * frag))
        n = int(agree.sum())
        if fit is None or n < min_consistent:
            continue
        mad = float(mads[agree].mean())
        if best is not None and (
            n < best.n_consistent or (n == best.n_consistent and mad >= best.mad)
        ):
            continue
        rot = np.vstack([a, [0, 0, 1]])
        best = CoarseResult(True, "", fit @ rot, n, mad)
    if best is None:
        return CoarseResult(
            False, "no overlap: no fragment offset confirmed by the reverse search", None, 0, np.inf
        )
    return best


def _orb_u8(img: np.ndarray) -> np.ndarray:
    clahe = cv2.createCLAHE(
        clipLimit=2.0, tileGridSize=(8, 8)
    )  # even out the weak NIR field texture
    return clahe.apply(cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8))


def orb_features(
    img: np.ndarray, n_features: int = 1500, fast_threshold: int = 20
) -> tuple[tuple, np.ndarray | None]:
    """Detect ORB keypoints and descriptors of one pyramid level, for :func:`coarse_orb`.

    Parameters
    ----------
    img : ndarray
        One pyramid level (float32); a CLAHE-equalised 8-bit copy is used.
    n_features : int
        Most keypoints.
    fast_threshold : int
        FAST threshold (of 255, on the equalised copy).

    Returns
    -------
    keypoints : tuple of cv2.KeyPoint
    descriptors : ndarray or None

    Notes
    -----
    Depends only on the frame, so a fixed reference frame computes it once. Four ORB scales
    (1.2^3 = 1.7x) cover the scale change between overlapping frames of one flight; the FAST
    threshold of 20 drops the weak corners, which never gave consistent matches (design
    notes, "Registration"). :func:`.register`'s last resort for low overlap asks for more and
    weaker corners.
    """
    orb = cv2.ORB_create(
        nfeatures=n_features,
        scaleFactor=1.2,
        nlevels=4,
        edgeThreshold=19,
        patchSize=19,
        fastThreshold=fast_threshold,
    )
    return orb.detectAndCompute(_orb_u8(img), None)


def coarse_orb(
    ref: np.ndarray,
    mov: np.ndarray,
    n_features: int = 1500,
    min_inliers: int = 10,
    ref_features: tuple[tuple, np.ndarray | None] | None = None,
    mov_features: tuple[tuple, np.ndarray | None] | None = None,
) -> CoarseResult:
    """Align coarsely, rotation-invariant: ORB features + RANSAC similarity on a low level.

    Parameters
    ----------
    ref, mov : ndarray of float32
        One pyramid level of each frame.
    n_features : int
        ORB features when they are computed here.
    min_inliers : int
        Fewest consistent matches.
    ref_features, mov_features : tuple, optional
        The frames' :func:`orb_features` when already known.

    Returns
    -------
    CoarseResult
        Transform in that level's pixels (moving -> reference), a 4-dof similarity
        (rotation, scale, translation).

    Notes
    -----
    Used before the paper's translation-only fragment search, because camera yaw between
    consecutive drone frames (tens of degrees) defeats a translation search on gradient
    magnitude at a level coarse enough to be cheap. Accuracy only needs to be a few pixels:
    the pyramid refinement takes it from there.
    """
    ka, da = ref_features if ref_features is not None else orb_features(ref, n_features)
    kb, db = mov_features if mov_features is not None else orb_features(mov, n_features)
    if da is None or db is None or len(ka) < min_inliers or len(kb) < min_inliers:
        return CoarseResult(False, "no texture: too few coarse features", None, 0, np.inf)
    if len(ka) < 2:
        return CoarseResult(False, "no texture: too few coarse features", None, 0, np.inf)
    # the two nearest reference descriptors (Hamming) of every moving one; Lowe's ratio test
    dist, idx = cv2.batchDistance(db, da, -1, normType=cv2.NORM_HAMMING, K=2)[:2]
    good = dist[:, 0] < 0.85 * dist[:, 1]
    if int(good.sum()) < min_inliers:
        return CoarseResult(
            False, "no overlap: too few coarse feature matches", None, int(good.sum()), np.inf
        )
    pa = np.float32([k.pt for k in ka])
    pb = np.float32([k.pt for k in kb])
    src = pb[good]
    dst = pa[idx[good, 0]]
    a, mask = cv2.estimateAffinePartial2D(
        src, dst, method=cv2.RANSAC, ransacReprojThreshold=3.0, maxIters=5000, confidence=0.999
    )
    n = 0 if mask is None else int(mask.sum())
    if a is None or n < min_inliers:
        return CoarseResult(
            False, f"no overlap: only {n} consistent coarse feature matches", None, n, np.inf
        )
    scale = float(np.sqrt(abs(np.linalg.det(a[:, :2]))))
    if not (0.5 < scale < 2.0):
        return CoarseResult(False, f"degenerate coarse fit (scale {scale:.2f})", None, n, np.inf)
    return CoarseResult(True, "", np.vstack([a, [0, 0, 1]]).astype(np.float64), n, 0.0)
