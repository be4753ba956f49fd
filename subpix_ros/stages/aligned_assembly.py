"""Aligned frames reassembled from their parts: the frame, its mask, its reference and the link.

Between processes an aligned frame travels as four messages (``aligned``,
``aligned/mask``, ``aligned/reference`` and ``aligned/reference_stamp``, the
link naming the frame's reference). :class:`AlignedAssembler` puts them back
together into :class:`~subpix_ros.stages.types.Aligned` whatever order they
arrive in: a frame goes with the reference its link names, and waits
(bounded) for a link or a reference not there yet. Without a link publisher
(an older registration node, a hand-made stream) a frame belongs to the
latest reference whose stamp is not later than its own.
"""

from __future__ import annotations

import collections
import functools
import threading
from typing import Callable

import numpy as np

from subpix_ros.core.validity import common_valid_box
from subpix_ros.stages.types import Aligned, Frame


class StampMatcher:
    """Pair messages of two streams by exact header stamp (bounded memory)."""

    def __init__(self, maxlen: int = 32) -> None:
        self.a: collections.OrderedDict[int, object] = collections.OrderedDict()
        self.b: collections.OrderedDict[int, object] = collections.OrderedDict()
        self.maxlen = maxlen

    def _put(self, mine, other, stamp, item):
        """Return the partner waiting in ``other``, or keep ``item`` in ``mine`` (None)."""
        if stamp in other:
            return other.pop(stamp)
        mine[stamp] = item
        while len(mine) > self.maxlen:
            mine.popitem(last=False)
        return None

    def add_a(self, stamp: int, item):
        """Offer an item of stream a; return ``(item, partner)`` once paired, else None."""
        b = self._put(self.a, self.b, stamp, item)
        return None if b is None else (item, b)

    def add_b(self, stamp: int, item):
        """Offer an item of stream b; return ``(partner, item)`` once paired, else None."""
        a = self._put(self.b, self.a, stamp, item)
        return None if a is None else (a, item)

    def clear(self) -> None:
        """Forget every unpaired item."""
        self.a.clear()
        self.b.clear()


class ReferenceCache:
    """References by stamp; an aligned frame belongs to the latest not later than it."""

    MAXLEN = 8

    def __init__(self, maxlen: int = MAXLEN) -> None:
        self.refs: collections.OrderedDict[int, Frame] = collections.OrderedDict()
        self.maxlen = maxlen

    def add(self, frame: Frame) -> None:
        """Keep a reference (the ``maxlen`` latest by stamp are kept)."""
        self.refs[frame.stamp_ns] = frame
        self.refs = collections.OrderedDict(sorted(self.refs.items())[-self.maxlen :])

    def get(self, stamp_ns: int) -> Frame | None:
        """Return the reference of exactly this stamp, if it has arrived."""
        return self.refs.get(stamp_ns)

    def for_stamp(self, stamp_ns: int) -> Frame | None:
        """Return the latest reference not later than ``stamp_ns``, if any."""
        earlier = [s for s in self.refs if s <= stamp_ns]
        return self.refs[max(earlier)] if earlier else None

    def clear(self) -> None:
        """Forget every reference."""
        self.refs.clear()


def _locked(method):
    """Run ``method`` under the assembler's lock (a node resets it from its worker thread)."""

    @functools.wraps(method)
    def call(self, *args, **kwargs):
        with self._lock:
            return method(self, *args, **kwargs)

    return call


class AlignedAssembler:
    """Frames, masks, references and links in any order -> :class:`Aligned`, to ``deliver``.

    ``has_link_publisher()`` says whether links are on the way (a frame without
    one then waits for it); ``warn`` receives the problems an operator should see.
    Thread-safe: the executor's callbacks and a reset from a node's worker thread
    (time jumping back) may come at once.
    """

    MAX_PENDING = 16  # frames held for a link or for a reference (two sets of 8), each map

    def __init__(
        self,
        deliver: Callable[[Aligned], None],
        has_link_publisher: Callable[[], bool],
        warn: Callable[[str], None],
        error: Callable[[str], None],
    ) -> None:
        self.deliver = deliver
        self.has_link_publisher = has_link_publisher
        self.warn = warn
        self.error = error
        self.refs = ReferenceCache()
        self.matcher = StampMatcher()
        # frame stamp -> its reference's stamp
        self.links: collections.OrderedDict[int, int] = collections.OrderedDict()
        # (frame, mask) awaiting a link
        self.unlinked: collections.OrderedDict[int, tuple] = collections.OrderedDict()
        # (frame, mask) awaiting a reference, by (reference stamp, frame stamp)
        self.waiting: collections.OrderedDict[tuple[int, int], tuple] = collections.OrderedDict()
        self.newest_link = -1  # stamp of the latest frame whose link arrived
        self._lock = threading.RLock()

    @_locked
    def add_reference(self, frame: Frame) -> None:
        """Take a reference frame; deliver the frames that were waiting for it."""
        self.refs.add(frame)
        # its frames that came first, taken out before any is delivered: a delivery may reset
        # the assembler (a node whose time jumped back clears it from the same thread)
        mine = [self.waiting.pop(k) for k in [k for k in self.waiting if k[0] == frame.stamp_ns]]
        for frame_and_mask in mine:
            self._deliver(*frame_and_mask, frame)

    @_locked
    def add_link(self, stamp: int, ref_stamp: int) -> None:
        """Take the link naming the reference (``ref_stamp``) of the frame stamped ``stamp``."""
        if stamp in self.unlinked:
            self._with_reference(*self.unlinked.pop(stamp), ref_stamp)
        else:
            bounded_put(self.links, stamp, ref_stamp, 8 * self.MAX_PENDING)
        # Links come in frame order (one writer, reliable): a frame older than the newest link and
        # still without its own lost it (e.g. published before the link reader was matched); it
        # would wait for ever. (The newest is the last to arrive, so a bag replayed from its start
        # again resets it.)
        self.newest_link = stamp
        lost = [t for t in self.unlinked if t < stamp]
        for t in lost:
            del self.unlinked[t]
        if lost:
            self._link_lost(len(lost))

    def _link_lost(self, n: int) -> None:
        """Warn that ``n`` frames lost their link and were skipped."""
        self.warn(f"{n} aligned frame(s) whose aligned/reference_stamp never came: skipped")

    @_locked
    def add_frame(self, frame: Frame) -> None:
        """Take an aligned frame's pixels (paired with its mask by stamp)."""
        pair = self.matcher.add_a(frame.stamp_ns, frame)
        if pair:
            self._pair(*pair)

    @_locked
    def add_mask(self, mask: Frame) -> None:
        """Take an aligned frame's mask (mono, nonzero where valid)."""
        if mask.image.ndim != 2:
            self.error("bad mask image: not mono8")
            return
        pair = self.matcher.add_b(mask.stamp_ns, mask.image > 0)
        if pair:
            self._pair(*pair)

    def _pair(self, frame: Frame, mask: np.ndarray) -> None:
        """Find the reference of a frame with its mask: by its link, or the latest before it."""
        if mask.shape != frame.image.shape[:2]:
            self.error(f"mask shape {mask.shape} does not match image {frame.image.shape[:2]}")
            return
        if frame.stamp_ns in self.links:
            self._with_reference(frame, mask, self.links.pop(frame.stamp_ns))
        elif frame.stamp_ns < self.newest_link:  # a later frame's link came first: this one's lost
            self._link_lost(1)
        elif self.has_link_publisher():  # its link is on the way
            if bounded_put(self.unlinked, frame.stamp_ns, (frame, mask), self.MAX_PENDING):
                self.warn("aligned frames without their aligned/reference_stamp: oldest dropped")
        else:  # no link publisher: the latest reference not later than the frame
            ref = self.refs.for_stamp(frame.stamp_ns)
            if ref is None:
                self.warn("aligned frame without a reference yet: skipped")
                return
            self._deliver(frame, mask, ref)

    def _with_reference(self, frame: Frame, mask: np.ndarray, ref_stamp: int) -> None:
        """Deliver a linked frame, or hold it until its reference arrives."""
        ref = self.refs.get(ref_stamp)
        if ref is not None:
            self._deliver(frame, mask, ref)
        elif bounded_put(
            self.waiting, (ref_stamp, frame.stamp_ns), (frame, mask), self.MAX_PENDING
        ):
            self.warn("aligned frames whose reference never arrived: oldest dropped")

    def _deliver(self, frame: Frame, mask: np.ndarray, ref: Frame) -> None:
        """Hand the assembled :class:`Aligned` to ``deliver``.

        A mask that is a rectangle (an integer crop's) is kept as that rectangle only.
        """
        box = common_valid_box([mask])
        self.deliver(
            Aligned(
                frame.stamp_ns,
                frame.image,
                mask if box is None else None,
                ref,
                np.eye(3),
                None,
                frame.frame_id,
                frame.received,
                box=box,
            )
        )

    @_locked
    def clear(self) -> None:
        """Forget everything held (a reset)."""
        self.refs.clear()
        self.matcher.clear()
        self.links.clear()
        self.unlinked.clear()
        self.waiting.clear()
        self.newest_link = -1


def bounded_put(store: collections.OrderedDict, key, value, maxlen: int) -> bool:
    """Set ``store[key] = value``, drop the oldest beyond ``maxlen``; True if any was dropped."""
    store[key] = value
    dropped = False
    while len(store) > maxlen:
        store.popitem(last=False)
        dropped = True
    return dropped
