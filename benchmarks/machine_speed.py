#!/usr/bin/env python3
"""A fixed reference workload, so that CPU figures from different machines can be compared.

The sessions that measure issue 22's and issue 20's targets run on machines that differ
by up to 2x in speed (docs/design-notes.md). This times, single-threaded (OpenCV on one
thread), the kinds of work the pipeline spends its CPU on, on 1080p arrays: a real
single-precision DFT (the reconstruction's spectra), an 8-tap separable filter (the shift
estimator's fractional delays), a BGR -> luminance conversion (every stage), elementwise
complex64 products (the reconstruction's per-bin solve) and a bilinear remap (the
registration's patches). Printed: the fastest and the median of ``--repeat`` rounds, ms of
CPU per round (the fastest is the machine, the median also its neighbours' load on a shared
host); a faster machine gives smaller numbers. No reference figure is built in: compare the
printed numbers of two machines.

Usage: python benchmarks/machine_speed.py [--repeat 15]
"""

from __future__ import annotations

import argparse
import time

import cv2
import numpy as np


def _workload() -> dict:
    """Arrays of the reference workload (fixed seed: every machine times the same values)."""
    rng = np.random.default_rng(0)
    bgr = rng.integers(0, 256, (1080, 1920, 3), dtype=np.uint8)
    gray = rng.random((1080, 1920), dtype=np.float32) * 255
    z = (rng.random((1080, 961)) + 1j * rng.random((1080, 961))).astype(np.complex64)
    yy, xx = np.mgrid[0:1080, 0:1920].astype(np.float32)
    return {
        "bgr": bgr,
        "gray": gray,
        "z": z,
        "kernel": np.hanning(10)[1:-1].astype(np.float32),
        "map_x": xx + 0.3,
        "map_y": yy + 0.7,
    }


def _round(w: dict) -> None:
    """One round of the workload."""
    cv2.dft(w["gray"], flags=cv2.DFT_REAL_OUTPUT)
    cv2.sepFilter2D(w["gray"], cv2.CV_32F, w["kernel"], w["kernel"])
    cv2.cvtColor(w["bgr"], cv2.COLOR_BGR2GRAY)
    z = w["z"]
    for _ in range(8):
        z = z * w["z"]
    cv2.remap(w["gray"], w["map_x"], w["map_y"], cv2.INTER_LINEAR)


def machine_ms(repeat: int = 15) -> tuple[float, float]:
    """Fastest and median time (ms) of ``repeat`` rounds of the workload, OpenCV on one thread."""
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        w = _workload()
        _round(w)  # warm-up: first-use allocations
        times = []
        for _ in range(repeat):
            t0 = time.process_time()
            _round(w)
            times.append(1000 * (time.process_time() - t0))
        return float(np.min(times)), float(np.median(times))
    finally:
        cv2.setNumThreads(threads)


def machine_line(repeat: int = 15) -> str:
    """One line for a benchmark's output: the reference workload's time on this machine."""
    fastest, median = machine_ms(repeat)
    return (
        f"machine: reference workload {fastest:.1f} ms of CPU fastest, {median:.1f} median "
        "(benchmarks/machine_speed.py; smaller is faster)"
    )


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--repeat", type=int, default=15)
    print(machine_line(ap.parse_args().repeat))


if __name__ == "__main__":
    main()
