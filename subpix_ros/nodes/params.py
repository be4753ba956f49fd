"""Node parameters: ROS descriptors and start-up / run-time validation of stage :class:`Spec` s."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Iterable, Sequence

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.node import Node
from rclpy.parameter import Parameter

from ..stages.params import Spec, order_error

__all__ = ["Param", "declare_params", "explain_rejection", "short_reason"]


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
        constraints = []
        if self.choices:
            constraints.append("one of: " + ", ".join(self.choices))
        if self.at_most:
            constraints.append(f"at most {self.at_most}")
        descriptor.additional_constraints = "; ".join(constraints)
        return descriptor

    def read_only_reason(self) -> str:
        """Return why a change of this read-only parameter is refused."""
        return (
            f"{self.name} is read-only: it takes effect only at start-up "
            f"(--ros-args -p {self.name}:=... or a params file)"
        )


def short_reason(param: Param, value: Any, reason: str) -> str:
    """Return what ``param`` accepts, briefly, for a summary of rejected values.

    E.g. ``range 2..4`` for a number out of range, ``one of map, pinv`` for a string not among
    the choices, ``expected float`` for a value of another type; else ``reason`` without the
    leading parameter name.
    """
    if type(value) is not type(param.default) and param.coerce(value) is value:
        return f"expected {type(param.default).__name__}"
    if param.min is not None and param.max is not None and not param.min <= value <= param.max:
        return f"range {param.min}..{param.max}"
    if param.choices and value not in param.choices:
        return "one of " + ", ".join(param.choices)
    prefix = f"{param.name}: "
    return reason[len(prefix) :] if reason.startswith(prefix) else reason


def declare_params(
    node: Node,
    params: Iterable[Param],
    on_change: Callable[[str, Any], None] | None = None,
    on_rejected: Callable[[Param, Any, str], None] | None = None,
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
    on_rejected : callable, optional
        ``on_rejected(param, value, reason)`` runs for each value given at start-up that is
        rejected (after the error log).

    Returns
    -------
    dict of str to Param
        The parameters by name.

    Notes
    -----
    A value given at start-up (``--ros-args -p`` or ``--params-file``) that is of the wrong
    type or out of range, or that breaks a rule between two parameters (``Spec.at_most``), is
    rejected with an error log and the default is kept. An integer for a double parameter is
    taken as a double, at start-up and at run time (:meth:`Spec.coerce`). Changes at run
    time are validated by :meth:`Param.check` and the rules between parameters; a rejected
    change leaves the old value and returns the reason to the caller of set_parameters
    (:func:`explain_rejection` logs it).
    """
    spec = {param.name: param for param in params}
    values, rejected = _start_values(node, spec)
    for name, param in spec.items():
        try:
            node.declare_parameter(name, values[name], param.descriptor(), ignore_override=True)
        except (InvalidParameterTypeException, InvalidParameterValueException) as exc:
            rejected[name] = (values[name], str(exc).splitlines()[0])
            node.declare_parameter(name, param.default, param.descriptor(), ignore_override=True)
    for name, (value, why) in rejected.items():
        param = spec[name]
        node.get_logger().error(
            f"parameter {name} = {value!r} rejected at start-up, default {param.default!r} "
            f"used: {why}"
        )
        if on_rejected is not None:
            on_rejected(param, value, why)
    node.add_pre_set_parameters_callback(_coercer(spec))
    node.add_on_set_parameters_callback(_validator(node, spec))
    if on_change is not None:

        def after(changes: list[Parameter]) -> None:
            for change in changes:
                if change.name in spec:
                    on_change(change.name, change.value)

        node.add_post_set_parameters_callback(after)
    return spec


def _start_values(
    node: Node, spec: dict[str, Param]
) -> tuple[dict[str, Any], dict[str, tuple[Any, str]]]:
    """Return the start-up value of each parameter and the rejected ones ``{name: (value, why)}``.

    A given value (a parameter override) that fails :meth:`Param.check` is rejected. Where two
    accepted values break a rule between them, the given one is rejected (both given: the
    bounded one, e.g. ``min_frames`` for ``min_frames`` <= ``n_frames``).
    """
    # rclpy keeps the start-up values (--ros-args -p, --params-file, parameter_overrides) here
    overrides = getattr(node, "_parameter_overrides", {})
    values = {name: param.default for name, param in spec.items()}
    given: set[str] = set()
    rejected: dict[str, tuple[Any, str]] = {}
    for name, param in spec.items():
        if name not in overrides:
            continue
        value = overrides[name].value
        bad = param.check(param.coerce(value))
        if bad:
            rejected[name] = (value, bad)
        else:
            values[name] = param.coerce(value)
            given.add(name)
    for param in spec.values():
        lo, hi = param.name, param.at_most
        if hi in given and lo not in given and values[lo] > values[hi]:
            values[lo] = values[hi]  # the default follows the given value (stages.params)
        while hi in spec and values[lo] > values[hi]:
            culprit = lo if lo in given else hi
            if culprit not in given:  # the defaults themselves (a declaration error)
                raise ValueError(order_error([param], values))
            rejected[culprit] = (values[culprit], order_error([param], values, culprit))
            values[culprit] = spec[culprit].default
            given.discard(culprit)
    return values, rejected


def _coercer(spec: dict[str, Param]) -> Callable[[list[Parameter]], list[Parameter]]:
    """Return the pre-set-parameters callback that converts values as :meth:`Spec.coerce` does.

    An integer for a double parameter becomes the double (and a number for a text parameter
    that takes numbers its text) before rclpy checks the type against the descriptor.
    """

    def coerce(changes: list[Parameter]) -> list[Parameter]:
        out = []
        for change in changes:
            param = spec.get(change.name)
            if param is not None and param.coerce(change.value) is not change.value:
                change = Parameter(change.name, value=param.coerce(change.value))
            out.append(change)
        return out

    return coerce


def _validator(node: Node, spec: dict[str, Param]) -> Callable[[list[Parameter]], Any]:
    """Return the on-set-parameters callback that checks changes against ``spec``."""

    def validate(changes: list[Parameter]) -> SetParametersResult:
        proposed = {name: node.get_parameter(name).value for name in spec}
        named = [change.name for change in changes if change.name in spec]
        for change in changes:
            param = spec.get(change.name)
            if param is None:
                continue
            if param.read_only:
                return SetParametersResult(successful=False, reason=param.read_only_reason())
            why = param.check(change.value)
            if why:
                return SetParametersResult(successful=False, reason=why)
            proposed[change.name] = change.value
        why = order_error(list(spec.values()), proposed, named[0] if len(named) == 1 else None)
        if why:
            return SetParametersResult(successful=False, reason=why)
        return SetParametersResult(successful=True)

    return validate


def explain_rejection(
    node: Node,
    spec: dict[str, Param],
    changes: Sequence[Parameter],
    result: SetParametersResult,
) -> SetParametersResult:
    """Log a refused run-time change (one warning line) and return ``result`` with our reason.

    rclpy refuses a value of the wrong type, out of the descriptor's range or for a read-only
    parameter before the node's callbacks run, with its own reason and no log line. This
    gives the reason :meth:`Param.check` (or :meth:`Param.read_only_reason`) gives, and logs
    ``parameter NAME = VALUE rejected: REASON``.

    Parameters
    ----------
    node : rclpy.node.Node
        The node whose parameters were set.
    spec : dict of str to Param
        Its declared parameters (:func:`declare_params`).
    changes : sequence of rclpy.parameter.Parameter
        The changes set together (one, from set_parameters or the set_parameters service).
    result : SetParametersResult
        rclpy's result; returned unchanged when successful.

    Returns
    -------
    SetParametersResult
        The result, with the reason replaced by the parameter's own where it has one.
    """
    if result.successful:
        return result
    if len(changes) == 1 and changes[0].name in spec:
        param, value = spec[changes[0].name], changes[0].value
        ours = param.read_only_reason() if param.read_only else param.check(value)
        if ours:
            result = SetParametersResult(successful=False, reason=ours)
    said = ", ".join(f"{change.name} = {change.value!r}" for change in changes)
    node.get_logger().warning(f"parameter {said} rejected: {result.reason}")
    return result
