"""Pair a shift with its standard errors when they arrive on two topics."""

from __future__ import annotations

import threading
import time
from collections import OrderedDict
from collections.abc import Callable

Std = tuple[float, float]
Emit = Callable[[int, float, float, float | None, float | None], None]


class ShiftStdJoin:
    """Join ``shift`` and ``shift/std`` messages by their header stamp.

    shift_node publishes a frame's standard errors (``shift/std``) just before its shift, on
    another topic, so either may arrive first. A shift is emitted once with its errors as soon
    as both are in, or with ``None`` errors after ``wait_s`` if no errors arrive (a shift_node
    that does not publish them, a lost message): a shift is never held back for good.

    Parameters
    ----------
    emit : callable
        ``emit(stamp_ns, u, v, u_std, v_std)``, called once per shift.
    wait_s : float
        Longest time a shift waits for its errors, seconds.
    keep : int
        Unmatched entries kept per side; the oldest are dropped beyond this.
    clock : callable
        Monotonic time in seconds (for tests).
    """

    def __init__(
        self,
        emit: Emit,
        wait_s: float = 0.5,
        keep: int = 256,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._emit = emit
        self.wait_s = wait_s
        self._keep = keep
        self._clock = clock
        self._lock = threading.Lock()
        self._std: OrderedDict[int, Std] = OrderedDict()
        self._waiting: OrderedDict[int, tuple[float, float, float]] = OrderedDict()
        self.unmatched = 0  # shifts emitted without errors

    def shift(self, stamp_ns: int, u: float, v: float) -> None:
        """Take a shift (px); emit it now if its errors are in, otherwise hold it."""
        with self._lock:
            std = self._std.pop(stamp_ns, None)
            overflow = []
            if std is None:
                self._waiting[stamp_ns] = (u, v, self._clock())
                while len(self._waiting) > self._keep:  # emitted without errors, never dropped
                    old, (ou, ov, _) = self._waiting.popitem(last=False)
                    overflow.append((old, ou, ov))
                self.unmatched += len(overflow)
        for old, ou, ov in overflow:
            self._emit(old, ou, ov, None, None)
        if std is not None:
            self._emit(stamp_ns, u, v, *std)

    def std(self, stamp_ns: int, u_std: float, v_std: float) -> None:
        """Take the standard errors (px) of the shift of ``stamp_ns``."""
        with self._lock:
            held = self._waiting.pop(stamp_ns, None)
            if held is None:
                self._std[stamp_ns] = (u_std, v_std)
                while len(self._std) > self._keep:
                    self._std.popitem(last=False)
                return
        self._emit(stamp_ns, held[0], held[1], u_std, v_std)

    def expire(self) -> int:
        """Emit the shifts that waited longer than ``wait_s`` without errors; return how many."""
        now = self._clock()
        with self._lock:
            late = [s for s, (_, _, t) in self._waiting.items() if now - t >= self.wait_s]
            out = [(s, *self._waiting.pop(s)[:2]) for s in late]
            self.unmatched += len(out)
        for stamp, u, v in out:
            self._emit(stamp, u, v, None, None)
        return len(out)
