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

    Raises ``ValueError`` naming the parameter for a value of the wrong type or out of range.
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
        bad = next(s for s in specs if s.name == k).check(v)
        if bad:
            raise ValueError(bad)
        values[k] = float(v) if isinstance(values[k], float) else v
    return values, extra
