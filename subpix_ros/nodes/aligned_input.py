"""Aligned frames arriving over DDS, reassembled into :class:`payloads.Aligned`.

Subscribes ``aligned`` + ``aligned/mask`` (paired by exact header stamp),
``aligned/reference`` (latched) and ``aligned/reference_stamp``
(sensor_msgs/TimeReference: the frame's stamp -> its reference's stamp) and
hands the decoded messages to :class:`~subpix_ros.stages.aligned_assembly.AlignedAssembler`,
which pairs them in any arrival order. Used by the shift and reconstruction
nodes; in the single-process pipeline they get the objects directly instead.
"""

from __future__ import annotations

from typing import Callable

from sensor_msgs.msg import Image, TimeReference

from subpix_ros.nodes import payloads as pl
from subpix_ros.nodes.qos import SequenceGaps, latched_qos, reliable_qos
from subpix_ros.stages.aligned_assembly import AlignedAssembler, ReferenceCache, StampMatcher  # noqa: F401
from subpix_ros.stages.aligned_assembly import bounded_put as _bounded_put  # noqa: F401


class AlignedInput:
    """The four subscriptions of a node that consumes aligned frames."""

    MAX_PENDING = AlignedAssembler.MAX_PENDING

    def __init__(self, node, on_aligned: Callable[[pl.Aligned], None], depth: int = 10) -> None:
        self.node = node
        self.on_aligned = on_aligned
        self.assembler = AlignedAssembler(
            lambda a: self.on_aligned(a), self._has_link_publisher, node.diag.warn, node.diag.error
        )
        q = reliable_qos(depth)
        # The reference subscription is made FIRST: rclpy's executors take the ready subscriptions
        # of a node in the order they were made, so a new reference waiting beside the first frame
        # aligned to it is taken before that frame (made after, the frame went with the previous
        # reference). Depth 8: two references in quick succession are both kept.
        node.create_subscription(
            Image,
            "aligned/reference",
            self._on_reference,
            latched_qos(ReferenceCache.MAXLEN),
            raw=True,
        )
        # links are tiny: a deep queue, so a busy node never loses one (its frame would wait);
        # transient local as published, so links sent before this reader matched still come
        self.link_sub = node.create_subscription(
            TimeReference,
            "aligned/reference_stamp",
            self._on_link,
            latched_qos(max(depth, 100)),
            raw=True,
        )
        # aligned frames that never reached the callback (replaced in the history): counted
        self.gaps = SequenceGaps(node, "aligned", node.diag, depth, "aligned frames")
        self.gaps.subscribe(Image, self._on_aligned, q)
        node.create_subscription(Image, "aligned/mask", self._on_mask, q, raw=True)

    refs = property(lambda self: self.assembler.refs)
    unlinked = property(lambda self: self.assembler.unlinked)

    def _has_link_publisher(self) -> bool:
        return self.link_sub.get_publisher_count() > 0

    def _decode(self, raw: bytes, what: str) -> pl.Frame | None:
        try:
            return pl.frame_from_cdr(raw)
        except Exception as exc:  # noqa: BLE001 - bad input must not kill the node
            self.node.diag.error(f"bad {what} image: {exc}")
            return None

    def _on_reference(self, raw: bytes) -> None:
        f = self._decode(raw, "reference")
        if f is not None:
            self.assembler.add_reference(f)

    def _on_link(self, raw: bytes) -> None:
        try:
            stamp, ref_stamp = pl.reference_link_from_cdr(raw)
        except Exception as exc:  # noqa: BLE001 - bad input must not kill the node
            self.node.diag.error(f"bad aligned/reference_stamp message: {exc}")
            return
        self.assembler.add_link(stamp, ref_stamp)

    def _on_aligned(self, raw: bytes) -> None:
        self.node.diag.rate("input").tick()
        f = self._decode(raw, "aligned")
        if f is not None:
            self.assembler.add_frame(f)

    def _on_mask(self, raw: bytes) -> None:
        m = self._decode(raw, "mask")
        if m is not None:
            self.assembler.add_mask(m)

    def clear(self) -> None:
        """Drop the frames and masks waiting to be assembled."""
        self.assembler.clear()
