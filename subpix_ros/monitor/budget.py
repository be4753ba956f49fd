"""The link budget of the live monitor: a token bucket, byte meters and image quality levels.

No ROS, no network: plain bookkeeping that :class:`subpix_ros.monitor.Monitor`
drives. Everything is measured in bytes on the wire (the WebSocket frame of a
Foxglove message data frame times the number of clients subscribed to its
channel), so the budget is the radio link's, whatever number of operators
watch.
"""

from __future__ import annotations

import collections
import threading
import time
from dataclasses import dataclass

__all__ = ["TokenBucket", "ByteMeter", "LEVELS", "QualityLevel", "wire_bytes"]


def wire_bytes(payload_len: int) -> int:
    """Bytes one Foxglove ``messageData`` frame of ``payload_len`` takes on the wire.

    Parameters
    ----------
    payload_len : int
        Length of the serialized message (protobuf or JSON bytes).

    Returns
    -------
    int
        ``payload + 13`` (opcode 1 byte, subscription id 4, log time 8) plus the
        WebSocket header the server writes (2, 4 or 10 bytes; server frames are
        not masked).

    Notes
    -----
    TCP/IP headers (about 40 bytes per 1460-byte segment, 2.7 %) are not counted:
    the budget is the application's share of the link.
    """
    n = payload_len + 13
    return n + (2 if n < 126 else 4 if n < 65536 else 10)


class TokenBucket:
    """Bytes allowed on the link: ``rate`` bytes/s, at most ``burst_s`` seconds saved up.

    :meth:`charge` takes bytes that must go (health, shifts): the level may go
    below zero and the images then wait until it has recovered. :meth:`allows`
    says whether an optional message of ``n`` bytes may go now.

    Parameters
    ----------
    rate_bytes_s : float
        Budget in bytes per second (``bandwidth_kbps * 1000 / 8``).
    burst_s : float
        Largest saving, seconds of budget: also the largest burst above the rate.
    """

    def __init__(self, rate_bytes_s: float, burst_s: float = 0.5) -> None:
        self._lock = threading.Lock()
        self.rate = float(rate_bytes_s)
        self.burst_s = float(burst_s)
        self.tokens = self.capacity
        self._t = time.monotonic()

    @property
    def capacity(self) -> float:
        """Most bytes the bucket saves up (``rate * burst_s``)."""
        return self.rate * self.burst_s

    def set_rate(self, rate_bytes_s: float) -> None:
        """Change the refill rate (bytes/s), keeping the tokens earned so far."""
        with self._lock:
            self._refill(time.monotonic())
            self.rate = float(rate_bytes_s)
            self.tokens = min(self.tokens, self.capacity)

    def _refill(self, now: float) -> None:
        self.tokens = min(self.capacity, self.tokens + (now - self._t) * self.rate)
        self._t = now

    def level(self, now: float | None = None) -> float:
        """Return the tokens (bytes) available now."""
        with self._lock:
            self._refill(time.monotonic() if now is None else now)
            return self.tokens

    def charge(self, n: int, now: float | None = None) -> None:
        """Take ``n`` bytes from the bucket (it may go negative: a debt)."""
        with self._lock:
            self._refill(time.monotonic() if now is None else now)
            self.tokens -= n

    def allows(self, n: int, now: float | None = None) -> bool:
        """Return True if ``n`` bytes fit now (a message over the capacity goes when it is full)."""
        with self._lock:
            self._refill(time.monotonic() if now is None else now)
            return self.tokens >= min(n, self.capacity) and self.tokens > 0


class ByteMeter:
    """Bytes per second over a sliding window, one meter per channel."""

    def __init__(self, window_s: float = 5.0) -> None:
        self.window_s = window_s
        self._events: collections.deque[tuple[float, int]] = collections.deque()
        self._sum = 0
        self.total = 0
        self.messages = 0
        self.first: float | None = None  # when the first bytes were counted
        self._lock = threading.Lock()

    def add(self, n: int, now: float | None = None) -> None:
        """Count ``n`` bytes sent at ``now``."""
        now = time.monotonic() if now is None else now
        with self._lock:
            if self.first is None:
                self.first = now
            self._events.append((now, n))
            self._sum += n
            self.total += n
            self.messages += 1
            self._trim(now)

    def _trim(self, now: float) -> None:
        while self._events and now - self._events[0][0] > self.window_s:
            self._sum -= self._events.popleft()[1]

    def full(self, now: float | None = None) -> bool:
        """Return True once the meter has counted for a whole window (its rate is not partial)."""
        now = time.monotonic() if now is None else now
        return self.first is not None and now - self.first >= self.window_s

    def rate(self, now: float | None = None) -> float:
        """Return the bytes per second over the window."""
        with self._lock:
            self._trim(time.monotonic() if now is None else now)
            return self._sum / self.window_s


@dataclass(frozen=True)
class QualityLevel:
    """One rung of an image stream's ladder: JPEG quality and a scale of its largest side."""

    quality: int
    scale: float


# Degradation of one image stream, best first: JPEG quality goes down before the size does
# (a smaller image loses detail the operator may need; quality 60 costs little to the eye).
LEVELS: tuple[QualityLevel, ...] = (
    QualityLevel(85, 1.0),
    QualityLevel(70, 1.0),
    QualityLevel(55, 1.0),
    QualityLevel(55, 0.75),
    QualityLevel(45, 0.6),
    QualityLevel(40, 0.5),
    QualityLevel(35, 0.4),
    QualityLevel(30, 0.3),
    QualityLevel(25, 0.25),
)
