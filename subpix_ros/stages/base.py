"""What every stage shares: its parameters, statistics, problem reports and time-jump reset."""

from __future__ import annotations

from typing import Any, Callable, Mapping, Sequence

from subpix_ros.stages.params import Spec, resolve
from subpix_ros.stages.stats import StageStats

Listener = Callable[[str, str], None]  # (level "warn" | "error", message)


class Stage:
    """Base of the ROS-free stages.

    A stage owns its state and its :class:`StageStats`; results go out as
    return values. Problems (a warning or an error the operator should see)
    are counted in the stats and passed to ``on_problem(level, message)``
    when set (a node forwards them to /diagnostics).
    """

    PARAMS: Sequence[Spec] = ()
    STATS = StageStats

    def __init__(self, **params: Any) -> None:
        self.params, self.extra = resolve(self.PARAMS, params)
        self.stats = self.STATS()
        self.on_problem: Listener | None = None
        self._last_stamp_ns: int | None = None

    @classmethod
    def from_params(cls, params: Mapping[str, Any] | None = None):
        """Build the stage from a mapping of parameter names to values (missing: defaults)."""
        return cls(**dict(params or {}))

    def param(self, name: str) -> Any:
        """Return the current value of the parameter ``name``."""
        return self.params[name]

    def configure(self, **changes: Any) -> None:
        """Change parameters at run time (checked: a bad value raises ``ValueError``, no change)."""
        values, extra = resolve(self.PARAMS, {**self.params, **self.extra, **changes})
        self.params, self.extra = values, extra

    def warn(self, message: str) -> None:
        """Count a warning and pass it to ``on_problem``."""
        self.stats.warnings += 1
        self.stats.last_warning = message
        if self.on_problem is not None:
            self.on_problem("warn", message)

    def error(self, message: str) -> None:
        """Count an error and pass it to ``on_problem``."""
        self.stats.errors += 1
        self.stats.last_error = message
        if self.on_problem is not None:
            self.on_problem("error", message)

    def check_time(self, stamp_ns: int) -> bool:
        """Reset when time jumps back (a looped bag, another stream); True if it did."""
        last = self._last_stamp_ns
        self._last_stamp_ns = stamp_ns
        if last is not None and stamp_ns < last:
            self.warn(f"time jumped back by {(last - stamp_ns) / 1e9:.3f} s: pipeline state reset")
            self.reset()
            self._last_stamp_ns = stamp_ns
            self.stats.resets += 1
            self.stats.times.clear()
            return True
        return False

    def reset(self) -> None:
        """Forget the stream (overridden by stages that keep any)."""
        self._last_stamp_ns = None

    def flush(self) -> list:
        """End of stream: whatever is still held (nothing by default)."""
        return []
