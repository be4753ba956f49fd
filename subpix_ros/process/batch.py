"""Many flight bags: sequentially in this process or in ``jobs`` worker processes, with progress.

Each bag runs :func:`subpix_ros.process.flight.process_bag` (one pipeline per
process); a bag that fails is reported by one line and the others go on.
Worker processes are started with ``spawn`` (no fork of a process that holds
OpenCV thread pools) and live for one bag each (``max_tasks_per_child=1``),
so each bag's peak memory in its ``timing.json`` is its own; each worker
gets the machine's cores divided by ``jobs`` as OpenCV threads. The products
do not depend on the thread count (they carry 10 significant digits:
:func:`subpix_ros.process.products.rounded`).

Progress: a tqdm bar per bag on a terminal (frames done / total, frames/s,
ETA), plain lines every ``PLAIN_PERIOD_S`` seconds otherwise, nothing with
``quiet``.
"""

from __future__ import annotations

import os
import sys
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from pathlib import Path
from typing import Any, Callable, Sequence

from subpix_ros.process.flight import BagResult, process_bag
from subpix_ros.runtime import die_with_parent

PLAIN_PERIOD_S = 5.0


class Progress:
    """Per-bag progress: tqdm bars on a TTY, periodic plain lines otherwise, or nothing."""

    def __init__(self, stream=None, quiet: bool = False, tty: bool | None = None) -> None:
        self.stream = stream or sys.stderr
        self.quiet = quiet
        self.tty = self.stream.isatty() if tty is None else tty
        self._bars: dict[str, object] = {}
        self._last: dict[str, float] = {}
        self._slots: list[str | None] = []

    def update(self, name: str, done: int, total: int) -> None:
        """Show that ``name`` has ``done`` of ``total`` frames processed."""
        if self.quiet:
            return
        if self.tty:
            from tqdm import tqdm

            bar = self._bars.get(name)
            if bar is None:
                slot = self._slots.index(None) if None in self._slots else len(self._slots)
                if slot == len(self._slots):
                    self._slots.append(name)
                else:
                    self._slots[slot] = name
                bar = tqdm(
                    total=total or None,
                    desc=name,
                    unit="frame",
                    file=self.stream,
                    position=slot,
                    leave=True,
                    dynamic_ncols=True,
                )
                self._bars[name] = bar
            bar.update(done - bar.n)
            return
        now = time.monotonic()
        first = name not in self._last
        if first:
            self._last[name] = now
            self._t0 = getattr(self, "_t0", {})
            self._t0[name] = now
        if first or now - self._last[name] >= PLAIN_PERIOD_S or (total and done >= total):
            self._last[name] = now
            el = now - self._t0[name]
            rate = done / el if el > 0 else 0.0
            pct = f" ({100.0 * done / total:.0f} %)" if total else ""
            print(
                f"{name}: {done}/{total or '?'} frames{pct}, {rate:.1f} frames/s",
                file=self.stream,
                flush=True,
            )

    def finish(self, name: str, line: str) -> None:
        """Show the result line of ``name`` (and close its bar)."""
        bar = self._bars.pop(name, None)
        if bar is not None:
            bar.close()
            self._slots[self._slots.index(name)] = None
        if not self.quiet:
            print(line, file=self.stream, flush=True)


def _raise_interrupt(signum, frame) -> None:
    import signal

    # the first stop request wins: a second SIGTERM (the pool terminates its workers again
    # once one has gone) must not cut the clean-up of the unfinished folder short
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    raise KeyboardInterrupt


def interrupt_on_signals() -> None:
    """SIGINT and SIGTERM raise KeyboardInterrupt (a clean stop), even where SIGINT was ignored."""
    import signal

    signal.signal(signal.SIGINT, _raise_interrupt)
    signal.signal(signal.SIGTERM, _raise_interrupt)


def _worker(
    bag: str,
    out: str,
    params: dict,
    camera_topic,
    telemetry,
    force: bool,
    threads: int,
    queue,
    skip_corrupt: bool = False,
) -> BagResult:
    import cv2

    from subpix_ros.runtime import favour_throughput

    interrupt_on_signals()
    favour_throughput()  # before this bag's threads allocate (subpix_ros.runtime.THROUGHPUT)
    cv2.setNumThreads(threads)
    from subpix_ros.process.inputs import bag_name

    name = bag_name(bag)
    last = [0.0]

    def progress(done: int, total: int) -> None:
        now = time.monotonic()
        if queue is not None and (now - last[0] >= 0.2 or done >= total):
            last[0] = now
            try:
                queue.put((name, done, total))
            except Exception:  # noqa: BLE001 - progress is best effort
                pass

    try:
        return process_bag(
            bag,
            out,
            params,
            camera_topic=camera_topic,
            telemetry=telemetry,
            force=force,
            skip_corrupt=skip_corrupt,
            progress=progress,
        )
    except KeyboardInterrupt:
        return BagResult(bag, name, "failed", f"{name}: interrupted")


def run_batch(
    bags: Sequence[str | Path],
    out: str | Path,
    params: dict,
    *,
    jobs: int = 1,
    camera_topic: str | None = None,
    telemetry: str | None = None,
    force: bool = False,
    skip_corrupt: bool = False,
    monitor: Any = None,
    progress: Progress | None = None,
    on_result: Callable[[BagResult], None] | None = None,
) -> list[BagResult]:
    """Process ``bags`` into ``out``; return one result per bag in the order given.

    Parameters
    ----------
    bags : sequence of str or Path
        The flight bags.
    out : str or Path
        The output folder (one subfolder per bag).
    params : dict
        Stage parameters keyed by node name.
    jobs : int
        Worker processes; 1 (or a single bag) processes in this process.
    camera_topic, telemetry, force, skip_corrupt, monitor
        As in :func:`subpix_ros.process.flight.process_bag` (``monitor`` with one job only).
    progress : Progress, optional
        Where progress goes (nothing by default).
    on_result : callable, optional
        Called with each bag's result as it finishes.

    Returns
    -------
    list of BagResult
        In the order of ``bags``.
    """
    progress = progress or Progress(quiet=True)
    bags = [str(b) for b in bags]
    results: dict[int, BagResult] = {}

    def done(i: int, r: BagResult) -> None:
        results[i] = r
        progress.finish(r.name, r.line)
        if on_result is not None:
            on_result(r)

    options = dict(camera_topic=camera_topic, telemetry=telemetry, force=force)
    if jobs <= 1 or len(bags) <= 1:
        from subpix_ros.process.inputs import bag_name
        from subpix_ros.process.report_ahead import SectionsAhead

        # one process for the flights' report figures, drawn while each flight's last set is
        # solved (not beside --jobs workers: there the cores are busy with other flights)
        ahead = SectionsAhead()
        try:
            for i, b in enumerate(bags):
                name = bag_name(b)
                r = process_bag(
                    b,
                    out,
                    params,
                    **options,
                    skip_corrupt=skip_corrupt,
                    monitor=monitor,
                    progress=lambda d, t, n=name: progress.update(n, d, t),
                    sections_ahead=ahead,
                )
                done(i, r)
        finally:
            ahead.close()
    else:
        _run_parallel(bags, out, params, jobs, options, skip_corrupt, progress, done)
    return [results[i] for i in range(len(bags))]


def _run_parallel(
    bags: list[str],
    out: str | Path,
    params: dict,
    jobs: int,
    options: dict,
    skip_corrupt: bool,
    progress: Progress,
    done: Callable[[int, BagResult], None],
) -> None:
    """Process ``bags`` in ``jobs`` spawned worker processes, one bag per process.

    While the workers run, SIGINT and SIGTERM only set a flag that the wait loop checks every
    0.2 s: a KeyboardInterrupt raised inside ``concurrent.futures.wait`` while it holds the
    futures' locks would leave them held, and the pool's shutdown would then wait forever.
    """
    import multiprocessing as mp
    import signal
    import threading
    from multiprocessing.managers import SyncManager

    ctx = mp.get_context("spawn")
    # the progress queue's server process ends with this one, a kill -9 included (it then holds
    # nothing open: multiprocessing's resource tracker ends too)
    manager = SyncManager(ctx=ctx)
    manager.start(initializer=die_with_parent)
    queue = manager.Queue()
    threads = max(1, (os.cpu_count() or 1) // jobs)
    stop = threading.Event()
    handlers = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            handlers[sig] = signal.signal(sig, lambda signum, frame: stop.set())
    pool = ProcessPoolExecutor(
        max_workers=jobs, mp_context=ctx, max_tasks_per_child=1, initializer=die_with_parent
    )
    try:
        futs = {
            pool.submit(
                _worker,
                b,
                str(out),
                params,
                options["camera_topic"],
                options["telemetry"],
                options["force"],
                threads,
                queue,
                skip_corrupt,
            ): i
            for i, b in enumerate(bags)
        }
        pending = set(futs)
        while pending:
            if stop.is_set():
                raise KeyboardInterrupt
            finished, pending = wait(pending, timeout=0.2, return_when=FIRST_COMPLETED)
            _drain(queue, progress)
            for f in finished:
                i = futs[f]
                try:
                    r = f.result()
                except Exception as exc:  # noqa: BLE001 - a crashed worker fails its bag only
                    from subpix_ros.process.inputs import bag_name

                    name = bag_name(bags[i])
                    r = BagResult(
                        bags[i],
                        name,
                        "failed",
                        f"{name}: failed: worker died: {type(exc).__name__}: {exc}",
                    )
                done(i, r)
        _drain(queue, progress)
    except KeyboardInterrupt:
        # Ctrl-C on a terminal reaches the workers too; a signal to this process alone does not:
        # stop them (each removes its unfinished folder) before leaving.
        for proc in list(getattr(pool, "_processes", {}).values()):
            try:
                proc.terminate()
            except OSError:
                pass
        pool.shutdown(wait=True, cancel_futures=True)
        manager.shutdown()
        raise
    finally:
        for sig, handler in handlers.items():
            signal.signal(sig, handler)
    pool.shutdown(wait=True)
    manager.shutdown()


def _drain(queue, progress: Progress) -> None:
    while True:
        try:
            name, d, t = queue.get_nowait()
        except Exception:  # noqa: BLE001 - queue.Empty or a closed manager
            return
        progress.update(name, d, t)
