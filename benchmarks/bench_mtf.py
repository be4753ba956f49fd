"""MTF benchmark: slanted-edge accuracy vs analytic MTFs, and the paper's evaluation (issue 5).

1. Accuracy: pixel-integrated edges with a known Gaussian blur at several
   angles, blurs and noise levels; MTF50/MTF30 error vs the analytic
   ``exp(-2 pi^2 s^2 f^2) |sinc(f cos a) sinc(f sin a)|`` (cycles/pixel), and
   the time per measurement.
2. Paper evaluation (METHODS.md B): a slanted-edge target pasted into a real
   field crop, rendered through the degradation (blur 0.4 LR px, pixel
   integration, SNR 40 dB, 8 bit) at x2/x3/x4 on full sub-pixel grids,
   reconstructed; MTF30 in cycles per INPUT pixel of one input frame,
   bicubic, the windowed eq. 7, our MAP, and the optics-blurred HR truth
   (the physical ceiling). Gain = MTF30(reconstruction) / MTF30(input) - 1
   (the paper reports 52-57 % at x2 on real data, theory 67 %).

Run: ``python benchmarks/bench_mtf.py``.
"""

from __future__ import annotations

import os
import time

import numpy as np
from scipy.special import erf

from subpix_ros.core.evaluate import mtf30_evaluation
from subpix_ros.core.mtf import gaussian_pixel_mtf, mtf_crossing, slanted_edge_mtf
from subpix_ros.data import load_crop


def edge_image(h, w, angle_deg, sigma, ss=8, noise=0.0, seed=0):
    th = np.deg2rad(angle_deg)
    sub = (np.arange(ss) + 0.5) / ss - 0.5
    r = np.arange(h)[:, None, None, None] + sub[None, None, :, None] - h / 2
    c = np.arange(w)[None, :, None, None] + sub[None, None, None, :] - w / 2
    d = c * np.cos(th) - r * np.sin(th)
    img = 50 + 150 * (0.5 * (1 + erf(d / (np.sqrt(2) * sigma)))).mean(axis=(2, 3))
    if noise:
        img = np.clip(
            np.rint(img + np.random.default_rng(seed).normal(0, noise, img.shape)), 0, 255
        )
    return img


def accuracy(seeds: int = 5) -> None:
    print(
        "\nSlanted-edge accuracy vs analytic Gaussian x pixel aperture (cycles/pixel), 100x80 ROI, 8 bit;"
    )
    print(f"noisy rows (1 DN): the mean and the worst |error| over {seeds} noise seeds")
    print(
        f"{'angle':>6s} {'sigma':>6s} {'noise':>6s} {'MTF50':>7s} {'true':>7s} {'err':>8s} {'worst':>7s} {'MTF30':>7s} "
        f"{'true':>7s} {'err':>8s} {'worst':>7s} {'ms':>6s}"
    )
    f = np.linspace(0, 1, 4001)
    worst = {}
    for angle in (2.5, 5.0, 8.0, 15.0, 30.0):
        for sigma in (0.3, 0.4, 0.5, 0.8, 1.2):
            for noise in (0.0, 1.0):
                ref = gaussian_pixel_mtf(f, sigma, angle)
                a50, a30 = mtf_crossing(f, ref, 0.5), mtf_crossing(f, ref, 0.3)
                m50, m30, ms = [], [], []
                for seed in range(seeds if noise else 1):
                    img = edge_image(100, 80, angle, sigma, noise=noise, seed=seed)
                    t = time.perf_counter()
                    r = slanted_edge_mtf(img)
                    ms.append((time.perf_counter() - t) * 1e3)
                    m50.append(r.mtf50)
                    m30.append(r.mtf30)
                e50, e30 = np.array(m50) - a50, np.array(m30) - a30
                w50, w30 = np.abs(e50).max(), np.abs(e30).max()
                key = noise > 0
                worst[key] = max(worst.get(key, 0.0), w50, w30)
                print(
                    f"{angle:6.1f} {sigma:6.2f} {noise:6.1f} {np.mean(m50):7.4f} {a50:7.4f} {e50.mean():+8.4f} {w50:7.4f} "
                    f"{np.mean(m30):7.4f} {a30:7.4f} {e30.mean():+8.4f} {w30:7.4f} {np.median(ms):6.1f}"
                )
    print(
        f"worst |error| noise-free {worst[False]:.4f}, with 1 DN noise {worst[True]:.4f} "
        "cycles/pixel (blur 0.3-1.2 px; target <= 0.01)"
    )


def paper_evaluation() -> None:
    print(
        "\nPaper evaluation: MTF30 in cycles per input pixel (slanted-edge target in a real field crop)"
    )
    print(
        f"{'factor':>6s} {'input':>7s} {'bicubic':>8s} {'windowed':>9s} {'map':>7s} {'ceiling':>8s} "
        f"{'gain map':>9s} {'gain win':>9s} {'map/ceil':>9s}"
    )
    for p in (2, 3, 4):
        r = mtf30_evaluation(load_crop("crop_field_edge"), p, lr=160, methods=("map", "windowed"))
        m_in, m_ceil, m_bic, m_map, m_win = (
            r["input"],
            r["ceiling"],
            r["bicubic"],
            r["map"],
            r["windowed"],
        )
        print(
            f"{'x' + str(p):>6s} {m_in:7.3f} {m_bic:8.3f} {m_win:9.3f} {m_map:7.3f} {m_ceil:8.3f} "
            f"{100 * (m_map / m_in - 1):8.0f}% {100 * (m_win / m_in - 1):8.0f}% {100 * m_map / m_ceil:8.0f}%"
        )


def main() -> None:
    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs")
    accuracy()
    paper_evaluation()


if __name__ == "__main__":
    main()
