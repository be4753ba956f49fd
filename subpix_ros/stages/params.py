"""Stage parameters: name, default, description, range, without ROS.

The nodes declare the same specs as ROS parameters (with descriptors and
ranges), so a params file serves a node and a stage alike.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence


@dataclass
class Spec:
    """One parameter: default, description and (for numbers) a range or (strings) the choices."""

    name: str
    default: Any
    description: str
    min: float | int | None = None
    max: float | int | None = None
    choices: Sequence[str] | None = None
    read_only: bool = False
    validate: Callable[[Any], str | None] | None = None  # extra check: why a value is bad, or None
    at_most: str | None = None  # the name of a parameter this one may not exceed (order_error)
    numeric_text: bool = False  # a text parameter that takes numbers: a number is taken as text

    def coerce(self, value: Any) -> Any:
        """Return ``value`` as this parameter's type where that is what a user means.

        An integer for a float parameter (``-p exposure_s:=0``) is the float; a number for a
        text parameter that takes numbers (``numeric_text``, e.g. ``blur_sigma:=1``) is its
        text. Anything else is returned as it is (2.5 for an integer parameter stays an error
        for :meth:`check`).
        """
        if isinstance(value, bool):
            return value
        if isinstance(self.default, float) and isinstance(value, int):
            return float(value)
        if self.numeric_text and isinstance(self.default, str) and isinstance(value, (int, float)):
            return str(value)
        return value

    def check(self, value: Any) -> str | None:
        """Return why ``value`` is not acceptable, or None."""
        if type(value) is not type(self.default) and not (
            isinstance(self.default, float)
            and isinstance(value, int)
            and not isinstance(value, bool)
        ):
            return (
                f"{self.name}: expected {type(self.default).__name__}, "
                f"got {type(value).__name__} {value!r}"
            )
        if self.min is not None and value < self.min:
            return f"{self.name}: {value!r} is below the minimum {self.min}"
        if self.max is not None and value > self.max:
            return f"{self.name}: {value!r} is above the maximum {self.max}"
        if self.choices and value not in self.choices:
            return f"{self.name}: {value!r} is not one of {', '.join(self.choices)}"
        if self.validate is not None:
            bad = self.validate(value)
            if bad:
                return f"{self.name}: {bad}"
        return None


def order_error(
    specs: Sequence[Spec], values: Mapping[str, Any], changed: str | None = None
) -> str | None:
    """Return why ``values`` break a rule between two parameters (``Spec.at_most``), or None.

    Parameters
    ----------
    specs : sequence of Spec
        The parameters; a spec with ``at_most="other"`` may not exceed ``other``.
    values : mapping of str to value
        The values to check (a rule whose parameters are not both in it is not checked).
    changed : str, optional
        The parameter being changed, if one: the reason is worded from its side.

    Returns
    -------
    str or None
        The reason, naming both parameters and their values, or None if the values agree.
    """
    for spec in specs:
        hi = spec.at_most
        if hi is None or spec.name not in values or hi not in values:
            continue
        lo_value, hi_value = values[spec.name], values[hi]
        if lo_value <= hi_value:
            continue
        rule = f"{spec.name} must be at most {hi}"
        if changed == hi:
            return f"{hi}: {hi_value!r} is below {spec.name} {lo_value!r}; {rule}: lower {spec.name} first"
        return f"{spec.name}: {lo_value!r} is above {hi} {hi_value!r}; {rule}"
    return None


# parameters of the nodes' transport (queues, QoS, publishing), not of a stage's policy
NODE_ONLY = frozenset(
    {
        "camera_reliable",
        "queue_size",
        "publish_rate_hz",
        "jpeg_quality",
        "input_timeout_s",
        "latch_output",
    }
)


def resolve(
    specs: Sequence[Spec], given: Mapping[str, Any]
) -> tuple[dict[str, Any], dict[str, Any]]:
    """``(values, extra)``: every spec's value (given or default, checked) and the unknown keys.

    Raises ``ValueError`` naming the parameter for a value of the wrong type or out of range,
    and naming both for two given values that break a rule between them (:func:`order_error`;
    a default that would break it follows the given value instead).
    Keys in :data:`NODE_ONLY` are dropped.
    """
    values = {s.name: s.default for s in specs}
    known = set(values)
    extra = {}
    for k, v in given.items():
        if k in NODE_ONLY:
            continue
        if k not in known:
            extra[k] = v
            continue
        spec = next(s for s in specs if s.name == k)
        v = spec.coerce(v)
        bad = spec.check(v)
        if bad:
            raise ValueError(bad)
        values[k] = v
    _defaults_follow(specs, values, {k for k in given if k in known})
    bad = order_error(specs, values)
    if bad:
        raise ValueError(bad)
    return values, extra


def _defaults_follow(specs: Sequence[Spec], values: dict[str, Any], given: set[str]) -> None:
    """Lower a default that exceeds the given value it may not exceed (``Spec.at_most``).

    ``n_frames: 3`` alone is a set of 3 frames, not an error against the default
    ``min_frames`` 4: the default follows the value the user gave (3). Two given values that
    break the rule are left for :func:`order_error`.
    """
    for spec in specs:
        hi = spec.at_most
        if (
            hi in values
            and spec.name not in given
            and hi in given
            and values[spec.name] > values[hi]
        ):
            values[spec.name] = values[hi]
