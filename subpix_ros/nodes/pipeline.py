"""pipeline: every subpix_ros node in one process, stages handing frames in memory.

The camera is subscribed once (``image`` / ``image/compressed``, by the
registration node) and each frame goes to the registration and mosaic stages
directly; aligned frames go to the shift stage, shifts with their frames to
the reconstruction stage, telemetry samples to frame selection: no DDS hop
inside. Every stage still publishes its public topics (the same names as the
separate nodes) and its /diagnostics. Runs on one executor thread (``SUBPIX_EXECUTOR``,
:func:`subpix_ros.nodes.run.executor_kind`).

Parameters are per stage, as for the separate nodes (node names
``telemetry_node``, ``registration_node``, ``shift_node``,
``reconstruction_node``, ``mosaic_node``), so one params file serves both
layouts. A node-name remap for every node (``-r __node:=NAME``) would give them all
the same name and is refused (exit status 2); one node is renamed with its own prefix,
``-r registration_node:__node:=reg_a``. ``--no-telemetry`` leaves the telemetry stage
out (e.g. when the telemetry comes from a bag). ``--monitor`` adds ``monitor_node`` (live
Foxglove view), fed the camera frames, shifts (with their standard errors)
and super-resolved images in memory.
"""

from __future__ import annotations

import sys
from typing import Sequence

from subpix_ros.nodes.run import run_nodes


def build(with_telemetry: bool = True, with_monitor: bool = False):
    """Create and wire the stages; returns the list of nodes (rclpy must be initialised)."""
    from subpix_ros.nodes.mosaic_node import MosaicNode
    from subpix_ros.nodes.reconstruction_node import ReconstructionNode
    from subpix_ros.nodes.registration_node import RegistrationNode
    from subpix_ros.nodes.shift_node import ShiftNode

    reg = RegistrationNode()
    shift = ShiftNode(subscribe_inputs=False)
    recon = ReconstructionNode(subscribe_inputs=False)
    mosaic = MosaicNode(subscribe_inputs=False)
    reg.listen(
        "frame", mosaic.handle_frame
    )  # camera -> registration (subscribed) and mosaic (in memory)
    reg.listen("aligned", shift.handle_aligned)
    shift.listen("shift", recon.handle_shift)
    nodes = [reg, shift, recon, mosaic]
    if with_monitor:
        from subpix_ros.nodes.monitor_node import MonitorNode

        mon = MonitorNode(subscribe_inputs=False)
        reg.listen("frame", mon.handle_frame)
        shift.listen("shift", mon.handle_shift)
        recon.listen("super_resolved", mon.handle_super_resolved)
        nodes.append(mon)
    if with_telemetry:
        from subpix_ros.nodes.telemetry_node import TelemetryNode

        tel = TelemetryNode()
        tel.listen("sample", reg.handle_telemetry)
        nodes.insert(0, tel)
    return nodes


#: The node-name remaps rcl knows (``__name`` is the older spelling of ``__node``).
_NAME_REMAPS = ("__node", "__name")


def global_name_remap(argv: Sequence[str]) -> str | None:
    """Return the first node-name remap in ``argv`` that applies to every node, or None.

    Parameters
    ----------
    argv : sequence of str
        A command line; ROS arguments follow ``--ros-args`` (up to ``--``).

    Returns
    -------
    str or None
        The rule as given (``__node:=cam_pipe``) for a ``-r`` / ``--remap`` of ``__node`` or
        ``__name`` without a ``node:`` prefix; None if there is none. rcl applies such a rule
        to every node of the process: the pipeline's nodes would all take that one name.
    """
    in_ros = False
    args = iter(argv)
    for arg in args:
        if arg == "--ros-args":
            in_ros = True
        elif arg == "--":
            in_ros = False
        elif in_ros and arg in ("-r", "--remap"):
            rule = next(args, "")
            if rule.split(":=", 1)[0] in _NAME_REMAPS:
                return rule
    return None


def main(args: Sequence[str] | None = None) -> int:
    """Run the in-process pipeline (console entry point)."""
    argv = list(sys.argv if args is None else args)
    rule = global_name_remap(argv)
    if rule is not None:
        name = rule.split(":=", 1)[1]
        print(
            f"pipeline: -r {rule} would give every node of the pipeline the name {name!r}; "
            f"rename one node with its own prefix, e.g. -r registration_node:__node:={name}",
            file=sys.stderr,
        )
        return 2
    with_telemetry = "--no-telemetry" not in argv
    with_monitor = "--monitor" in argv
    argv = [a for a in argv if a not in ("--no-telemetry", "--monitor")]
    nodes: list = []

    def factory(i):
        def make():
            if not nodes:
                nodes.extend(build(with_telemetry, with_monitor))
            return nodes[i]

        return make

    count = (5 if with_telemetry else 4) + (1 if with_monitor else 0)
    try:
        return run_nodes([factory(i) for i in range(count)], argv, threads=max(4, count))
    except Exception as exc:
        from subpix_ros.monitor import MonitorError

        if not isinstance(exc, MonitorError):
            raise
        print(str(exc), file=sys.stderr)  # the monitor's exposure rules: one line, exit status 2
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
