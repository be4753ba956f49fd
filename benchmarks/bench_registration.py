"""Co-registration benchmark: ours vs ORB+RANSAC vs SIFT+RANSAC (same run, same machine).

Rows: the 8 consecutive pairs of the Seneca strip at half resolution (bundled,
1800x1350) and, when /work/shared/data/seneca (or $SUBPIX_FULLRES) is present,
at full resolution (3600x2700); synthetic pairs with a known homography
(real crops, small rotation + perspective) for the corner transfer error.
Time per pair: best of ``--repeat`` runs (the machine may be shared), images
already decoded; the rows give the median over the pairs (s/pair) and the slowest
pair (s.max). ``ours``: ``register(ref, mov)`` on two arrays (as ``subpix register``: the two
frames are prepared at the same time, in two threads). ``ours,strip``: each frame prepared once (the operational case of a
video stream or a mosaic), per pair = preparing the new frame + registering it to
the prepared previous one, same statistic (the first frame's preparation is listed
separately; it happens once). Inliers / residual: the method's own inlier set (ours:
1.5 px threshold on the full model; ORB/SIFT: RANSAC 3 px) and its RMS.

Tracking rows (``register(..., prior=H)`` with a prepared reference, the video-rate path):
1920x1080 frames made from the bundled pairs (resized to 1920 wide, centre 1080 rows), the
prior = the full result moved by (1.5, -1.0) px; time per frame, tracked vs full.

    python benchmarks/bench_registration.py [--repeat 2] [--no-fullres] [--only tracking|real|synthetic]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from subpix_ros.core.registration import (  # noqa: E402
    apply_h,
    calibrate_distortion,
    prepare_reference,
    register,
)
from subpix_ros.data import CROP_NAMES, load_crop, seneca_frame_paths  # noqa: E402
from subpix_ros.runtime import add_malloc_argument, allocator_line  # noqa: E402

FULLRES = Path(os.environ.get("SUBPIX_FULLRES", "/work/shared/data/seneca"))


def feature_ransac(kind: str, ref: np.ndarray, mov: np.ndarray):
    """ORB or SIFT features, ratio test, cv2.findHomography RANSAC (3 px). Returns (H, inliers, rms)."""
    g0 = ref if ref.ndim == 2 else cv2.cvtColor(ref, cv2.COLOR_BGR2GRAY)
    g1 = mov if mov.ndim == 2 else cv2.cvtColor(mov, cv2.COLOR_BGR2GRAY)
    if kind == "orb":
        det, norm, ratio = cv2.ORB_create(nfeatures=5000), cv2.NORM_HAMMING, 0.8
    else:
        det, norm, ratio = cv2.SIFT_create(), cv2.NORM_L2, 0.75
    k0, d0 = det.detectAndCompute(g0, None)
    k1, d1 = det.detectAndCompute(g1, None)
    if d0 is None or d1 is None:
        return None, 0, None
    m = [
        p[0]
        for p in cv2.BFMatcher(norm).knnMatch(d1, d0, k=2)
        if len(p) == 2 and p[0].distance < ratio * p[1].distance
    ]
    if len(m) < 8:
        return None, 0, None
    src = np.float32([k1[a.queryIdx].pt for a in m])
    dst = np.float32([k0[a.trainIdx].pt for a in m])
    h, mask = cv2.findHomography(src, dst, cv2.RANSAC, 3.0)
    if h is None:
        return None, 0, None
    inl = mask.ravel() > 0
    r = apply_h(h, src[inl].astype(np.float64)) - dst[inl]
    return h, int(inl.sum()), float(np.sqrt(np.mean((r * r).sum(axis=1))))


def run_ours(ref, mov, distortion=True):
    res = register(ref, mov, distortion=distortion)
    if not res.ok:
        return None, 0, None, res
    return res.homography, res.inliers, res.rms_px, res


def timed(fn, repeat):
    best, out = np.inf, None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def real_rows(paths, repeat, label, lam=None):
    ims = [cv2.imread(str(p)) for p in paths]
    rows = []
    methods = [("ours", run_ours)]
    if lam is not None:
        methods.append((f"ours,lam={lam:+.4f}", lambda a, b: run_ours(a, b, distortion=lam)))
    methods += [
        ("ORB+RANSAC", lambda a, b: feature_ransac("orb", a, b)),
        ("SIFT+RANSAC", lambda a, b: feature_ransac("sift", a, b)),
    ]
    for name, fn in methods:
        ok, inl, rms, tt, extra = 0, [], [], [], []
        for i in range(len(ims) - 1):
            t, out = timed(lambda: fn(ims[i], ims[i + 1]), repeat if name != "SIFT+RANSAC" else 1)
            tt.append(t)
            if out[0] is not None:
                ok += 1
                inl.append(out[1])
                rms.append(out[2])
                if name.startswith("ours"):
                    extra.append(out[3].rms_px_projective)
        per_pair = " ".join(f"{v:.2f}" for v in rms)
        if name.startswith("ours"):
            per_pair += "  inl " + " ".join(str(v) for v in inl)
        rows.append(
            (
                label,
                name,
                f"{ok}/{len(ims) - 1}",
                int(np.median(inl)) if inl else 0,
                min(inl) if inl else 0,
                float(np.median(rms)) if rms else float("nan"),
                max(rms) if rms else float("nan"),
                float(np.median(tt)),
                per_pair,
                (float(np.median(extra)) if extra else None),
                float(np.max(tt)),
            )
        )
        if name == "ours":
            r = rows[-1]
            strip, first = strip_time(ims, repeat)
            rows.append(
                (
                    label,
                    "ours,strip",
                    r[2],
                    r[3],
                    r[4],
                    r[5],
                    r[6],
                    float(np.median(strip)),
                    f"(same results; each frame prepared once; first frame's preparation {first:.3f} s, once)",
                    None,
                    float(np.max(strip)),
                )
            )
    return rows


def strip_time(ims, repeat) -> tuple[np.ndarray, float]:
    """Time a strip's registration with each frame prepared once (prepare_reference).

    Per-pair seconds; each prepared frame is used as the
    moving frame of one pair and the reference of the next: pair i costs preparing frame i + 1 plus
    register(prepared i, prepared i + 1) (the steady state of a video stream or a mosaic). Best of
    ``repeat`` per pair, like the from-scratch row, whose median over pairs it is compared with; the first
    frame's preparation (a one-off at the start of the stream) is returned separately (best of repeats).
    """
    per = np.full((repeat, len(ims) - 1), np.inf)
    first = np.inf
    for k in range(repeat):
        t = time.perf_counter()
        prev = prepare_reference(ims[0])
        first = min(first, time.perf_counter() - t)
        for i in range(len(ims) - 1):
            t = time.perf_counter()
            nxt = prepare_reference(ims[i + 1])
            register(prev, nxt)
            per[k, i] = time.perf_counter() - t
            prev = nxt
    return per.min(axis=0), first


def synthetic_pair(hr, h384, noise=1.0, seed=0):
    s = np.array([[2, 0, 0.5], [0, 2, 0.5], [0, 0, 1.0]])
    h = s @ h384 @ np.linalg.inv(s)
    mov = cv2.warpPerspective(
        hr.astype(np.float32),
        h,
        (768, 768),
        flags=cv2.INTER_LANCZOS4 | cv2.WARP_INVERSE_MAP,
        borderMode=cv2.BORDER_REFLECT,
    )
    rng = np.random.default_rng(seed)

    def lr(x):
        y = x.astype(np.float64).reshape(384, 2, 384, 2).mean(axis=(1, 3))
        return np.clip(np.rint(y + rng.normal(0, noise, y.shape)), 0, 255).astype(np.uint8)

    return lr(hr), lr(mov)


def synthetic_rows():
    rng = np.random.default_rng(42)
    corners = np.array([[0, 0], [383, 0], [383, 383], [0, 383]], float)
    cases = []
    for name in CROP_NAMES:
        for k in range(2):
            th = np.deg2rad(rng.uniform(-5, 5))
            c = 191.5
            t = np.array([[1, 0, c], [0, 1, c], [0, 0, 1.0]])
            r = np.array([[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1.0]])
            h = t @ r @ np.linalg.inv(t)
            h[:2, 2] += rng.uniform(-15, 15, 2)
            h[2, :2] = rng.uniform(-3e-5, 3e-5, 2)
            cases.append((name, h, *synthetic_pair(load_crop(name), h, seed=k)))
    rows = []
    for meth in ("ours", "ORB+RANSAC", "SIFT+RANSAC"):
        errs, fails = [], 0
        for name, h, ref, mov in cases:
            if meth == "ours":
                res = register(ref, mov)
                est = res.transfer(corners) if res.ok else None
            else:
                hh, _, _ = feature_ransac("orb" if meth.startswith("ORB") else "sift", ref, mov)
                est = None if hh is None else apply_h(hh, corners)
            if est is None:
                fails += 1
                continue
            errs.append(np.hypot(*(est - apply_h(h, corners)).T).mean())
        rows.append(
            (meth, len(cases) - fails, len(cases), float(np.mean(errs)), float(np.max(errs)))
        )
    return rows


def to_1080p(img: np.ndarray) -> np.ndarray:
    """Make a 1920x1080 frame from a 1800x1350 one: resized to 1920x1440 (area), 1080 centre rows."""
    big = cv2.resize(img, (1920, 1440), interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(big[180:1260])


def tracking_rows(repeat: int, lam: float | None):
    """Tracked (prior, prepared reference) vs full registration of 1080p frames; per setting one row."""
    ims = [to_1080p(cv2.imread(str(p))) for p in seneca_frame_paths()]
    settings = [(n, False) for n in (300, 500, 700)]
    if lam is not None:
        settings.append((500, lam))
    rows = []
    for n_points, dist in settings:
        t_tr, t_full, t_plain, agree, n_tr, n_ok, inl_tr, inl_full = [], [], [], [], 0, 0, [], []
        for i in range(len(ims) - 1):
            a, b = ims[i], ims[i + 1]
            t_plain.append(timed(lambda: register(a, b, distortion=dist, n_points=n_points), 1)[0])
            ref = prepare_reference(a)
            tf, full = timed(lambda: register(ref, b, distortion=dist, n_points=n_points), repeat)
            if not full.ok:
                continue
            n_ok += 1
            t_full.append(tf)
            prior = full.homography.copy()
            prior[:2, 2] += (1.5, -1.0)
            tt, tr = timed(
                lambda: register(ref, b, distortion=dist, n_points=n_points, prior=prior),
                repeat + 1,
            )
            if tr.ok and tr.tracked:
                n_tr += 1
                t_tr.append(tt)
                pm = full.points[:, 2:]
                agree.append(float(np.hypot(*(tr.transfer(pm) - full.transfer(pm)).T).mean()))
                inl_tr.append(tr.inliers)
                inl_full.append(full.inliers)
        rows.append(
            (
                n_points,
                "off" if dist is False else f"{dist:+.4f}",
                n_ok,
                len(ims) - 1,
                n_tr,
                np.median(t_tr) * 1e3 if t_tr else np.nan,
                np.max(t_tr) * 1e3 if t_tr else np.nan,
                np.median(t_full) * 1e3 if t_full else np.nan,
                np.median(t_plain) * 1e3,
                np.median(inl_tr) if inl_tr else 0,
                np.median(inl_full) if inl_full else 0,
                np.median(agree) if agree else np.nan,
                np.max(agree) if agree else np.nan,
            )
        )
    return rows


def print_tracking(rows) -> None:
    print(
        "\nTracking path, 1920x1080 (prior = full result + (1.5, -1.0) px; prepared reference; ms/frame, best of repeats)"
    )
    print(
        f"{'n_points':>8s} {'lambda':>8s} {'full ok':>7s} {'tracked':>7s} {'trk med':>8s} {'trk max':>8s} "
        f"{'full(prep)':>10s} {'full':>7s} {'inl trk':>7s} {'inl full':>8s} {'|trk-full| med':>14s} {'max':>6s}"
    )
    for r in rows:
        print(
            f"{r[0]:8d} {r[1]:>8s} {r[2]:>3d}/{r[3]:<3d} {r[4]:>3d}/{r[2]:<3d} {r[5]:8.1f} {r[6]:8.1f} {r[7]:10.1f} {r[8]:7.1f} "
            f"{r[9]:7.0f} {r[10]:8.0f} {r[11]:14.3f} {r[12]:6.3f}"
        )
    print("(|trk-full|: mean transfer difference over the full result's inlier tie points, px)")


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--no-fullres", action="store_true")
    ap.add_argument(
        "--only", choices=["tracking", "real", "synthetic"], help="run one section only"
    )
    add_malloc_argument(ap)
    a = ap.parse_args()
    print(
        f"cv2 {cv2.__version__}, numpy {np.__version__}, {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}"
    )
    print(allocator_line(a.default_malloc))
    if a.only == "tracking":
        print_tracking(tracking_rows(a.repeat, None))
        print(f"load average at the end {os.getloadavg()[0]:.1f}")
        return 0
    if a.only == "synthetic":
        print_synthetic()
        return 0
    # One radial-distortion calibration for the camera (same for every frame): pooled over the
    # per-pair registrations of the bundled strip (in-sample), lambda is resolution-independent.
    ims = [cv2.imread(str(p)) for p in seneca_frame_paths()]
    lam = calibrate_distortion([register(ims[i], ims[i + 1]) for i in range(len(ims) - 1)])
    print(
        f"shared calibration: division-model lambda {lam:+.5f} (pooled over the 8 half-resolution pairs)"
    )
    rows = real_rows(seneca_frame_paths(), a.repeat, "1800x1350", lam)
    full = sorted(FULLRES.glob("IMG_*.jpg")) if FULLRES.is_dir() else []
    if full and not a.no_fullres:
        rows += real_rows(
            full, a.repeat, "3600x2700", lam
        )  # best of repeats, as at half resolution
    print(
        "\nReal consecutive Seneca pairs (inliers: method's own inlier set; rms: inlier RMS residual, px)"
    )
    print(
        f"{'size':10s} {'method':16s} {'ok':>5s} {'inl.med':>7s} {'inl.min':>7s} {'rms.med':>7s} {'rms.max':>7s} {'s/pair':>7s} "
        f"{'s.max':>6s}  per-pair rms (ours: and inliers)"
    )
    for r in rows:
        print(
            f"{r[0]:10s} {r[1]:16s} {r[2]:>5s} {r[3]:7d} {r[4]:7d} {r[5]:7.3f} {r[6]:7.3f} {r[7]:7.3f} {r[10]:6.3f}  {r[8]}"
            + (f"   (ours, projective part only: rms.med {r[9]:.3f})" if r[9] is not None else "")
        )
    if a.only == "real":
        print(f"load average at the end {os.getloadavg()[0]:.1f}")
        return 0
    print_synthetic()
    print_tracking(tracking_rows(a.repeat, lam))
    print(f"load average at the end {os.getloadavg()[0]:.1f}")
    return 0


def print_synthetic() -> None:
    print(
        "\nSynthetic pairs, known homography (4 real crops x 2, rotation +-5 deg, perspective, 384x384, 1 DN noise)"
    )
    print(f"{'method':12s} {'ok':>6s} {'corner err mean':>16s} {'max':>8s}")
    for m, ok, n, e, emax in synthetic_rows():
        print(f"{m:12s} {ok:>3d}/{n:<2d} {e:16.4f} {emax:8.4f}")


if __name__ == "__main__":
    sys.exit(main())
