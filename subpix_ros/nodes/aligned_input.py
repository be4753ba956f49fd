"""Aligned frames arriving over DDS, reassembled into :class:`payloads.Aligned`.

Subscribes ``aligned`` + ``aligned/mask`` (paired by exact header stamp),
``aligned/reference`` (latched) and ``aligned/reference_stamp``
(sensor_msgs/TimeReference: the frame's stamp -> its reference's stamp). A
frame goes with the reference its link names; a frame whose link or reference
has not arrived yet waits for it (bounded), so the topics may arrive in any
order (another host, retransmissions). Without a link publisher (an older
registration node, a hand-made stream) a frame belongs to the latest
reference whose stamp is not later than its own. Used by the shift and
reconstruction nodes; in the single-process pipeline they get the objects
directly instead.
"""
from __future__ import annotations

import collections
from typing import Callable

import numpy as np

from sensor_msgs.msg import Image, TimeReference

from subpix_ros.nodes import payloads as pl
from subpix_ros.nodes.common import latched_qos, reliable_qos


class StampMatcher:
    """Pair messages of two streams by exact header stamp (bounded memory)."""

    def __init__(self, maxlen: int = 32) -> None:
        self.a: collections.OrderedDict[int, object] = collections.OrderedDict()
        self.b: collections.OrderedDict[int, object] = collections.OrderedDict()
        self.maxlen = maxlen

    def _put(self, mine, other, stamp, item):
        if stamp in other:
            return other.pop(stamp)
        mine[stamp] = item
        while len(mine) > self.maxlen:
            mine.popitem(last=False)
        return None

    def add_a(self, stamp: int, item):
        b = self._put(self.a, self.b, stamp, item)
        return None if b is None else (item, b)

    def add_b(self, stamp: int, item):
        a = self._put(self.b, self.a, stamp, item)
        return None if a is None else (a, item)

    def clear(self) -> None:
        self.a.clear()
        self.b.clear()


class ReferenceCache:
    """References by stamp; an aligned frame belongs to the latest not later than it."""

    MAXLEN = 8

    def __init__(self, maxlen: int = MAXLEN) -> None:
        self.refs: collections.OrderedDict[int, pl.Frame] = collections.OrderedDict()
        self.maxlen = maxlen

    def add(self, frame: pl.Frame) -> None:
        self.refs[frame.stamp_ns] = frame
        self.refs = collections.OrderedDict(sorted(self.refs.items())[-self.maxlen:])

    def get(self, stamp_ns: int) -> pl.Frame | None:
        """The reference of exactly this stamp, if it has arrived."""
        return self.refs.get(stamp_ns)

    def for_stamp(self, stamp_ns: int) -> pl.Frame | None:
        earlier = [s for s in self.refs if s <= stamp_ns]
        return self.refs[max(earlier)] if earlier else None

    def clear(self) -> None:
        self.refs.clear()


class AlignedInput:
    """The four subscriptions of a node that consumes aligned frames."""

    MAX_PENDING = 16  # frames held for a link or for a reference (two sets of 8), each map

    def __init__(self, node, on_aligned: Callable[[pl.Aligned], None], depth: int = 10) -> None:
        self.node = node
        self.on_aligned = on_aligned
        self.refs = ReferenceCache()
        self.matcher = StampMatcher()
        q = reliable_qos(depth)
        # The reference subscription is made FIRST: rclpy's executors take the ready subscriptions of a
        # node in the order they were made, so a new reference waiting beside the first frame aligned to it
        # is taken before that frame (made after, the frame went with the previous reference). Depth 8: two
        # references in quick succession are both kept.
        node.create_subscription(Image, "aligned/reference", self._on_reference, latched_qos(ReferenceCache.MAXLEN),
                                 raw=True)
        # links are tiny: a deep queue, so a busy node never loses one (its frame would wait in vain)
        self.link_sub = node.create_subscription(TimeReference, "aligned/reference_stamp", self._on_link,
                                                 reliable_qos(max(depth, 100)), raw=True)
        node.create_subscription(Image, "aligned", self._on_aligned, q, raw=True)
        node.create_subscription(Image, "aligned/mask", self._on_mask, q, raw=True)
        self.links: collections.OrderedDict[int, int] = collections.OrderedDict()  # frame stamp -> reference stamp
        self.unlinked: collections.OrderedDict[int, tuple] = collections.OrderedDict()  # (frame, mask) awaiting a link
        self.waiting: collections.OrderedDict[tuple[int, int], tuple] = collections.OrderedDict()  # awaiting a reference
        self.newest_link = -1  # stamp of the latest frame whose link arrived

    def _decode(self, raw: bytes, what: str) -> pl.Frame | None:
        try:
            return pl.frame_from_cdr(raw)
        except Exception as exc:  # noqa: BLE001 - bad input must not kill the node
            self.node.diag.error(f"bad {what} image: {exc}")
            return None

    def _on_reference(self, raw: bytes) -> None:
        f = self._decode(raw, "reference")
        if f is not None:
            self.refs.add(f)
            for key in [k for k in self.waiting if k[0] == f.stamp_ns]:  # its frames that came first
                self._deliver(*self.waiting.pop(key), f)

    def _on_link(self, raw: bytes) -> None:
        try:
            stamp, ref_stamp = pl.reference_link_from_cdr(raw)
        except Exception as exc:  # noqa: BLE001 - bad input must not kill the node
            self.node.diag.error(f"bad aligned/reference_stamp message: {exc}")
            return
        if stamp in self.unlinked:
            self._with_reference(*self.unlinked.pop(stamp), ref_stamp)
        else:
            _bounded_put(self.links, stamp, ref_stamp, 8 * self.MAX_PENDING)
        # Links come in frame order (one writer, reliable): a frame older than the newest link and still
        # without its own lost it (e.g. published before the link reader was matched); it would wait for ever.
        # (The newest is the last to arrive, so a bag replayed from its start again resets it.)
        self.newest_link = stamp
        lost = [t for t in self.unlinked if t < stamp]
        for t in lost:
            del self.unlinked[t]
        if lost:
            self._link_lost(len(lost))

    def _link_lost(self, n: int) -> None:
        self.node.diag.warn(f"{n} aligned frame(s) whose aligned/reference_stamp never came: skipped")

    def _on_aligned(self, raw: bytes) -> None:
        self.node.diag.rate("input").tick()
        f = self._decode(raw, "aligned")
        if f is not None:
            pair = self.matcher.add_a(f.stamp_ns, f)
            if pair:
                self._pair(*pair)

    def _on_mask(self, raw: bytes) -> None:
        m = self._decode(raw, "mask")
        if m is None:
            return
        if m.image.ndim != 2:
            self.node.diag.error("bad mask image: not mono8")
            return
        pair = self.matcher.add_b(m.stamp_ns, m.image > 0)
        if pair:
            self._pair(*pair)

    def _pair(self, frame: pl.Frame, mask: np.ndarray) -> None:
        if mask.shape != frame.image.shape[:2]:
            self.node.diag.error(f"mask shape {mask.shape} does not match image {frame.image.shape[:2]}")
            return
        if frame.stamp_ns in self.links:
            self._with_reference(frame, mask, self.links.pop(frame.stamp_ns))
        elif frame.stamp_ns < self.newest_link:  # a later frame's link came first: this one's is lost
            self._link_lost(1)
        elif self.link_sub.get_publisher_count() > 0:  # its link is on the way
            if _bounded_put(self.unlinked, frame.stamp_ns, (frame, mask), self.MAX_PENDING):
                self.node.diag.warn("aligned frames without their aligned/reference_stamp: oldest dropped")
        else:  # no link publisher: the latest reference not later than the frame
            ref = self.refs.for_stamp(frame.stamp_ns)
            if ref is None:
                self.node.diag.warn("aligned frame without a reference yet: skipped")
                return
            self._deliver(frame, mask, ref)

    def _with_reference(self, frame: pl.Frame, mask: np.ndarray, ref_stamp: int) -> None:
        ref = self.refs.get(ref_stamp)
        if ref is not None:
            self._deliver(frame, mask, ref)
        elif _bounded_put(self.waiting, (ref_stamp, frame.stamp_ns), (frame, mask), self.MAX_PENDING):
            self.node.diag.warn("aligned frames whose reference never arrived: oldest dropped")

    def _deliver(self, frame: pl.Frame, mask: np.ndarray, ref: pl.Frame) -> None:
        self.on_aligned(pl.Aligned(frame.stamp_ns, frame.image, mask, ref, np.eye(3), None, frame.frame_id,
                                   frame.received))

    def clear(self) -> None:
        self.refs.clear()
        self.matcher.clear()
        self.links.clear()
        self.unlinked.clear()
        self.waiting.clear()
        self.newest_link = -1


def _bounded_put(store: collections.OrderedDict, key, value, maxlen: int) -> bool:
    """``store[key] = value``, dropping the oldest entries beyond ``maxlen``; True if any was dropped."""
    store[key] = value
    dropped = False
    while len(store) > maxlen:
        store.popitem(last=False)
        dropped = True
    return dropped
