#!/usr/bin/env python3
"""Per-stage process CPU of the real stage objects (``Pipeline``) on the bench frames (issue 22).

``profile_pipeline.py`` drives the core functions; this drives what the ``pipeline``
node and ``subpix process`` run: :class:`subpix_ros.stages.Pipeline` with the parameters of
``config/bench.yaml`` (and ``--params FILE``), 1920x1080 bgr8 frames drifting by
(0.41, 0.27) px per frame at 10 Hz stamps, the reconstruction in the caller's thread
(``overlap=False``) so that each stage's CPU is its own. Without ROS or DDS: the difference
to the node's CPU per frame is the node's own (decode, executor, diagnostics).

Printed: process CPU per frame of each stage's ``add`` (registration, shift, reconstruction,
mosaic), the total, and the maximum resident set size; ``--cprofile N`` adds the top N
functions by cumulative time.

Usage: python benchmarks/profile_stages.py [--frames 96] [--params FILE] [--cprofile 40 [--sort tottime]]
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pstats
import resource
import sys
import time
from collections import defaultdict
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
from bench_pipeline import make_frames  # noqa: E402
from machine_speed import machine_line  # noqa: E402

from subpix_ros.runtime import add_malloc_argument, allocator_line  # noqa: E402
from subpix_ros.stages import Pipeline  # noqa: E402
from subpix_ros.stages.types import Frame  # noqa: E402


def load_params(files: list[str]) -> dict:
    """Node parameters of config/bench.yaml, then each ``--params`` file on top."""
    out: dict = {}
    for f in [ROOT / "config" / "bench.yaml", *files]:
        for key, body in (yaml.safe_load(Path(f).read_text()) or {}).items():
            node = key.rsplit("/", 1)[-1]  # /**/registration_node: the node in any namespace
            out.setdefault(node, {}).update((body or {}).get("ros__parameters", {}))
    return out


class Timed:
    """Wrap a stage's ``add`` to sum its process CPU time."""

    def __init__(self, name: str, fn, acc: dict) -> None:
        self.name, self.fn, self.acc = name, fn, acc

    def __call__(self, *a, **kw):
        t0 = time.process_time()
        try:
            return self.fn(*a, **kw)
        finally:
            self.acc[self.name] += time.process_time() - t0


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--frames", type=int, default=96)
    ap.add_argument("--params", action="append", default=[], metavar="FILE")
    ap.add_argument("--cprofile", type=int, default=0, metavar="N")
    ap.add_argument(
        "--sort",
        default="cumulative",
        choices=("cumulative", "tottime"),
        help="order of the --cprofile table",
    )
    add_malloc_argument(ap)
    args = ap.parse_args()
    print(machine_line(), flush=True)
    print(allocator_line(args.default_malloc))
    params = load_params(args.params)
    frames = make_frames(args.frames)
    pipe = Pipeline(params, overlap=False)
    acc: dict = defaultdict(float)
    inner = {"registration": pipe.registration, "shift": pipe.shift}
    inner["reconstruction"] = pipe.reconstruction
    if pipe.mosaic is not None:
        inner["mosaic"] = pipe.mosaic
    for name, stage in inner.items():
        for meth in ("add", "assemble", "reconstruct", "idle_sets", "flush_sets"):
            if hasattr(stage, meth):
                setattr(stage, meth, Timed(name, getattr(stage, meth), acc))
    counts = defaultdict(int)
    for kind in ("aligned", "shift", "super_resolved", "mosaic", "skipped", "error"):
        pipe.on(kind, lambda *_a, k=kind: counts.__setitem__(k, counts[k] + 1))
    prof = cProfile.Profile() if args.cprofile else None
    t0, w0 = time.process_time(), time.perf_counter()
    if prof:
        prof.enable()
    for k, img in enumerate(frames):
        pipe.add(Frame(1_000_000_000 + k * 100_000_000, img, "camera"))
    pipe.flush()
    if prof:
        prof.disable()
    cpu, wall = time.process_time() - t0, time.perf_counter() - w0
    pipe.close()
    n = len(frames)
    print(
        f"\n1920x1080 bgr8, {n} frames, Pipeline(config/bench.yaml"
        f"{''.join(', ' + p for p in args.params)}), reconstruction in the caller's thread "
        f"(load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs)"
    )
    print(f"outputs: {dict(counts)}")
    print("| stage | process CPU ms per frame |\n|---|---|")
    for name in inner:
        print(f"| {name} | {1000 * acc[name] / n:.1f} |")
    print(f"| rest (pipeline glue) | {1000 * (cpu - sum(acc.values())) / n:.1f} |")
    print(
        f"| total | {1000 * cpu / n:.1f} |\nwall {wall / n * 1000:.1f} ms/frame; max RSS "
        f"{resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB"
    )
    if prof:
        pstats.Stats(prof).sort_stats(args.sort).print_stats(args.cprofile)


if __name__ == "__main__":
    main()
