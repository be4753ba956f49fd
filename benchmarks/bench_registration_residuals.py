"""Where the inlier residual of real Seneca pairs comes from (issue 4's RMS target).

For each of the 8 consecutive half-resolution pairs (bundled 1800x1350 frames):

* ``rms``: the inlier RMS transfer residual of ``register`` (px, reference frame).
* ``along`` / ``cross``: its RMS along the baseline (the direction the frame
  centre moves between the two exposures) and across it. Parallax from relief
  under a translating camera lies along the baseline (epipolar lines of a
  nadir camera in straight flight); matching noise is isotropic.
* ``nn.al`` / ``nn.cr``: correlation of each inlier's residual with that of
  its nearest inlier (~20-25 px away). Matching noise is independent between
  points (~0); a geometric effect (relief, model error) is shared (~1).
* ``row``: fraction of the along-baseline residual variance explained by a
  smooth function of the image row (degree-8 Legendre): rolling-shutter
  wobble or line-timing errors would show here.
* ``ctrl``: the same registration on a control pair with the SAME geometry
  but no scene change: the reference frame warped by the pair's own fitted
  homography (Lanczos-4) stands in for the moving frame. Its residual is the
  matching + fitting floor on this real texture.
* ``epi``: the RMS distance of each reference tie point from the epipolar
  line of its match (fundamental matrix, 8-point least squares on all the
  inliers, distortion removed with the pair's own lambda). Any rigid 3-D
  scene satisfies the epipolar constraint, so ``epi`` is the part of the
  residual that relief cannot explain (matching error, appearance change):
  ``rms`` far above ``epi`` means the homography's residual is depth.
* ``B m``, ``|t| px``, ``H m``: GPS baseline between the exposures, the
  baseline in image px (frame-centre motion) and the height above ground
  implied by both with the camera model (f 4.3 mm, 3.08 um pitch at half
  resolution): ``H = B f / (|t| p)``.
* ``px/cm``: parallax of 1 cm of relief between the two exposures,
  ``|t| dh / H`` (px per cm).
* ``view``: the angle between the two lines of sight to a ground point
  under the baseline's midpoint, ``2 atan(B / 2H)`` (degrees): how differently
  the two exposures see 3-D texture (furrows, crops, verges: shading and
  self-occlusion change with it, in every direction, unlike parallax).

A second table tests the other explanation, a lens model richer than the
one division-model term ``register`` fits per pair: the tie points of all 8
pairs (registered without distortion, threshold 3 px, so none is pre-cut)
are fitted JOINTLY with one Brown-Conrady model shared by every frame
(radial k1, k2, k3, tangential p1, p2, and the distortion centre free) and
8 homographies (scipy least_squares, soft-L1). The residual is the transfer
error in reference pixels (the undistorted-space residual divided by the
local scale of the undistortion: without that, a model that shrinks the
undistorted plane "wins" by shrinking the residuals with it). It is fitted
to the very points it is scored on, so it is optimistic. ``rms<=1.5`` is
the RMS over the points within 1.5 px (``register``'s inlier threshold).

A third table asks whether the residual is bad matches: each inlier's
normalised cross-correlation (15x15 px) between the reference patch and the
moving frame sampled at the point's OWN match, with the model's local
geometry around it. A mismatch or a patch whose appearance changed between
the views (occlusion, shading) correlates worse; if those carried the
residual, the best-correlated points would fit the homography better.
(Sampled at the model's prediction instead, the correlation would only
restate the residual.)

    python benchmarks/bench_registration_residuals.py
"""

from __future__ import annotations

import csv
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from subpix_ros.core.registration import (  # noqa: E402
    Normaliser,
    apply_h,
    register,
    sample_linear_cv,
    to_gray32,
    undistort_points,
)
from subpix_ros.core.telemetry import enu_offset_m  # noqa: E402
from subpix_ros.data import seneca_frame_paths  # noqa: E402

FOCAL_M = 4.3e-3
PITCH_HALF_M = 2 * 1.54e-6  # half resolution


def nn_corr(p: np.ndarray, a: np.ndarray) -> float:
    """Correlation of ``a`` at each point with ``a`` at its nearest neighbour."""
    d2 = ((p[:, None, :] - p[None, :, :]) ** 2).sum(-1)
    np.fill_diagonal(d2, np.inf)
    nn = d2.argmin(1)
    return float(np.corrcoef(a, a[nn])[0, 1])


def row_explained(rows: np.ndarray, a: np.ndarray, deg: int = 8) -> float:
    t = (rows - rows.min()) / max(np.ptp(rows), 1.0) * 2 - 1
    V = np.polynomial.legendre.legvander(t, deg)
    c, *_ = np.linalg.lstsq(V, a, rcond=None)
    return float(1.0 - np.var(a - V @ c) / np.var(a))


def anatomy(ref: np.ndarray, r) -> dict:
    """Return the columns of the first table for one pair: ``r`` = register(ref, moving), ok."""
    pr, pm = r.points[:, :2], r.points[:, 2:]
    h, w = ref.shape[:2]
    t = r.baseline_px()  # moving centre -> reference: minus the scene motion
    along, cross = r.residual_components()
    rms_along, rms_cross = r.residual_along_cross()
    nrm = Normaliser.for_shape(r.ref_shape)
    ur, um = undistort_points(pr, r.distortion, nrm), undistort_points(pm, r.distortion, nrm)
    f, _ = cv2.findFundamentalMat(um, ur, cv2.FM_8POINT)
    lines = (
        np.hstack([um, np.ones((len(um), 1))]) @ f.T
    )  # epipolar lines in the reference: a x + b y + c = 0
    epi = np.sum(np.hstack([ur, np.ones((len(ur), 1))]) * lines, axis=1) / np.hypot(
        lines[:, 0], lines[:, 1]
    )
    # control: same geometry, same exposure (reference warped by the fitted homography)
    ctrl_mov = cv2.warpPerspective(
        ref, r.homography, (w, h), flags=cv2.INTER_LANCZOS4 | cv2.WARP_INVERSE_MAP
    )
    rc = register(ref, ctrl_mov, distortion=False)
    return {
        "inliers": r.inliers,
        "rms": r.rms_px,
        "along": rms_along,
        "cross": rms_cross,
        "nn_al": nn_corr(pr, along),
        "nn_cr": nn_corr(pr, cross),
        "row": row_explained(pr[:, 1], along),
        "ctrl": rc.rms_px if rc.ok else float("nan"),
        "ctrl_inl": rc.inliers,
        "t_px": float(np.hypot(*t)),
        "epi": float(np.sqrt(np.mean(epi**2))),
    }


def match_ncc(ref: np.ndarray, mov: np.ndarray, r, half: int = 7) -> np.ndarray:
    """NCC of each inlier's reference patch with the moving frame around the inlier's own match.

    The moving frame is sampled (bilinear) at ``m + T(x) - T(p)`` for the patch pixels ``x`` around the
    reference point ``p`` (``T`` = the full model's reference -> moving map, ``m`` the match).
    """
    g0, g1 = to_gray32(ref), to_gray32(mov)  # the seed luminance register() matched on
    pr, pm = r.points[:, :2], r.points[:, 2:]
    d = np.arange(-half, half + 1, dtype=np.float64)
    offs = np.stack(np.meshgrid(d, d), -1).reshape(1, -1, 2)
    grid = pr[:, None, :] + offs  # (N, k*k, 2) reference positions
    mg = (
        r.inverse_transfer(grid.reshape(-1, 2)).reshape(grid.shape)
        - r.inverse_transfer(pr)[:, None, :]
        + pm[:, None, :]
    )
    a = sample_linear_cv(g0, grid[..., 0], grid[..., 1])
    b = sample_linear_cv(g1, mg[..., 0], mg[..., 1])
    a = a - a.mean(1, keepdims=True)
    b = b - b.mean(1, keepdims=True)
    return (a * b).sum(1) / np.sqrt((a * a).sum(1) * (b * b).sum(1) + 1e-12)


def inlier_residuals(ours: list) -> np.ndarray:
    """Transfer residual (px, reference frame) of every inlier of the registrations ``ours``, concatenated."""
    return np.concatenate(
        [np.hypot(*(r.transfer(r.points[:, 2:]) - r.points[:, :2]).T) for r in ours]
    )


def quality_table(ims: list, ours: list) -> None:
    """Print the third table: residual RMS of the inliers whose match correlates at least ``t``."""
    res = inlier_residuals(ours)
    ncc = np.concatenate([match_ncc(ims[i], ims[i + 1], r) for i, r in enumerate(ours)])
    print(
        "\nBad matches? Inlier residual by the NCC of each point's own match (15x15 px, all 8 pairs)"
    )
    head = f"{'NCC >=':>6s} {'points':>7s} {'share':>6s} {'rms px':>7s}"
    print(head)
    print("-" * len(head))
    for t in (-1.0, 0.7, 0.8, 0.85, 0.9, 0.95):
        k = ncc >= t
        if k.any():
            print(
                f"{t:6.2f} {int(k.sum()):7d} {k.mean():6.2f} {float(np.sqrt(np.mean(res[k] ** 2))):7.3f}"
            )
    print(f"correlation of |residual| with NCC: {float(np.corrcoef(res, ncc)[0, 1]):+.3f}")


def _brown_undistort(p: np.ndarray, k: np.ndarray, c: np.ndarray, scale: float) -> np.ndarray:
    """Brown-Conrady undistortion (k1, k2, k3 radial, p1, p2 tangential), radius in ``scale`` px."""
    x = (p - c) / scale
    r2 = (x**2).sum(1, keepdims=True)
    rad = 1 + k[0] * r2 + k[1] * r2**2 + k[2] * r2**3
    xx, yy = x[:, :1], x[:, 1:]
    tx = 2 * k[3] * xx * yy + k[4] * (r2 + 2 * xx * xx)
    ty = k[3] * (r2 + 2 * yy * yy) + 2 * k[4] * xx * yy
    return np.hstack([xx * rad + tx, yy * rad + ty]) * scale + c


def _local_scale(
    p: np.ndarray, k: np.ndarray, c: np.ndarray, scale: float, e: float = 0.5
) -> np.ndarray:
    """Sqrt |det| of the undistortion's Jacobian at ``p`` (undistorted px per image px)."""
    a = _brown_undistort(p + [e, 0], k, c, scale) - _brown_undistort(p - [e, 0], k, c, scale)
    b = _brown_undistort(p + [0, e], k, c, scale) - _brown_undistort(p - [0, e], k, c, scale)
    return np.sqrt(np.abs(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])) / (2 * e)


def joint_lens_fit(pairs: list, shape: tuple) -> list:
    """Per-pair transfer residuals (px) after one shared Brown model + a homography per pair.

    ``pairs``: (moving points, reference points, initial homography) per pair.
    """
    from scipy.optimize import least_squares

    h, w = shape
    scale = float(np.hypot(w, h) / 2)
    c0 = np.array([w / 2.0, h / 2.0])

    def unpack(x):
        return (
            np.asarray(x[:5]),
            c0 + x[5:7],
            [np.append(x[7 + 8 * j : 15 + 8 * j], 1.0).reshape(3, 3) for j in range(len(pairs))],
        )

    def resid(x):
        k, c, hs = unpack(x)
        out = []
        for (pm, pr, _), hj in zip(pairs, hs):
            d = apply_h(hj, _brown_undistort(pm, k, c, scale)) - _brown_undistort(pr, k, c, scale)
            out.append((d / _local_scale(pr, k, c, scale)[:, None]).ravel())
        return np.concatenate(out)

    x0 = [0.0] * 7
    for _, _, h0 in pairs:
        x0 += list((h0 / h0[2, 2]).ravel()[:8])
    sol = least_squares(resid, np.array(x0), loss="soft_l1", f_scale=1.0, x_scale="jac")
    r = sol.fun.reshape(-1, 2)
    d = np.hypot(r[:, 0], r[:, 1])
    out, i = [], 0
    for pm, _, _ in pairs:
        out.append(d[i : i + len(pm)])
        i += len(pm)
    return out


def lens_table(ims: list, ours: list) -> None:
    """Print the second table: ``ours[i]`` = register(ims[i], ims[i + 1]) (all successful)."""
    pts = []
    for i in range(len(ims) - 1):
        r0 = register(ims[i], ims[i + 1], distortion=False, inlier_px=3.0)
        if not r0.ok:
            print(f"{i:4d} failed without distortion: {r0.reason}")
            return
        pts.append((r0.points[:, 2:], r0.points[:, :2], r0.homography))
    res = joint_lens_fit(pts, ims[0].shape[:2])
    print(
        "\nA richer lens model? Joint fit over the strip: one Brown model (k1 k2 k3 p1 p2 + centre) for all frames"
    )
    head = f"{'pair':>4s} {'register: inl':>13s} {'rms':>6s} | {'joint Brown: <=1.5':>18s} {'rms<=1.5':>8s}"
    print(head)
    print("-" * len(head))
    for i, (r1, d) in enumerate(zip(ours, res)):
        inl = d <= 1.5
        print(
            f"{i:4d} {r1.inliers:13d} {r1.rms_px:6.3f} | {int(inl.sum()):18d} {float(np.sqrt(np.mean(d[inl] ** 2))):8.3f}"
        )
    allr = np.concatenate(res)
    inl = allr <= 1.5
    own = inlier_residuals(ours)
    print(
        f"all pairs: register (one lambda per pair) {np.sqrt(np.mean(own**2)):.3f} px over {own.size} inliers;"
        f" joint Brown {np.sqrt(np.mean(allr[inl] ** 2)):.3f} px over {int(inl.sum())} of {allr.size} points"
    )


def main() -> int:
    paths = seneca_frame_paths()
    with open(paths[0].parent / "frames.csv", newline="") as f:
        meta = {row["file"]: row for row in csv.DictReader(f)}
    print("Inlier residual anatomy, Seneca strip at 1800x1350 (px unless stated)")
    head = (
        f"{'pair':>4s} {'inl':>4s} {'rms':>6s} {'along':>6s} {'cross':>6s} {'nn.al':>6s} {'nn.cr':>6s} {'row':>5s} "
        f"{'epi':>6s} {'ctrl':>6s} {'c.inl':>5s} {'B m':>6s} {'|t| px':>7s} {'H m':>6s} {'px/cm':>6s} {'view':>5s}"
    )
    print(head)
    print("-" * len(head))
    ims = [cv2.imread(str(p)) for p in paths]
    results = [register(ims[i], ims[i + 1]) for i in range(len(ims) - 1)]
    allr = []
    for i, r in enumerate(results):
        if not r.ok:
            print(f"{i:4d} failed: {r.reason}")
            continue
        s = anatomy(ims[i], r)
        m0, m1 = meta[paths[i].name], meta[paths[i + 1].name]
        east, north = enu_offset_m(
            float(m0["latitude_deg"]),
            float(m0["longitude_deg"]),
            float(m1["latitude_deg"]),
            float(m1["longitude_deg"]),
        )
        base = float(np.hypot(east, north))
        height = base * FOCAL_M / (s["t_px"] * PITCH_HALF_M)
        s["pxcm"] = s["t_px"] * 0.01 / height
        s["view"] = float(np.degrees(2 * np.arctan(base / (2 * height))))
        allr.append(s)
        print(
            f"{i:4d} {s['inliers']:4d} {s['rms']:6.3f} {s['along']:6.3f} {s['cross']:6.3f} {s['nn_al']:6.2f} "
            f"{s['nn_cr']:6.2f} {s['row']:5.2f} {s['epi']:6.3f} {s['ctrl']:6.3f} {s['ctrl_inl']:5d} {base:6.1f} {s['t_px']:7.1f} "
            f"{height:6.1f} {s['pxcm']:6.3f} {s['view']:5.1f}"
        )
    if allr:
        med = {
            k: float(np.median([s[k] for s in allr]))
            for k in (
                "rms",
                "along",
                "cross",
                "nn_al",
                "nn_cr",
                "row",
                "epi",
                "ctrl",
                "pxcm",
                "view",
            )
        }
        print(
            f"median: rms {med['rms']:.3f}, along {med['along']:.3f}, cross {med['cross']:.3f}, nn corr along "
            f"{med['nn_al']:.2f} / cross {med['nn_cr']:.2f}, row-explained {med['row']:.2f}, off the epipolar lines {med['epi']:.3f}, control {med['ctrl']:.3f} px; "
            f"1 cm of relief = {med['pxcm']:.3f} px of parallax along the baseline; lines of sight {med['view']:.0f} deg apart"
        )
    if all(r.ok for r in results):
        lens_table(ims, results)
        quality_table(ims, results)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
