"""Typed statistics of a stage (the nodes turn them into DiagnosticStatus values)."""

from __future__ import annotations

import collections
from dataclasses import dataclass, field, fields


class StageTimes:
    """Durations of a stage's step (ms): the last, median, maximum of the last ``history``."""

    def __init__(self, history: int = 200) -> None:
        self._d: collections.deque[float] = collections.deque(maxlen=history)

    def add(self, ms: float) -> None:
        """Record one duration, ms."""
        self._d.append(float(ms))

    def clear(self) -> None:
        """Forget every duration."""
        self._d.clear()

    @property
    def last(self) -> float | None:
        """The latest duration, ms (None before the first)."""
        return self._d[-1] if self._d else None

    @property
    def p50(self) -> float | None:
        """The median of the kept durations (the upper one of an even count), ms."""
        return sorted(self._d)[len(self._d) // 2] if self._d else None

    @property
    def max(self) -> float | None:
        """The longest kept duration, ms."""
        return max(self._d) if self._d else None

    def as_dict(self) -> dict:
        """Return last, p50, max (ms) and the count ``n`` as a dict."""
        return {"last": self.last, "p50": self.p50, "max": self.max, "n": len(self._d)}


@dataclass
class StageStats:
    """Counters every stage keeps.

    ``frames_in``: inputs offered; ``kept``: inputs used; ``skipped_by_reason``:
    inputs left out by design, per reason; ``dropped``: inputs lost (not by
    design: a set cut short, an input that never found its partner);
    ``fallbacks``: a cheaper or safer path taken; ``errors`` and
    ``last_error``; ``warnings`` and ``last_warning``; ``resets`` when time
    jumped back; ``times``: the stage's step durations (ms).
    """

    frames_in: int = 0
    kept: int = 0
    skipped_by_reason: dict[str, int] = field(default_factory=dict)
    dropped: int = 0
    fallbacks: int = 0
    errors: int = 0
    last_error: str = ""
    warnings: int = 0
    last_warning: str = ""
    resets: int = 0
    times: StageTimes = field(default_factory=StageTimes)

    @property
    def skipped(self) -> int:
        """Inputs skipped for any reason."""
        return sum(self.skipped_by_reason.values())

    def skip(self, reason: str) -> None:
        """Count one input skipped for ``reason``."""
        self.skipped_by_reason[reason] = self.skipped_by_reason.get(reason, 0) + 1

    def as_dict(self) -> dict:
        """Return every counter as plain values (``times`` as a dict), with ``skipped`` added."""
        out = {}
        for f in fields(self):
            v = getattr(self, f.name)
            out[f.name] = (
                v.as_dict()
                if isinstance(v, StageTimes)
                else (dict(v) if isinstance(v, dict) else v)
            )
        out["skipped"] = self.skipped
        return out


@dataclass
class RegistrationStats(StageStats):
    """Registration: ``fallbacks`` counts tracking fallbacks to the full search."""

    tracked: int = 0
    references: int = 0
    references_predicted: int = 0
    registration_failures: int = 0
    reference_stamp_ns: int | None = None
    reference_reason: str = ""
    last_selection: str = ""
    last_tracking_fallback: str = ""
    inliers: int | None = None
    rms_px: float | None = None
    rms_along_px: float | None = None
    rms_cross_px: float | None = None
    warped: bool | None = None
    # METHODS eq. 1 against the frames: the last aligned frames' shifts fitted to the
    # telemetry's expected ones (core.timing_check; None: not enough to tell yet)
    telemetry_pairs: int = 0
    telemetry_scale: float | None = None
    telemetry_rotation_deg: float | None = None
    telemetry_agrees: bool | None = None
    telemetry_check: str = ""


@dataclass
class ShiftStats(StageStats):
    """Shift estimation: ``kept`` counts published shifts, ``skipped_by_reason`` the rest."""

    u: float | None = None
    v: float | None = None
    u_std: float | None = None
    v_std: float | None = None
    cond: float | None = None
    pixels: int | None = None
    iterations: int | None = None


@dataclass
class ReconstructionStats(StageStats):
    """Reconstruction: ``kept`` counts images made; ``fallbacks`` the images that fell back."""

    sets_complete: int = 0
    sets_incomplete: int = 0
    sets_flushed: int = 0
    sets_dropped: int = 0
    sets_skipped_budget: int = 0  # sets left out for max_cpu_cores (their frames: "cpu_budget")
    set_cpu_time_s: float | None = None  # CPU seconds of the last set's reconstruction
    pending_sets: int = 0
    method: str = ""
    fell_back: bool | None = None
    fallback_reason: str = ""
    noise_sigma: float | None = None
    # frames used in the last image (fewer than the set under max_memory_mb)
    frames: int | None = None
    memory_estimate_mb: float | None = None  # predicted working memory of the last reconstruction
    memory_reduction: str = ""  # what max_memory_mb gave up in the last one ("" nothing)
    memory_reduced: int = 0  # images made with a reduction
    shifts_disputed: int = 0  # given shifts replaced by the frames' own registration
    frames_without_shift: int = 0  # aligned frames no shift came for (let go by the matcher)
    # motion blur (du, dv) LR px modelled in the last image: exposure_s x the set's image velocity
    # (None: exposure_s 0 or no velocity fitted)
    motion_blur_px: tuple[float, float] | None = None
    # resident memory handed back after the last set (release_memory; None: not asked or no glibc)
    released_mb: float | None = None
    # buffers the solve keeps for the next set (frame spectra, luminance, HR spectrum), MB
    workspace_mb: float = 0.0


@dataclass
class MosaicStats(StageStats):
    """Mosaic: ``kept`` counts frames added; ``skipped_by_reason['min_interval']`` the gate."""

    in_canvas: int = 0  # frames in the current canvas (a reset starts a new one)
    seam_residual_px: float | None = None
