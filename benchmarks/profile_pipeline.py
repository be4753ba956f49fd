#!/usr/bin/env python3
"""Per-stage process CPU and peak allocation of the single-process pipeline's core work (issue 22).

Drives the core functions as the ``pipeline`` executable does with
``config/bench.yaml`` (1920x1080 bgr8 frames drifting by (0.41, 0.27) px per
frame, see bench_pipeline.make_frames; a new reference every ``--set`` frames;
projective registration with 150 points, integer-crop alignment, luminance,
shift estimation, x2 MAP reconstruction of each set, a mosaic frame every
10th frame), without ROS: what it measures is the stages' own cost.

Two passes over the same frames:

1. process CPU time (``time.process_time``) per stage, per frame of the stream;
2. ``tracemalloc``: the peak of traced allocations (numpy and OpenCV outputs)
   above what was allocated when the stage started, per stage (largest call).

Printed: a table with CPU ms per frame and peak MB per stage, the total CPU
s/frame and the process's maximum resident set size; ``--cprofile N`` adds the
top N functions by cumulative time. ``--max-memory-mb`` reconstructs through
:func:`subpix_ros.core.superres.budget.reconstruct_within_budget` (and prints
the plans).

Usage: python benchmarks/profile_pipeline.py [--frames 48] [--set 16] [--size 1920x1080]
       [--max-memory-mb MB] [--cprofile 30]
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pstats
import resource
import sys
import time
import tracemalloc
from collections import defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
from bench_pipeline import make_frames  # noqa: E402

from subpix_ros.core import registration as reg  # noqa: E402
from subpix_ros.core.luminance import luminance  # noqa: E402
from subpix_ros.core.mosaic import Mosaic  # noqa: E402
from subpix_ros.core.motion import MotionTracker  # noqa: E402
from subpix_ros.core.shift import estimate_shift  # noqa: E402
from subpix_ros.core.superres.budget import reconstruct_within_budget  # noqa: E402
from subpix_ros.runtime import add_malloc_argument, allocator_line  # noqa: E402

STAGES = ("reference", "register", "align", "gray", "shift", "reconstruct", "mosaic")


def gray(image: np.ndarray) -> np.ndarray:
    """Return the shift node's luminance (float32)."""
    return luminance(image, order="bgr" if image.ndim == 3 else "mono", dtype=np.float32)


class Meter:
    """Process CPU and (when tracing) the peak traced allocation of each stage."""

    def __init__(self, trace: bool) -> None:
        self.trace = trace
        self.cpu: dict[str, float] = defaultdict(float)
        self.calls: dict[str, int] = defaultdict(int)
        self.peak: dict[str, float] = defaultdict(float)

    def run(self, stage: str, fn, *a, **kw):
        if self.trace:
            tracemalloc.reset_peak()
            base = tracemalloc.get_traced_memory()[0]
        t0 = time.process_time()
        out = fn(*a, **kw)
        self.cpu[stage] += time.process_time() - t0
        self.calls[stage] += 1
        if self.trace:
            self.peak[stage] = max(
                self.peak[stage], (tracemalloc.get_traced_memory()[1] - base) / 1e6
            )
        return out


def run(
    frames: list[np.ndarray], set_size: int, m: Meter, budget: float | None, plans: list
) -> None:
    """One pass of the stream through the stages (the pipeline's order and settings)."""
    ref = prep = rg = None
    mt = MotionTracker()
    mos = Mosaic(max_size_px=2048, frame_max_px=1280)
    members: list = []
    for k, f in enumerate(frames):
        t = k / 10.0
        if k % 10 == 0:
            m.run("mosaic", mos.add, f, stamp_s=t)  # stamped, as the mosaic stage adds them
        if ref is None or len(members) >= set_size - 1:
            if members:
                fr = [ref] + [a for a, _, _ in members]
                ms = [np.ones(ref.shape[:2], bool)] + [mk for _, mk, _ in members]
                sh = np.array([[0.0, 0.0]] + [s for _, _, s in members])
                _, plan = m.run(
                    "reconstruct",
                    reconstruct_within_budget,
                    fr,
                    sh,
                    2,
                    masks=ms,
                    max_memory_mb=budget,
                    method="map",
                    geometry="translation",
                    refine_shifts=False,
                )
                plans.append(plan)
            ref, members = f, []
            prep = m.run("reference", reg.prepare_reference, f)
            rg = m.run("reference", gray, f)  # the reference's luminance, once per reference
            mt.restart(t)
            continue
        r = m.run(
            "register",
            reg.register,
            prep,
            f,
            model="projective",
            n_points=150,
            distortion=False,
            prior=mt.predict(t),
            track_radius=4,
            want_inliers=100,
        )
        if not r.ok:
            continue
        mt.update(r.homography, t)
        al = m.run("align", reg.align, ref, f, r, warp_threshold_px=0.1)
        g = m.run("gray", gray, al.aligned)
        s = m.run("shift", estimate_shift, rg, g, mask=al.mask)
        if s.ok:
            members.append((al.aligned, al.mask, [s.u, s.v]))


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--frames", type=int, default=48)
    ap.add_argument(
        "--set", type=int, default=16, help="frames per super-resolved image (default %(default)s)"
    )
    ap.add_argument("--size", default="1920x1080", help="WxH of the frames (default %(default)s)")
    ap.add_argument(
        "--max-memory-mb", type=float, default=None, help="reconstruction memory budget"
    )
    ap.add_argument(
        "--cprofile",
        type=int,
        default=0,
        metavar="N",
        help="print the top N functions (cumulative)",
    )
    ap.add_argument("--no-trace", action="store_true", help="skip the tracemalloc pass")
    add_malloc_argument(ap)
    args = ap.parse_args()
    print(allocator_line(args.default_malloc))
    w, h = (int(v) for v in args.size.lower().split("x"))
    frames = make_frames(args.frames, w, h)
    n = len(frames)
    cpu_m = Meter(trace=False)
    plans: list = []
    prof = cProfile.Profile() if args.cprofile else None
    t0, w0 = time.process_time(), time.perf_counter()
    if prof:
        prof.enable()
    run(frames, args.set, cpu_m, args.max_memory_mb, plans)
    if prof:
        prof.disable()
    cpu_total, wall_total = time.process_time() - t0, time.perf_counter() - w0
    rss_cpu_pass = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    mem_m = Meter(trace=True)
    if not args.no_trace:
        tracemalloc.start()
        run(frames, args.set, mem_m, args.max_memory_mb, [])
        tracemalloc.stop()
    print(
        f"\n{w}x{h} bgr8, {n} frames, sets of {args.set}, x2 MAP"
        f"{'' if args.max_memory_mb is None else f', max_memory_mb {args.max_memory_mb:g}'} "
        f"(load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs)"
    )
    print(
        "| stage | calls | process CPU ms per frame | ms per call | peak traced MB (largest call) |"
    )
    print("|---|---|---|---|---|")
    for st in STAGES:
        c = cpu_m.calls.get(st, 0)
        print(
            f"| {st} | {c} | {1000 * cpu_m.cpu[st] / n:.1f} | {1000 * cpu_m.cpu[st] / max(c, 1):.1f} | "
            f"{'-' if args.no_trace else f'{mem_m.peak[st]:.0f}'} |"
        )
    print(f"| total (incl. frame loop) | | {1000 * cpu_total / n:.1f} | | |")
    print(
        f"total CPU {cpu_total / n:.4f} s/frame, wall {wall_total / n:.4f} s/frame; "
        f"max RSS {rss_cpu_pass:.0f} MB after the CPU pass, "
        f"{resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB at the end"
    )
    if plans:
        print(
            "reconstruction plans: "
            + "; ".join(
                f"{p.n_frames} frames, grid {p.grid}, est {p.estimate_mb:.0f} MB"
                + (f" ({', '.join(p.reductions)})" if p.reductions else "")
                for p in plans[:3]
            )
        )
    if prof:
        pstats.Stats(prof).sort_stats("cumulative").print_stats(args.cprofile)


if __name__ == "__main__":
    main()
