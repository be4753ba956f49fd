#!/usr/bin/env python3
"""Memory and CPU of one set's reconstruction, whole and within a budget (issue 22).

The pipeline's set: ``--set`` 1920x1080 bgr8 frames (bench_pipeline.make_frames,
drifting by (0.41, 0.27) px per frame, shifts known), x2 MAP, translation
geometry, shifts as given. Each row runs ``--repeat`` times after one warm-up
call; printed per row: process CPU s per set, peak traced allocation
(tracemalloc, numpy and OpenCV outputs; a separate call), minor page faults
per set (fresh memory the kernel maps in), and the difference to the whole
reconstruction (interior, 64 LR px from the edges: RMS and max, DN) next to
the SR detail itself (RMS of whole - bicubic).

Rows:

* ``whole``: :func:`reconstruct_aligned` as the reconstruction node calls it;
* ``budget B``: :func:`reconstruct_within_budget` with ``max_memory_mb=B`` and the output
  in the frames' type, as the reconstruction stage calls it;
* ``(patch) ...``: the same with a change to ``superres.py`` applied by
  monkeypatching in this process only, to measure what it would give:
  ``shared prior`` (every tile given the whole set's spectrum prior and noise
  level instead of fitting its own).

Usage: python benchmarks/bench_reconstruction_memory.py [--set 16] [--size 1920x1080] [--repeat 2]
       [--budgets 600 400 250] [--default-malloc]
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
from bench_pipeline import STEP, make_frames  # noqa: E402

from subpix_ros.core import superres  # noqa: E402
from subpix_ros.core.superres import fourier_map  # noqa: E402
from subpix_ros.core.superres.budget import reconstruct_within_budget  # noqa: E402
from subpix_ros.core.superres.masks import reconstruct_aligned  # noqa: E402
from subpix_ros.runtime import add_malloc_argument, allocator_line  # noqa: E402

KW = dict(method="map", geometry="translation", refine_shifts=False)


def measure(fn, repeat: int) -> tuple[float, float, float, np.ndarray]:
    """(CPU s per call, peak traced MB, minor faults per call, image)."""
    img = fn()  # warm-up (caches, first-use allocations)
    f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    t0 = time.process_time()
    for _ in range(repeat):
        img = fn()
    cpu = (time.process_time() - t0) / repeat
    faults = (resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0) / repeat
    del img
    tracemalloc.start()
    img = fn()
    peak = tracemalloc.get_traced_memory()[1] / 1e6
    tracemalloc.stop()
    return cpu, peak, faults, img


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--set", type=int, default=16)
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--budgets", type=float, nargs="*", default=[600, 400, 250])
    add_malloc_argument(ap)
    args = ap.parse_args()
    print(allocator_line(args.default_malloc))
    w, h = (int(v) for v in args.size.lower().split("x"))
    frames = make_frames(args.set, w, h)
    shifts = np.array([[k * STEP[0], k * STEP[1]] for k in range(args.set)])
    rows = []

    def row(name, fn, plan_of=None):
        cpu, peak, faults, img = measure(fn, args.repeat)
        rows.append((name, cpu, peak, faults, img, plan_of))

    row("whole", lambda: reconstruct_aligned(frames, shifts, 2, **KW).image)
    whole = rows[0][4]
    bic = superres.bicubic_upscale(frames[0].astype(np.float32), 2)
    plans = {}
    for b in args.budgets:

        def run(b=b):
            # tiles rounded into the frames' type as they are placed, as the reconstruction stage
            # asks (the plan counts the output at 1 B per value for uint8)
            res, plans[b] = reconstruct_within_budget(
                frames, shifts, 2, max_memory_mb=b, out_dtype=frames[0].dtype, **KW
            )
            return res.image

        row(f"budget {b:g} MB", run, b)
    # shared prior: the whole set's fit_spectrum result and noise level given to every tile
    orig_fit = fourier_map.fit_spectrum
    fits = []
    fourier_map.fit_spectrum = lambda *a, **k: fits.append(orig_fit(*a, **k)) or fits[-1]
    noise = reconstruct_aligned(frames, shifts, 2, **KW).noise_sigma
    fourier_map.fit_spectrum = lambda *a, **k: fits[-1]
    try:
        for b in args.budgets[-1:]:

            def run_shared(b=b):
                return reconstruct_within_budget(
                    frames,
                    shifts,
                    2,
                    max_memory_mb=b,
                    noise_sigma=noise,
                    out_dtype=frames[0].dtype,
                    **KW,
                )[0].image

            row(f"(patch) shared prior, budget {b:g} MB", run_shared)
    finally:
        fourier_map.fit_spectrum = orig_fit

    m = 64 * 2
    inner = (slice(m, -m), slice(m, -m))
    detail = float(np.sqrt(np.mean((whole[inner] - bic[inner]) ** 2)))
    print(
        f"\n{args.set} frames {w}x{h} bgr8 -> x2, MAP (load average {os.getloadavg()[0]:.1f} on "
        f"{os.cpu_count()} CPUs); SR detail (whole - bicubic, interior RMS) {detail:.3f} DN"
    )
    print(
        "| run | plan | process CPU s per set | peak traced MB | minor faults per set | "
        "interior diff to whole RMS / max DN |"
    )
    print("|---|---|---|---|---|---|")
    for name, cpu, peak, faults, img, b in rows:
        d = np.abs(img[inner].astype(np.float64) - whole[inner])
        plan = plans.get(b)
        desc = (
            "-"
            if plan is None
            else (", ".join(plan.reductions) or "whole") + f" (est {plan.estimate_mb:.0f} MB)"
        )
        print(
            f"| {name} | {desc} | {cpu:.2f} | {peak:.0f} | {faults:.0f} | "
            f"{np.sqrt(np.mean(d**2)):.4f} / {d.max():.3f} |"
        )
    print(f"max RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")


if __name__ == "__main__":
    main()
