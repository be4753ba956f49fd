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
        descriptor = ParameterDescriptor(
            name=self.name, description=self.description, read_only=self.read_only
        )
        if self.min is not None and self.max is not None:
            if isinstance(self.default, bool):
                pass
            elif isinstance(self.default, int):
                descriptor.integer_range = [
                    IntegerRange(from_value=int(self.min), to_value=int(self.max), step=0)
                ]
            elif isinstance(self.default, float):
                descriptor.floating_point_range = [
                    FloatingPointRange(
                        from_value=float(self.min), to_value=float(self.max), step=0.0
                    )
                ]
        if self.choices:
            descriptor.additional_constraints = "one of: " + ", ".join(self.choices)
        return descriptor


def declare_params(
    node: Node, params: Iterable[Param], on_change: Callable[[str, Any], None] | None = None
) -> dict[str, Param]:
    """Declare ``params`` on ``node`` and guard them at run time.

    Parameters
    ----------
    node : rclpy.node.Node
        The node to declare them on.
    params : iterable of Param
        The parameters, with defaults, descriptions and ranges.
    on_change : callable, optional
        ``on_change(name, value)`` runs after each accepted run-time change.

    Returns
    -------
    dict of str to Param
        The parameters by name.

    Notes
    -----
    A value given at start-up (``--ros-args -p`` or ``--params-file``) that is of the wrong
    type or out of range is rejected with an error log and the default is kept. Changes at run
    time are validated by :meth:`Param.check`; a rejected change leaves the old value and
    returns the reason to the caller of set_parameters.
    """
    spec = {param.name: param for param in params}
    for param in spec.values():
        _declare_one(node, param)
    node.add_on_set_parameters_callback(_validator(node, spec))
    if on_change is not None:

        def after(changes: list[Parameter]) -> None:
            for change in changes:
                if change.name in spec:
                    on_change(change.name, change.value)

        node.add_post_set_parameters_callback(after)
    return spec


def _declare_one(node: Node, param: Param) -> None:
    """Declare ``param``, falling back to its default if the start-up value is rejected."""
    try:
        node.declare_parameter(param.name, param.default, param.descriptor())
        bad = param.check(node.get_parameter(param.name).value)
    except (InvalidParameterTypeException, InvalidParameterValueException) as exc:
        bad = str(exc).splitlines()[0]
        node.undeclare_parameter(param.name) if node.has_parameter(param.name) else None
    if bad:
        node.get_logger().error(
            f"parameter rejected at start-up, keeping default {param.default!r}: {bad}"
        )
        if node.has_parameter(param.name):
            node.undeclare_parameter(param.name)
        node.declare_parameter(param.name, param.default, param.descriptor(), ignore_override=True)


def _validator(node: Node, spec: dict[str, Param]) -> Callable[[list[Parameter]], Any]:
    """Return the on-set-parameters callback that checks changes against ``spec``."""

    def validate(changes: list[Parameter]) -> SetParametersResult:
        for change in changes:
            param = spec.get(change.name)
            if param is None:
                continue
            if param.read_only:
                return SetParametersResult(successful=False, reason=f"{param.name} is read-only")
            why = param.check(change.value)
            if why:
                node.get_logger().warning(f"parameter change rejected: {why}")
                return SetParametersResult(successful=False, reason=why)
        return SetParametersResult(successful=True)

    return validate
