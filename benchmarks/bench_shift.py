"""Sub-pixel shift: accuracy and speed of subpix_ros against the reference methods.

One run, one table: the paper's single solve ("seed"), the seed iterated 3x
with INTER_CUBIC warps, skimage phase_cross_correlation(upsample_factor=100),
cv2.phaseCorrelate (float32, Hanning window), cv2.findTransformECC (MOTION_TRANSLATION,
default Gaussian 5) and ours (subpix_ros.core.shift.estimate_shift).

Accuracy: pairs rendered by subpix_ros.core.render from the four real Seneca
crops (768 px full resolution, factor 4 -> 176 px LR frames after the 8 px
margin) with exactly known shifts:
  A  |s| <= 1 px, SNR 40 dB, optics blur 0.5 LR px
  B  |s| <= 1 px, SNR 40 dB, optics blur 0.3 LR px (strong aliasing)
  C  |s| <= 1 px, noise sigma 10 DN, blur 0.4, fresh noise on BOTH frames of
     every pair (a reference shared by many pairs would make its one noise
     draw a common error of all of them): RMSE / Cramer-Rao bound. /CRB:
     2 sigma^2 J^-1 per pair, J the gradient energy matrix of the noise-free
     reference (spectral gradients = exact derivative of the band-limited
     frame; checked against finite differences of the renderer) over the
     whole frame; /CRBc: the same over the frame less a 5 px border (the
     pixels ours can use); /CRBw: the variance of the best frequency-weighted
     (gradient / cross-correlation) estimator, i.e. with the ideal weight
     P/(2 P n + n^2) computed from the noise-free spectrum P (n the noise
     power per frequency), a weight no estimator that does not know the
     scene has: estimators of this family do not reach 2 sigma^2 J^-1 at
     low per-frequency SNR because of the noise-times-noise term of the two
     noisy frames (ideal periodic frames, same weights: see shift.py).
  D  |s| <= 4 px, SNR 40 dB, blur 0.4
  E  as A with blur 0.4 plus a 0.2 deg rotation between the frames (error of
     the translation at the frame centre; ours also reports the misfit flag)
RMSE is over both axes; bias is the largest |mean error| over 5 bins of the
fractional part of the true shift per axis (needs many pairs per bin).

Speed: median and best wall time (and median process CPU time, all threads)
per pair at 1920x1080 and 3840x2160 (uint8
input, conversion included), pairs rendered from the full-resolution Seneca
originals in /work/shared/data/seneca when present, otherwise from the
bundled half-resolution frames upscaled. Methods are timed interleaved so a
loaded machine slows all of them alike.

Usage: python benchmarks/bench_shift.py [--quick] [--no-speed] [--no-accuracy]
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from subpix_ros.core.evaluate import max_bin_bias  # noqa: E402
from subpix_ros.core.render import fourier_shift_blur, render_frame, render_sequence  # noqa: E402
from subpix_ros.core.shift import estimate_shift  # noqa: E402
from subpix_ros.data import CROP_NAMES, load_crop, seneca_frame_paths  # noqa: E402
from subpix_ros.runtime import add_malloc_argument, allocator_line  # noqa: E402

try:
    from skimage.registration import phase_cross_correlation
except ImportError:  # pragma: no cover
    phase_cross_correlation = None

FULLRES = Path("/work/shared/data/seneca")


# ---------------------------------------------------------------------------
# the methods: each takes (reference uint8, moving uint8) and returns (u, v) or None
# ---------------------------------------------------------------------------


def m_seed(r, m):
    res = estimate_shift(r, m, method="seed")
    return (res.u, res.v) if res.ok else None


def m_seed_it(r, m):
    res = estimate_shift(r, m, method="seed-iterated")
    return (res.u, res.v) if res.ok else None


def m_skimage(r, m):
    sh, _, _ = phase_cross_correlation(r, m, upsample_factor=100)
    return (-float(sh[0]), -float(sh[1]))  # skimage: shift registering moving onto reference


_WIN = {}


def m_phasecorr(r, m):
    rf = r.astype(np.float32)  # float32: twice as fast as float64 here, same answer
    mf = m.astype(np.float32)
    key = rf.shape
    if key not in _WIN:
        _WIN[key] = cv2.createHanningWindow((rf.shape[1], rf.shape[0]), cv2.CV_32F)
    (dx, dy), _ = cv2.phaseCorrelate(rf, mf, _WIN[key])
    return (dy, dx)


def m_ecc(r, m):
    W = np.eye(2, 3, dtype=np.float32)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-6)
    try:
        _, W = cv2.findTransformECC(r, m, W, cv2.MOTION_TRANSLATION, crit, None, 5)
    except cv2.error:
        return None
    return (float(W[1, 2]), float(W[0, 2]))


def m_ours_fixed(r, m):
    res = estimate_shift(r, m, prefilter_sigma=0.8)
    return (res.u, res.v) if res.ok else None


def m_ours(r, m):
    res = estimate_shift(r, m)
    return (res.u, res.v) if res.ok else None


METHODS = [
    ("seed (paper, 1 solve)", m_seed),
    ("seed iterated x3 (cubic)", m_seed_it),
    ("skimage pcc upsample 100", m_skimage),
    ("cv2.phaseCorrelate", m_phasecorr),
    ("cv2.findTransformECC", m_ecc),
    ("subpix_ros (ours)", m_ours),
]


# ---------------------------------------------------------------------------
# rendered accuracy sets
# ---------------------------------------------------------------------------


def render_set(n_per_crop, max_shift, blur, seed, snr_db=None, noise=0.0, clean=False):
    rng = np.random.default_rng(seed)
    out = []
    for ci, name in enumerate(CROP_NAMES):
        hr = load_crop(name)
        sh = rng.uniform(-max_shift, max_shift, (n_per_crop, 2))
        shifts = [(0.0, 0.0)] + [tuple(s) for s in sh]
        seq = render_sequence(
            hr, 4, shifts, blur_sigma=blur, snr_db=snr_db, noise_sigma=noise, seed=seed + ci
        )
        cref = None
        if clean:
            cref = render_sequence(
                hr, 4, shifts[:1], blur_sigma=blur, seed=seed + ci, quantize=False
            ).frames[0]
        for i in range(n_per_crop):
            out.append((seq.frames[0], seq.frames[i + 1], sh[i], cref))
    return out


def render_noisy_set(n_per_crop, max_shift, blur, seed, noise):
    """Return pairs with fresh noise on both frames; the clean reference is kept.

    The noise model of render_frame: Gaussian, rounded, clipped to uint8.
    """
    rng = np.random.default_rng(seed)
    out = []

    def noisy(a):
        return np.clip(np.rint(a + rng.normal(0.0, noise, a.shape)), 0, 255).astype(np.uint8)

    for ci, name in enumerate(CROP_NAMES):
        hr = load_crop(name)
        sh = rng.uniform(-max_shift, max_shift, (n_per_crop, 2))
        seq = render_sequence(
            hr,
            4,
            [(0.0, 0.0)] + [tuple(x) for x in sh],
            blur_sigma=blur,
            seed=seed + ci,
            quantize=False,
        )
        cref = seq.frames[0]
        for i in range(n_per_crop):
            out.append((noisy(cref), noisy(seq.frames[i + 1]), sh[i], cref))
    return out


def render_rotated(n_per_crop, seed, angle=0.2, blur=0.4):
    rng = np.random.default_rng(seed)
    out = []
    for name in CROP_NAMES:
        hr = load_crop(name).astype(np.float64)
        h, w = hr.shape
        for _ in range(n_per_crop):
            a = angle * rng.choice([-1.0, 1.0])
            sh = rng.uniform(-1, 1, 2)
            M = cv2.getRotationMatrix2D(((w - 1) / 2, (h - 1) / 2), a, 1.0)
            rot = cv2.warpAffine(
                hr, M, (w, h), flags=cv2.INTER_LANCZOS4, borderMode=cv2.BORDER_REFLECT
            )
            r = render_frame(hr, 4, (0.0, 0.0), blur, 0.5, rng)[8:-8, 8:-8]
            m = render_frame(rot, 4, tuple(sh), blur, 0.5, rng)[8:-8, 8:-8]
            out.append((r, m, sh, None))
    return out


def fft_gradients(a, pad=32):
    p = np.pad(np.asarray(a, np.float64), pad, mode="reflect")
    F = np.fft.fft2(p)
    ky = np.fft.fftfreq(p.shape[0])[:, None]
    kx = np.fft.fftfreq(p.shape[1])[None, :]
    return (
        np.fft.ifft2(F * 2j * np.pi * ky).real[pad:-pad, pad:-pad],
        np.fft.ifft2(F * 2j * np.pi * kx).real[pad:-pad, pad:-pad],
    )


def central_gradients(a):
    """Central differences (np.gradient): the common shortcut for J, looser than the bound."""
    return np.gradient(np.asarray(a, np.float64))


def crb_diag(clean, sigma, border=0, gradients=fft_gradients):
    """Return the shift variance bound diag(2 sigma^2 J^-1).

    J is the gradient energy matrix of the noise-free frame (``gradients``: spectral by default),
    over the frame minus ``border`` px on each side.
    """
    g0, g1 = gradients(clean)
    if border:
        g0, g1 = g0[border:-border, border:-border], g1[border:-border, border:-border]
    J = np.array([[np.sum(g0 * g0), np.sum(g0 * g1)], [np.sum(g0 * g1), np.sum(g1 * g1)]])
    return np.diag(2.0 * sigma**2 * np.linalg.inv(J))


_WBOUND = {}


def crb_weighted_factor(clean, sigma):
    """Per-axis ratio (unknown-scene bound) / (2 sigma^2 J^-1) for one noise-free frame.

    On the mirrored (periodic, jump-free) frame with DFT power P(k) and noise
    power n = N sigma^2 per frequency: the optimally weighted second-order
    estimator has information sum w w^T P^2 / (2 P n + n^2), which tends to
    J / (2 sigma^2) (J = sum w w^T P / N) where P >> n.
    """
    key = id(clean)
    if key not in _WBOUND:
        c = np.asarray(clean, np.float64) - float(np.mean(clean))
        m = np.block([[c, c[:, ::-1]], [c[::-1], c[::-1, ::-1]]])
        N = m.size
        F = np.fft.fft2(m)
        P = F.real**2 + F.imag**2
        wy = 2 * np.pi * np.fft.fftfreq(m.shape[0])[:, None]
        wx = 2 * np.pi * np.fft.fftfreq(m.shape[1])[None, :]
        n = N * sigma**2
        ww = (wy, wx)
        J = np.array([[np.sum(ww[i] * ww[j] * P) for j in (0, 1)] for i in (0, 1)]) / N
        Iw = np.array(
            [[np.sum(ww[i] * ww[j] * P * P / (2 * P * n + n * n)) for j in (0, 1)] for i in (0, 1)]
        )
        _WBOUND[key] = np.diag(np.linalg.inv(Iw)) / np.diag(2 * sigma**2 * np.linalg.inv(J))
    return _WBOUND[key]


def evaluate(pairs, fn):
    est, fails = [], 0
    for r, m, _, _ in pairs:
        try:
            e = fn(r, m)
        except Exception:  # noqa: BLE001 - a reference method failing counts as a failure
            e = None
        if e is None:
            fails += 1
            est.append((np.nan, np.nan))
        else:
            est.append(e)
    est = np.array(est, dtype=np.float64)
    truth = np.array([p[2] for p in pairs])
    return est - truth, truth, fails


def accuracy(quick: bool):
    k = 4 if quick else 1
    sets = {
        "A": ("|s|<=1, 40 dB, blur 0.5", render_set(60 // k, 1.0, 0.5, 11, snr_db=40.0)),
        "B": ("|s|<=1, 40 dB, blur 0.3", render_set(60 // k, 1.0, 0.3, 22, snr_db=40.0)),
        "C": (
            "|s|<=1, noise 10 DN (fresh on both frames), blur 0.4",
            render_noisy_set(60 // k, 1.0, 0.4, 33, 10.0),
        ),
        "D": ("|s|<=4, 40 dB, blur 0.4", render_set(30 // k, 4.0, 0.4, 44, snr_db=40.0)),
        "E": ("rotation 0.2 deg, blur 0.4", render_rotated(10 // k, 55)),
    }
    cache = {}
    for p in sets["C"][1]:
        if id(p[3]) not in cache:
            cache[id(p[3])] = (
                crb_diag(p[3], 10.0),
                crb_diag(p[3], 10.0, 5),
                crb_weighted_factor(p[3], 10.0),
            )
    crb = np.array([cache[id(p[3])][0] for p in sets["C"][1]])
    crb_in = np.array([cache[id(p[3])][1] for p in sets["C"][1]])
    crb_w = np.array([cache[id(p[3])][0] * cache[id(p[3])][2] for p in sets["C"][1]])
    print("\nAccuracy on rendered real-texture pairs (176x176 px LR; errors in px)")
    for key, (desc, pairs) in sets.items():
        print(f"  set {key}: {desc}: {len(pairs)} pairs")
    head = f"{'method':26s} | {'A rmse':>7s} {'A bias':>7s} | {'B rmse':>7s} {'B bias':>7s} | {'C rmse':>7s} {'/CRB':>5s} {'/CRBc':>5s} {'/CRBw':>5s} | {'D rmse':>7s} | {'E rmse':>7s} | fails"
    print(head)
    print("-" * len(head))
    for name, fn in METHODS[:-1] + [("ours, fixed prefilter 0.8", m_ours_fixed)] + METHODS[-1:]:
        if fn is m_skimage and phase_cross_correlation is None:
            continue
        row = {}
        fails = 0
        for key, (_, pairs) in sets.items():
            err, truth, f = evaluate(pairs, fn)
            fails += f
            ok = np.all(np.isfinite(err), axis=1)
            e = err[ok]
            row[key] = (
                float(np.sqrt(np.mean(e**2))) if len(e) else float("nan"),
                max_bin_bias(e, truth[ok])[0] if len(e) else float("nan"),
            )
            if key == "C":
                row["crb"] = (
                    float(np.sqrt(np.mean(e**2) / np.mean(crb[ok]))) if len(e) else float("nan")
                )
                row["crb_in"] = (
                    float(np.sqrt(np.mean(e**2) / np.mean(crb_in[ok]))) if len(e) else float("nan")
                )
                row["crb_w"] = (
                    float(np.sqrt(np.mean(e**2) / np.mean(crb_w[ok]))) if len(e) else float("nan")
                )
        print(
            f"{name:26s} | {row['A'][0]:7.4f} {row['A'][1]:7.4f} | {row['B'][0]:7.4f} {row['B'][1]:7.4f} | "
            f"{row['C'][0]:7.4f} {row['crb']:5.2f} {row['crb_in']:5.2f} {row['crb_w']:5.2f} | {row['D'][0]:7.4f} | {row['E'][0]:7.4f} | {fails}"
        )
    print(
        f"  bounds (rms per axis) for set C: {math.sqrt(float(np.mean(crb))):.4f} px = 2 sigma^2 J^-1 over the whole "
        f"176x176 frame (/CRB), {math.sqrt(float(np.mean(crb_in))):.4f} px over the central 166x166 px (/CRBc, the pixels "
        f"ours uses), {math.sqrt(float(np.mean(crb_w))):.4f} px unknown-scene bound with the ideal weighting (/CRBw)"
    )
    resC = [estimate_shift(r, m) for r, m, _, _ in sets["C"][1]]
    errC = np.array([(x.u - t[0], x.v - t[1]) for x, (_, _, t, _) in zip(resC, sets["C"][1])])
    stdC = np.array([(x.u_std, x.v_std) for x in resC])
    crb_cd = np.array([crb_diag(p[3], 10.0, gradients=central_gradients) for p in sets["C"][1]])
    print(
        f"  ours on set C with J from central differences of the noise-free frame instead (the np.gradient shortcut: "
        f"J {float(np.mean(crb) / np.mean(crb_cd)):.2f}x the exact one, sin(w) for w): RMSE / that figure "
        f"{math.sqrt(float(np.mean(errC**2)) / float(np.mean(crb_cd))):.2f}. Not a bound (it undercounts the near-Nyquist "
        f"gradient energy the estimator uses), so /CRB above is the target's figure."
    )
    print(
        f"  ours on set C: empirical RMSE / reported std (rms) = "
        f"{math.sqrt(float(np.mean(errC**2)) / float(np.mean(stdC**2))):.3f} (1 = honest); n_pixels {resC[0].n_pixels}"
    )
    res = [estimate_shift(r, m) for r, m, _, _ in sets["E"][1]]
    flagged = sum(x.misfit for x in res)
    print(
        f"  ours on set E: misfit flagged on {flagged}/{len(res)} pairs; median reported std "
        f"{np.median([max(x.u_std, x.v_std) for x in res]):.3f} px; median misfit_px "
        f"{np.median([x.misfit_px for x in res]):.3f}"
    )
    clean = [estimate_shift(r, m) for key in "ABCD" for r, m, _, _ in sets[key][1]]
    print(
        f"  ours on sets A-D: misfit flagged on {sum(x.misfit for x in clean)}/{len(clean)} pure translations; "
        f"not converged {sum(not x.converged for x in clean)}"
    )


# ---------------------------------------------------------------------------
# speed
# ---------------------------------------------------------------------------


def big_pair(w, h, shift=(1.37, -2.61), noise=1.0, seed=1):
    """Return (reference, moving), uint8 w x h, with an exact Fourier shift, ``noise`` DN noise."""
    src = None
    if FULLRES.is_dir() and (FULLRES / "IMG_0464.jpg").is_file():
        src = cv2.imread(str(FULLRES / "IMG_0464.jpg"), cv2.IMREAD_GRAYSCALE)
        origin = "full-resolution original IMG_0464 (3600x2700)"
    if src is None:
        src = cv2.imread(str(seneca_frame_paths()[3]), cv2.IMREAD_GRAYSCALE)
        origin = "bundled half-resolution frame, upscaled"
    if src.shape[1] < w or src.shape[0] < h:
        s = max(w / src.shape[1], h / src.shape[0])
        src = cv2.resize(
            src,
            (int(math.ceil(src.shape[1] * s)), int(math.ceil(src.shape[0] * s))),
            interpolation=cv2.INTER_CUBIC,
        )
        origin += f", resized x{s:.2f}"
    y0 = (src.shape[0] - h) // 2
    x0 = (src.shape[1] - w) // 2
    crop = src[y0 : y0 + h, x0 : x0 + w].astype(np.float64)
    rng = np.random.default_rng(seed)
    ref = np.clip(
        np.rint(fourier_shift_blur(crop, (0, 0), 0.4, pad=16) + rng.normal(0, noise, crop.shape)),
        0,
        255,
    ).astype(np.uint8)
    mov = np.clip(
        np.rint(fourier_shift_blur(crop, shift, 0.4, pad=16) + rng.normal(0, noise, crop.shape)),
        0,
        255,
    ).astype(np.uint8)
    return ref, mov, origin, shift


def speed(quick: bool):
    print("\nSpeed per pair (ms; uint8 input), methods interleaved in one loop")
    reps = {"1080p": 3 if quick else 9, "1080p noisy": 3 if quick else 9, "4K": 2 if quick else 5}
    configs = (
        ("1080p", (1920, 1080), 1.0),
        ("1080p noisy", (1920, 1080), 10.0),
        ("4K", (3840, 2160), 1.0),
    )
    for label, (w, h), noise in configs:
        # noisy: a fresh noise draw per repetition, and the error column is the RMS
        # (over both axes) of the answers on all of them; else one pair
        npairs = reps[label] if noise > 1.0 else 1
        pairs = [big_pair(w, h, noise=noise, seed=1 + i) for i in range(npairs)]
        _, _, origin, truth = pairs[0]
        print(
            f"  {label} {w}x{h} from {origin}; noise {noise:g} DN; true shift {truth}"
            + (f"; {npairs} noise draws" if npairs > 1 else "")
        )
        times = {name: [] for name, _ in METHODS}
        cpu = {name: [] for name, _ in METHODS}
        errs = {name: [] for name, _ in METHODS}
        for name, fn in METHODS:  # warm-up
            fn(pairs[0][0], pairs[0][1])
        for i in range(reps[label]):
            ref, mov = pairs[i % npairs][:2]
            for name, fn in METHODS:
                t0 = time.perf_counter()
                c0 = time.process_time()
                e = fn(ref, mov)
                times[name].append(time.perf_counter() - t0)
                cpu[name].append(time.process_time() - c0)
                if i < npairs:
                    errs[name].append(None if e is None else (e[0] - truth[0], e[1] - truth[1]))
        what = "RMS error (px) over the draws" if npairs > 1 else "error vs true shift (px)"
        print(f"  {'method':26s} | {'median':>8s} {'best':>8s} {'cpu med':>8s} | {what}")
        for name, _ in METHODS:
            ts = np.array(times[name]) * 1e3
            ok = [x for x in errs[name] if x is not None]
            if not ok:
                err = "failed"
            elif npairs > 1:
                err = f"{math.sqrt(float(np.mean(np.square(ok)))):.4f}" + (
                    f" ({len(errs[name]) - len(ok)} failed)" if len(ok) < len(errs[name]) else ""
                )
            else:
                err = f"{math.hypot(*ok[0]):.4f}"
            cm = np.median(cpu[name]) * 1e3
            print(f"  {name:26s} | {np.median(ts):8.1f} {ts.min():8.1f} {cm:8.1f} | {err}")


def main() -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--quick", action="store_true", help="fewer pairs and repetitions")
    ap.add_argument("--no-speed", action="store_true")
    ap.add_argument("--no-accuracy", action="store_true")
    add_malloc_argument(ap)
    args = ap.parse_args()
    print(allocator_line(args.default_malloc))
    try:
        load = os.getloadavg()
        print(
            f"machine: {os.cpu_count()} cores, load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}; "
            f"OpenCV {cv2.__version__} threads {cv2.getNumThreads()}"
        )
    except OSError:
        pass
    if not args.no_accuracy:
        accuracy(args.quick)
    if not args.no_speed:
        speed(args.quick)
    return 0


if __name__ == "__main__":
    sys.exit(main())
