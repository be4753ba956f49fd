"""Node parameters: ROS descriptors and start-up / run-time validation of stage :class:`Spec` s."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Iterable

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.node import Node
from rclpy.parameter import Parameter

from ..stages.params import Spec

__all__ = ["Param", "declare_params"]


@dataclass
class Param(Spec):
    """One declared parameter: default, description and (for numbers) a range.

    The fields and :meth:`check` are :class:`subpix_ros.stages.params.Spec`'s (a stage's
    parameters are Specs; the node declares them as Params); this adds the ROS descriptor.
    """

    def descriptor(self) -> ParameterDescriptor:
        """Return the ROS descriptor: description, read-only flag, range, choices."""
        d = ParameterDescriptor(
            name=self.name, description=self.description, read_only=self.read_only
        )
        if self.min is not None and self.max is not None:
            if isinstance(self.default, bool):
                pass
            elif isinstance(self.default, int):
                d.integer_range = [
                    IntegerRange(from_value=int(self.min), to_value=int(self.max), step=0)
                ]
            elif isinstance(self.default, float):
                d.floating_point_range = [
                    FloatingPointRange(
                        from_value=float(self.min), to_value=float(self.max), step=0.0
                    )
                ]
        if self.choices:
            d.additional_constraints = "one of: " + ", ".join(self.choices)
        return d


def declare_params(
    node: Node, params: Iterable[Param], on_change: Callable[[str, Any], None] | None = None
) -> dict[str, Param]:
    """Declare ``params`` on ``node`` and guard them at run time.

    A value given at start-up (``--ros-args -p`` or ``--params-file``) that is
    of the wrong type or out of range is rejected with an error log and the
    default is kept. Changes at run time are validated by :meth:`Param.check`;
    a rejected change leaves the old value and returns the reason to the
    caller of set_parameters. ``on_change(name, value)`` runs after accepted
    run-time changes.
    """
    spec = {p.name: p for p in params}
    for p in spec.values():
        try:
            node.declare_parameter(p.name, p.default, p.descriptor())
            bad = p.check(node.get_parameter(p.name).value)
        except (InvalidParameterTypeException, InvalidParameterValueException) as exc:
            bad = str(exc).splitlines()[0]
            node.undeclare_parameter(p.name) if node.has_parameter(p.name) else None
        if bad:
            node.get_logger().error(
                f"parameter rejected at start-up, keeping default {p.default!r}: {bad}"
            )
            if node.has_parameter(p.name):
                node.undeclare_parameter(p.name)
            node.declare_parameter(p.name, p.default, p.descriptor(), ignore_override=True)

    def validate(changes: list[Parameter]) -> SetParametersResult:
        for change in changes:
            p = spec.get(change.name)
            if p is None:
                continue
            if p.read_only:
                return SetParametersResult(successful=False, reason=f"{p.name} is read-only")
            why = p.check(change.value)
            if why:
                node.get_logger().warning(f"parameter change rejected: {why}")
                return SetParametersResult(successful=False, reason=why)
        return SetParametersResult(successful=True)

    node.add_on_set_parameters_callback(validate)
    if on_change is not None:

        def after(changes: list[Parameter]) -> None:
            for change in changes:
                if change.name in spec:
                    on_change(change.name, change.value)

        node.add_post_set_parameters_callback(after)
    return spec
