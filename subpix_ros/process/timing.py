"""Stage timing of a processed flight (``timing.json``) and the read-ahead of its bag."""

from __future__ import annotations

import queue
import threading
import time
from typing import Any, Iterator

import numpy as np

from subpix_ros.process.collector import _TIME_KEY, _stats_dict

__all__ = ["prefetch"]


class _Timer:
    """Wall time of every call of a stage method, ``add`` by default (timing.json: median, p99)."""

    def __init__(self) -> None:
        self.ms: dict[str, list[float]] = {}

    def wrap(self, name: str, obj: Any, method: str = "add") -> None:
        """Time every call of ``obj.<method>`` under ``name`` (from any thread)."""
        add = getattr(obj, method)
        times = self.ms.setdefault(name, [])

        def timed(*a, **k):
            t0 = time.perf_counter()
            try:
                return add(*a, **k)
            finally:
                times.append(1000.0 * (time.perf_counter() - t0))

        try:
            setattr(obj, method, timed)
        except (AttributeError, TypeError):
            pass

    def summary(self) -> dict[str, dict[str, float]]:
        out = {}
        for name, v in self.ms.items():
            if v:
                a = np.asarray(v)
                out[name] = {
                    "calls": int(a.size),
                    "median_ms": float(np.median(a)),
                    "p99_ms": float(np.percentile(a, 99)),
                    "max_ms": float(a.max()),
                    "total_s": float(a.sum() / 1000.0),
                }
        return out


def prefetch(events: Iterator, depth: int = 4) -> Iterator:
    """Read (and decode) ``events`` on a background thread, up to ``depth`` items ahead, in order.

    Parameters
    ----------
    events : iterator
        The flight's events (:meth:`Flight.events`).
    depth : int
        How many items may wait.

    Yields
    ------
    object
        The items of ``events`` in order; an exception of the reader (a corrupt bag) is raised
        here, in order.

    Notes
    -----
    Reading the bag and decoding images (JPEG/PNG of a CompressedImage camera) then overlaps the
    stages' work.
    """
    q: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()
    end = object()

    def run() -> None:
        try:
            for ev in events:
                while not stop.is_set():
                    try:
                        q.put((None, ev), timeout=0.1)
                        break
                    except queue.Full:
                        continue
                if stop.is_set():
                    return
            q.put((None, end))
        except BaseException as exc:  # noqa: BLE001 - handed to the consumer
            q.put((exc, None))

    t = threading.Thread(target=run, name="subpix-reader", daemon=True)
    t.start()
    try:
        while True:
            exc, ev = q.get()
            if exc is not None:
                raise exc
            if ev is end:
                return
            yield ev
    finally:
        stop.set()
        t.join(timeout=5.0)


def _timing_record(add_ms: list[float], timer: _Timer, stats: dict, flight_s: float) -> dict:
    """Build the figures of ``timing.json`` before the wall/CPU totals: per frame, per stage."""
    a = np.asarray(add_ms) if add_ms else np.zeros(0)
    return {
        "frames": int(a.size),
        "frame_ms": {
            "median": float(np.median(a)) if a.size else None,
            "p99": float(np.percentile(a, 99)) if a.size else None,
            "max": float(a.max()) if a.size else None,
        },
        "stages": timer.summary(),
        "stage_stats_ms": {
            k: {kk: vv for kk, vv in _stats_dict(v).items() if _TIME_KEY.search(kk)}
            for k, v in stats.items()
        },
        "flight_s": flight_s,
    }
