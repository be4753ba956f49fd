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

    python benchmarks/bench_registration_residuals.py
"""
from __future__ import annotations

import csv
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from subpix_ros.core.registration import register  # noqa: E402
from subpix_ros.core.registration_points import apply_h  # noqa: E402
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


def anatomy(ref: np.ndarray, mov: np.ndarray) -> dict:
    r = register(ref, mov)
    if not r.ok:
        return {"ok": False, "reason": r.reason}
    pr, pm = r.points[:, :2], r.points[:, 2:]
    d = r.transfer(pm) - pr
    h, w = ref.shape[:2]
    c = np.array([[w / 2.0, h / 2.0]])
    t = (apply_h(r.homography, c) - c)[0]  # moving centre -> reference: minus the scene motion
    e = t / np.hypot(*t)
    along, cross = d @ e, d @ np.array([-e[1], e[0]])
    # control: same geometry, same exposure (reference warped by the fitted homography)
    ctrl_mov = cv2.warpPerspective(ref, r.homography, (w, h), flags=cv2.INTER_LANCZOS4 | cv2.WARP_INVERSE_MAP)
    rc = register(ref, ctrl_mov, distortion=False)
    return {
        "ok": True, "inliers": r.inliers, "rms": r.rms_px,
        "along": float(np.sqrt(np.mean(along ** 2))), "cross": float(np.sqrt(np.mean(cross ** 2))),
        "nn_al": nn_corr(pr, along), "nn_cr": nn_corr(pr, cross), "row": row_explained(pr[:, 1], along),
        "ctrl": rc.rms_px if rc.ok else float("nan"), "ctrl_inl": rc.inliers, "t_px": float(np.hypot(*t)),
    }


def main() -> int:
    paths = seneca_frame_paths()
    with open(paths[0].parent / "frames.csv", newline="") as f:
        meta = {row["file"]: row for row in csv.DictReader(f)}
    print("Inlier residual anatomy, Seneca strip at 1800x1350 (px unless stated)")
    head = (f"{'pair':>4s} {'inl':>4s} {'rms':>6s} {'along':>6s} {'cross':>6s} {'nn.al':>6s} {'nn.cr':>6s} {'row':>5s} "
            f"{'ctrl':>6s} {'c.inl':>5s} {'B m':>6s} {'|t| px':>7s} {'H m':>6s} {'px/cm':>6s} {'view':>5s}")
    print(head)
    print("-" * len(head))
    allr = []
    for i in range(len(paths) - 1):
        a, b = cv2.imread(str(paths[i])), cv2.imread(str(paths[i + 1]))
        s = anatomy(a, b)
        if not s["ok"]:
            print(f"{i:4d} failed: {s['reason']}")
            continue
        m0, m1 = meta[paths[i].name], meta[paths[i + 1].name]
        east, north = enu_offset_m(float(m0["latitude_deg"]), float(m0["longitude_deg"]),
                                   float(m1["latitude_deg"]), float(m1["longitude_deg"]))
        base = float(np.hypot(east, north))
        height = base * FOCAL_M / (s["t_px"] * PITCH_HALF_M)
        s["pxcm"] = s["t_px"] * 0.01 / height
        s["view"] = float(np.degrees(2 * np.arctan(base / (2 * height))))
        allr.append(s)
        print(f"{i:4d} {s['inliers']:4d} {s['rms']:6.3f} {s['along']:6.3f} {s['cross']:6.3f} {s['nn_al']:6.2f} "
              f"{s['nn_cr']:6.2f} {s['row']:5.2f} {s['ctrl']:6.3f} {s['ctrl_inl']:5d} {base:6.1f} {s['t_px']:7.1f} "
              f"{height:6.1f} {s['pxcm']:6.3f} {s['view']:5.1f}")
    if allr:
        med = {k: float(np.median([s[k] for s in allr])) for k in ("rms", "along", "cross", "nn_al", "nn_cr", "row", "ctrl", "pxcm", "view")}
        print(f"median: rms {med['rms']:.3f}, along {med['along']:.3f}, cross {med['cross']:.3f}, nn corr along "
              f"{med['nn_al']:.2f} / cross {med['nn_cr']:.2f}, row-explained {med['row']:.2f}, control {med['ctrl']:.3f} px; "
              f"1 cm of relief = {med['pxcm']:.3f} px of parallax along the baseline; lines of sight {med['view']:.0f} deg apart")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
