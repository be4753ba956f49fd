"""Event-rate meter and the bounded drop-oldest worker thread of the nodes."""

from __future__ import annotations

import collections
import threading
import time
import traceback
from typing import Any, Callable

__all__ = ["RateMeter", "DropOldestWorker"]


class RateMeter:
    """Events per second over a sliding window of ``window_s`` seconds."""

    def __init__(self, window_s: float = 5.0) -> None:
        self.window_s = window_s
        self._times: collections.deque[float] = collections.deque(maxlen=10_000)
        self.total = 0

        self.last: float | None = None  # time.monotonic() of the latest event

    def tick(self, now: float | None = None) -> None:
        """Count one event at ``now`` (time.monotonic() by default)."""
        self.last = time.monotonic() if now is None else now
        self._times.append(self.last)
        self.total += 1

    def rate(self, now: float | None = None) -> float:
        """Return the events per second over the window."""
        now = time.monotonic() if now is None else now
        while self._times and now - self._times[0] > self.window_s:
            self._times.popleft()
        return len(self._times) / self.window_s


class DropOldestWorker:
    """Bounded drop-oldest queue served by one worker thread.

    ``put`` never blocks: when the queue is full the oldest item is dropped
    and counted. Exceptions in ``handler`` are caught, counted and passed to
    ``on_error``; the worker keeps running.
    """

    def __init__(
        self,
        handler: Callable[[Any], None],
        maxsize: int = 4,
        name: str = "worker",
        on_error: Callable[[BaseException], None] | None = None,
    ) -> None:
        self._handler = handler
        self._on_error = on_error
        self._queue: collections.deque = collections.deque()
        self._cv = threading.Condition()
        self.maxsize = max(1, int(maxsize))
        self.dropped = 0
        self.processed = 0
        self.errors = 0
        self.cpu_s = 0.0  # CPU time of the worker thread spent in the handler
        self.busy = False
        self._stop = False
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def put(self, item: Any) -> bool:
        """Queue ``item``; return False if an older item had to be dropped."""
        with self._cv:
            dropped = False
            while len(self._queue) >= self.maxsize:
                self._queue.popleft()
                self.dropped += 1
                dropped = True
            self._queue.append(item)
            self._cv.notify()
        return not dropped

    def resize(self, maxsize: int) -> None:
        """Change the queue's bound at run time; the oldest items beyond it are dropped (counted)."""
        with self._cv:
            self.maxsize = max(1, int(maxsize))
            while len(self._queue) > self.maxsize:
                self._queue.popleft()
                self.dropped += 1

    def clear(self) -> None:
        """Drop every queued item."""
        with self._cv:
            self._queue.clear()

    @property
    def depth(self) -> int:
        """Items waiting in the queue."""
        return len(self._queue)

    def idle(self) -> bool:
        """Return True if nothing is queued or being handled."""
        return not self._queue and not self.busy

    def _run(self) -> None:
        while True:
            with self._cv:
                while not self._queue and not self._stop:
                    self._cv.wait(0.5)
                if self._stop:
                    return
                item = self._queue.popleft()
                self.busy = True
            t_cpu = time.thread_time()
            try:
                self._handler(item)
                self.processed += 1
            except Exception as exc:  # noqa: BLE001 - a worker must survive bad data
                self.errors += 1
                if self._on_error is not None:
                    self._on_error(exc)
                else:
                    traceback.print_exc()
            finally:
                self.cpu_s += time.thread_time() - t_cpu
                self.busy = False

    @property
    def cpu_ms_per_item(self) -> float:
        """Mean CPU time (this worker thread only) per item handled, ms."""
        n = self.processed + self.errors
        return 1000.0 * self.cpu_s / n if n else 0.0

    def stop(self, timeout: float = 2.0, drain_s: float = 0.0) -> int:
        """Stop the worker thread; return how many queued items it left unhandled.

        Parameters
        ----------
        timeout : float, optional
            Seconds to wait for the thread to finish the item it is handling.
        drain_s : float, optional
            Seconds to let it handle what is queued first (0: what is queued is dropped).

        Returns
        -------
        int
            The items still queued when it stopped (dropped, not counted in ``dropped``,
            which counts the queue's overflow).
        """
        deadline = time.monotonic() + max(0.0, drain_s)
        with self._cv:
            while (self._queue or self.busy) and time.monotonic() < deadline:
                self._cv.wait(0.02)
            self._stop = True
            left = len(self._queue)
            self._queue.clear()
            self._cv.notify_all()
        self._thread.join(timeout)
        return left
