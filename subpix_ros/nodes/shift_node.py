"""shift_node: sub-pixel shift of each aligned frame against its reference.

Subscribes ``aligned`` + ``aligned/mask`` (matched by stamp) and
``aligned/reference`` (each aligned frame belongs to the latest reference not
later than it). Publishes ``shift`` (geometry_msgs/Vector3Stamped: x = u rows,
y = v columns, z = intensity offset, in the estimator's convention: content
at (r, c) in the reference appears at (r + u, c + v) in the aligned frame;
header = the aligned frame's) and, just before it, ``shift/std``
(Vector3Stamped, same header: x, y = the standard errors of u and v in px,
z = 0). Quality figures (condition, pixels, iterations) go to /diagnostics; a failed estimate publishes nothing
and the reason goes to /diagnostics. The estimation is
:class:`~subpix_ros.stages.ShiftStage`'s.
"""

from __future__ import annotations

from geometry_msgs.msg import Vector3Stamped

from subpix_ros.nodes import payloads as pl
from subpix_ros.nodes.aligned_input import AlignedInput
from subpix_ros.nodes.base import StageNode, ros_params
from subpix_ros.nodes.params import Param
from subpix_ros.nodes.qos import reliable_qos
from subpix_ros.nodes.run import run_nodes
from subpix_ros.stages import Shift, ShiftStage


class ShiftNode(StageNode):
    """Sub-pixel shift of each aligned frame: :class:`ShiftStage` between ROS topics."""

    MAIN_INPUTS = ("aligned",)
    queued_items = "aligned frame(s)"
    PARAMS = (
        Param(
            "queue_size",
            4,
            "aligned frames waiting for the worker; the oldest is dropped beyond this",
            1,
            100,
        ),
        *ros_params(ShiftStage.PARAMS),
    )

    def __init__(self, *, subscribe_inputs: bool = True, name: str = "shift_node", **kw) -> None:
        super().__init__(name, subscribe_inputs=subscribe_inputs, **kw)
        self.make_stage(ShiftStage)
        self.pub = self.create_publisher(
            Vector3Stamped, "shift", reliable_qos(20), event_callbacks=self.output_events("shift")
        )
        self.pub_std = self.create_publisher(
            Vector3Stamped,
            "shift/std",
            reliable_qos(20),
            event_callbacks=self.output_events("shift/std"),
        )
        self.make_worker(self._process, self.param("queue_size"))
        self.inputs = AlignedInput(self, self.handle_aligned) if subscribe_inputs else None

    published = property(lambda self: self.stage.stats.kept)
    failed = property(lambda self: self.stage.stats.skipped)

    def handle_aligned(self, aligned: pl.Aligned) -> None:
        """Queue an aligned frame for the worker (the oldest is dropped beyond queue_size)."""
        self.worker.put(aligned)

    def reset(self) -> None:
        """Forget the stream (time jumped back): the stage and the inputs held."""
        super().reset()
        if self.inputs is not None:
            self.inputs.clear()

    def _process(self, a: pl.Aligned) -> None:
        self.check_time(a.stamp_ns)
        s = self.stage.add(a)
        st = self.stage.stats
        if not isinstance(s, Shift):
            self.diag.set(shift_failures=st.skipped)
            return
        self.pub_std.publish(pl.shift_std_cdr(s))
        self.pub.publish(pl.shift_cdr(s))
        self.output(
            "shift",
            (s, a),
            a.received,
            "estimate_ms",
            u=st.u,
            v=st.v,
            u_std=st.u_std,
            v_std=st.v_std,
            cond=st.cond,
            pixels=st.pixels,
            iterations=st.iterations,
            shifts_published=st.kept,
        )
        self.diag.ok()


def main(args=None) -> int:
    """Run shift_node (console entry point)."""
    return run_nodes([ShiftNode], args, large_messages=False)  # shifts only: a small segment


if __name__ == "__main__":
    raise SystemExit(main())
