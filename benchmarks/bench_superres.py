"""Super-resolution benchmark: quality and speed tables (issue 5).

Quality: sequences rendered from the four real Seneca crops (optics blur
0.4 LR px, pixel integration, SNR 40 dB, 8 bit), PSNR over the interior
(4*factor px cut) against the sharp HR truth, reported as gain over bicubic
upscaling of the reference frame (dB). Methods: ``map`` (ours, default
settings), ``windowed`` (eq. 7, normalised), ``pinv`` (eq. 6), and a
reference Tikhonov least-squares solution by conjugate gradients
(``scipy.sparse.linalg.cg`` on the same spatial observation operators,
gradient regulariser, weight tuned once on crop_field_edge).

Speed: output sizes from 256^2 to 4K at x2 from 4 frames; best and median of
``--repeats`` runs, in s and s per output MP; ``map`` is the full default
(shift refinement, geometry check, noise and prior estimation: what the
speed target is about), ``map-core`` the Fourier MAP solve alone with given
shifts and noise; the windowed eq. 7, bicubic (``cv2.resize``) and a scipy
CG Tikhonov solution (up to 1 MP) as references in the same run. Then a
least-squares fit ``best time = fixed + slope * MP`` per method: linear in
pixel count means a small fixed per-call cost and a slope close to the
large-size s/MP. Last, the reconstruction node's call (8 aligned 1920x1080
frames with border-strip masks, x2, through ``reconstruct_aligned``).

Run: ``python benchmarks/bench_superres.py [--quick] [--repeats 5] [--only quality|speed|pipeline]``. The
machine's load is printed: timings on a shared machine are noisy (report
the best of several runs).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import cv2
import numpy as np

from subpix_ros.core.render import render_sequence
from subpix_ros.core.superres import bicubic_upscale, psnr, reconstruct
from subpix_ros.core.superres_model import FrameOperator, translation_homography
from subpix_ros.data import CROP_NAMES, load_crop, seneca_frame_paths
from subpix_ros.runtime import add_malloc_argument, allocator_line

FULLRES = Path("/work/shared/data/seneca")


def grid(p):
    return [(a / p, b / p) for a in range(p) for b in range(p)]


def tikhonov_cg(frames, shifts, p, lam, iters=60, blur_sigma=0.4):
    """Solve the reference problem argmin sum ||A_n x - y_n||^2 + lam ||grad x||^2 by scipy CG.

    ``A_n``: the package's operators (pixel box, Gaussian optics of ``blur_sigma`` LR px; 0: none).
    """
    from scipy.sparse.linalg import LinearOperator, cg

    h, w = frames[0].shape
    shape = (h * p, w * p)
    ops = [
        FrameOperator(translation_homography(*s), (h, w), shape, p, p, blur_sigma) for s in shifts
    ]
    lap = np.array([[0, -1, 0], [-1, 4, -1], [0, -1, 0]], float)

    def normal(v):
        x = np.asarray(v, dtype=np.float64).reshape(shape)
        out = lam * cv2.filter2D(x, -1, lap, borderType=cv2.BORDER_REFLECT)
        for op in ops:
            out = out + op.adjoint(op.forward(x))
        return out.ravel()

    b = sum(op.adjoint(np.asarray(f, float) * op.valid) for op, f in zip(ops, frames)).ravel()
    x0 = bicubic_upscale(frames[0], p).ravel()
    sol, _ = cg(
        LinearOperator((b.size, b.size), matvec=normal, dtype=np.float64), b, x0=x0, maxiter=iters
    )
    return sol.reshape(shape)


def gain(seq, img):
    b = 4 * seq.factor
    return psnr(img, seq.truth, b) - psnr(bicubic_upscale(seq.frames[0], seq.factor), seq.truth, b)


def quality(quick: bool) -> None:
    from subpix_ros.core.shift import estimate_shift

    lr2 = 192 if quick else 256
    cases = [
        ("x2, 4 frames, 2x2 grid", 2, lambda k: grid(2), 0.0, False, lr2),
        ("x2, 8 random frames, shifts by estimate_shift", 2, None, 0.0, True, lr2),
        ("x2, 4 grid frames, 0.05 px shift error", 2, lambda k: grid(2), 0.05, False, lr2),
        ("x2, 4 grid frames, 0.10 px shift error", 2, lambda k: grid(2), 0.10, False, lr2),
        ("x3, 9 frames, 3x3 grid", 3, lambda k: grid(3), 0.0, False, 160 if quick else 200),
        ("x4, 16 frames, 4x4 grid", 4, lambda k: grid(4), 0.0, False, 128 if quick else 176),
    ]
    lam = None
    print(
        "\nQuality: PSNR gain over bicubic of the reference frame (dB); per crop "
        + ", ".join(c.replace("crop_", "") for c in CROP_NAMES)
        + "; mean"
    )
    print(f"{'case':48s} {'method':22s} {'gains per crop':30s} {'mean':>6s} {'s/run':>7s}")
    for title, p, shifts_fn, err, estimate, lr in cases:
        rows = {}
        for k, name in enumerate(CROP_NAMES):
            if shifts_fn is None:
                rng = np.random.default_rng(20 + k)
                shifts = [(0.0, 0.0)] + [tuple(rng.uniform(-1, 1, 2)) for _ in range(7)]
            else:
                shifts = shifts_fn(k)
            hr = load_crop(name)[: (lr + 16) * p, : (lr + 16) * p]
            seq = render_sequence(hr, p, shifts, blur_sigma=0.4, snr_db=40, seed=1)
            given = seq.shifts.copy()
            if err:
                noise = np.random.default_rng(100 + k).normal(0, err, given.shape)
                noise[0] = 0
                given = given + noise
            if estimate:
                rs = [estimate_shift(seq.frames[0], f) for f in seq.frames]
                given = np.array([[r.u, r.v] for r in rs])
            runs = {
                "map (ours)": lambda: reconstruct(seq.frames, given, p).image,
                "map, shifts as given": lambda: (
                    reconstruct(seq.frames, given, p, refine_shifts=False).image
                ),
            }
            if shifts_fn is not None and not err:
                runs["windowed eq.7 (norm.)"] = lambda: (
                    reconstruct(seq.frames, given, p, method="windowed").image
                )
                if p == 2:
                    runs["pinv eq.6"] = lambda: (
                        reconstruct(seq.frames, given, p, method="pinv").image
                    )
            if p == 2 and not quick:
                if (
                    lam is None
                ):  # tune the reference's weight once, on the first crop of the first case
                    best = max(
                        (gain(seq, tikhonov_cg(seq.frames, given, p, l)), l)
                        for l in (0.003, 0.01, 0.03, 0.1)
                    )
                    lam = best[1]
                runs[f"tikhonov-cg scipy l={lam}"] = lambda: tikhonov_cg(seq.frames, given, p, lam)
            for mname, fn in runs.items():
                t = time.perf_counter()
                img = fn()
                dt = time.perf_counter() - t
                g = gain(seq, img)
                rows.setdefault(mname, ([], []))
                rows[mname][0].append(g)
                rows[mname][1].append(dt)
        for mname, (gs, ts) in rows.items():
            print(
                f"{title:48s} {mname:22s} {' '.join(f'{g:+6.2f}' for g in gs):30s} {np.mean(gs):+6.2f} {np.mean(ts):7.2f}"
            )


def speed_source(h, w):
    """Return an HR source image of at least h x w (full-resolution original, else bundled)."""
    cands = sorted(FULLRES.glob("IMG_*.jpg")) if FULLRES.is_dir() else []
    src = cv2.imread(str(cands[0] if cands else seneca_frame_paths()[0]), cv2.IMREAD_GRAYSCALE)
    if src.shape[0] < h or src.shape[1] < w:
        scale = max(h / src.shape[0], w / src.shape[1]) * 1.01
        src = cv2.resize(src, None, fx=scale, fy=scale, interpolation=cv2.INTER_CUBIC)
    return src[:h, :w].astype(np.float64), bool(cands)


def speed(quick: bool, repeats: int) -> None:
    sizes = [(256, 256), (512, 512), (1024, 1024), (1080, 1920)] + ([] if quick else [(2160, 3840)])
    print(
        f"\nSpeed: x2 from 4 frames (2x2 grid), best / median of {repeats} runs, seconds and s per output MP"
        f" (load average {os.getloadavg()[0]:.2f} at start)"
    )
    print(
        f"{'output':>11s} {'method':24s} {'best s':>8s} {'median s':>9s} {'best s/MP':>10s} {'med s/MP':>9s}"
    )
    best: dict[str, list[tuple[float, float]]] = {}
    full = False
    for oh, ow in sizes:
        hr, full = speed_source(oh + 32, ow + 32)
        seq = render_sequence(hr, 2, grid(2), blur_sigma=0.4, snr_db=40, seed=1, margin=8)
        frames, sh = seq.frames, seq.shifts
        mp = seq.truth.size / 1e6
        methods = {
            "map (full default)": (lambda: reconstruct(frames, sh, 2), repeats),
            "map-core (given noise)": (
                lambda: reconstruct(
                    frames, sh, 2, refine_shifts=False, geometry="translation", noise_sigma=0.4
                ),
                repeats,
            ),
            "windowed eq.7": (lambda: reconstruct(frames, sh, 2, method="windowed"), repeats),
            "bicubic cv2.resize": (lambda: bicubic_upscale(frames[0], 2), repeats),
        }
        if oh * ow <= 1024 * 1024:  # the scipy reference: 60 CG iterations (fewer runs at 1 MP)
            methods["tikhonov-cg scipy 60it"] = (
                lambda: tikhonov_cg(frames, sh, 2, 0.01),
                repeats if oh * ow <= 512 * 512 else min(repeats, 2),
            )
        for name, (fn, reps) in methods.items():
            ts = []
            for _ in range(reps):
                t = time.perf_counter()
                fn()
                ts.append(time.perf_counter() - t)
            best.setdefault(name, []).append((mp, min(ts)))
            print(
                f"{seq.truth.shape[1]:>5d}x{seq.truth.shape[0]:<5d} {name:24s} {min(ts):8.3f} {np.median(ts):9.3f} "
                f"{min(ts) / mp:10.4f} {np.median(ts) / mp:9.4f}"
            )
    print(
        "(source: full-resolution originals)"
        if full
        else "(source: bundled half-resolution frames, upsampled)"
    )
    print(f"load average {os.getloadavg()[0]:.2f} at end")
    # linearity: least-squares fit best time = fixed + slope * MP over the sizes (fixed: per-call overhead)
    print("\nLinearity: best time = fixed + slope * output MP (least squares over the sizes above)")
    print(f"{'method':24s} {'fixed ms':>9s} {'slope s/MP':>11s} {'max |resid| ms':>15s}")
    for name, pts in best.items():
        if len(pts) < 3:
            continue
        mp_, t_ = np.array(pts).T
        (slope, fixed), *_ = np.linalg.lstsq(
            np.stack([mp_, np.ones_like(mp_)], axis=1), t_, rcond=None
        )
        resid = t_ - (fixed + slope * mp_)
        print(f"{name:24s} {fixed * 1e3:9.1f} {slope:11.4f} {np.abs(resid).max() * 1e3:15.1f}")
    print(
        "targets (issue 5): MAP <= 0.05 s/MP (1920x1080 from 4 frames in ~0.1 s); windowed eq. 7 <= 0.01 s/MP"
    )


def pipeline_case(repeats: int) -> None:
    """Time the reconstruction node's call: 8 aligned 1080p frames, strip masks, x2 (4K out)."""
    from subpix_ros.core.superres_masks import reconstruct_aligned

    h, w = 1080, 1920
    rng = np.random.default_rng(7)
    hr, full = speed_source(2 * (h + 16) + 8, 2 * (w + 16) + 8)
    shifts = [(0.0, 0.0)] + [tuple(rng.uniform(-0.5, 0.5, 2)) for _ in range(7)]
    seq = render_sequence(hr, 2, shifts, blur_sigma=0.4, snr_db=40, seed=1, margin=8)
    frames = [f[:h, :w] for f in seq.frames]
    masks = [np.ones((h, w), bool)]
    for _ in range(7):  # integer alignment leaves invalid strips along two borders
        m = np.ones((h, w), bool)
        a, b = rng.integers(1, 12, 2)
        m[(slice(0, a) if rng.random() < 0.5 else slice(h - a, h))] = False
        m[:, (slice(0, b) if rng.random() < 0.5 else slice(w - b, w))] = False
        masks.append(m)
    print(
        f"\nPipeline case (reconstruction_node): reconstruct_aligned, 8 aligned {w}x{h} frames with strip masks, x2 "
        f"-> {2 * w}x{2 * h}; best / median of {repeats} (load average {os.getloadavg()[0]:.2f})"
    )
    cut = (slice(16, 2 * h - 16), slice(16, 2 * w - 16))
    base = psnr(bicubic_upscale(frames[0], 2)[cut], seq.truth[: 2 * h, : 2 * w][cut])
    for name, fr in (
        ("mono", frames),
        ("BGR (luminance SR)", [cv2.cvtColor(f, cv2.COLOR_GRAY2BGR) for f in frames]),
    ):
        ts = []
        for _ in range(repeats):
            t = time.perf_counter()
            r = reconstruct_aligned(fr, np.array(seq.shifts), 2, masks=masks)
            ts.append(time.perf_counter() - t)
        img = (
            r.image
            if r.image.ndim == 2
            else cv2.cvtColor(r.image.astype(np.float32), cv2.COLOR_BGR2GRAY)
        )
        g = psnr(img[cut], seq.truth[: 2 * h, : 2 * w][cut]) - base
        print(
            f"{name:20s} method {r.method:7s} best {min(ts):6.3f} s  median {np.median(ts):6.3f} s  "
            f"{min(ts) / (4 * h * w / 1e6):.4f} s/MP out  gain over bicubic {g:+.2f} dB"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument(
        "--quick", action="store_true", help="smaller images, no scipy reference in quality"
    )
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--only", choices=["quality", "speed", "pipeline"], default=None)
    add_malloc_argument(ap)
    args = ap.parse_args()
    print(allocator_line(args.default_malloc))
    print(
        f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs; OpenCV threads {cv2.getNumThreads()}"
    )
    if args.only in (None, "quality"):
        quality(args.quick)
    if args.only in (None, "speed"):
        speed(args.quick, args.repeats)
    if args.only in (None, "pipeline"):
        pipeline_case(max(2, args.repeats // 2))


if __name__ == "__main__":
    main()
