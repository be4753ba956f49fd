"""What the stage pipeline reports for each frame, collected into per-frame records."""

from __future__ import annotations

import math
import re
import threading
from collections import Counter
from dataclasses import dataclass
from typing import Any

import numpy as np

from subpix_ros.process.products import ProductWriter, rounded
from subpix_ros.process.report_sections import SetCrop, set_crop
from subpix_ros.stages.types import bicubic_upscale

__all__ = ["reason_key"]


def reason_key(reason: str) -> str:
    """Return ``reason`` without its numbers, for counting reasons of one kind together."""
    return re.sub(r"[-+]?\d+(\.\d+)?(e[-+]?\d+)?", "#", str(reason)).strip() or "unspecified"


def _clean(value: Any) -> Any:
    """Return a JSON-safe copy of ``o``.

    Floats to 10 significant digits (:func:`rounded`), non-finite to None, numpy scalars to
    Python.
    """
    if isinstance(value, dict):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    if isinstance(value, (np.floating, float)):
        return rounded(value) if math.isfinite(float(value)) else None
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value


def _stats_dict(record: Any) -> dict:
    """Return a stage statistics record (dataclass, dict or object) as a dict."""
    if record is None:
        return {}
    if hasattr(record, "as_dict"):
        return dict(record.as_dict())
    if isinstance(record, dict):
        return dict(record)
    return dict(getattr(record, "__dict__", {}))


_TIME_KEY = re.compile(r"(^times$|_ms$|time_s$)")  # stage figures that are processing times


@dataclass
class _FrameRec:
    """One row of ``frames.csv``: what became of a frame and the registration's figures."""

    index: int
    stamp_ns: int
    status: str = "in"
    reason: str = ""
    reference_stamp_ns: int | None = None
    inliers: int | None = None
    rms_px: float | None = None
    rms_along_px: float | None = None
    rms_cross_px: float | None = None
    tracked: bool | None = None
    mosaic: bool | None = None


class _Collector:
    """Turns the pipeline's events for the frame being added into records and products."""

    def __init__(
        self, writer: ProductWriter, reg_params: dict, reg_stats: Any = None, score=None
    ) -> None:
        self.writer = writer
        # score(entry, stamp, image, reference): figures of a set added to its entry as it
        # arrives (truth PSNR, edge MTF): the images are not kept
        self.score = score
        self.reg_stats = reg_stats
        self._tracked = self._fallbacks = 0
        self.reg_params = reg_params
        self.frames: list[_FrameRec] = []
        self.current: _FrameRec | None = None
        self.shifts: dict[int, dict] = {}
        self.references: list[dict] = []
        self.sets: list[dict] = []
        self.errors: list[str] = []
        self.homographies: dict[int, np.ndarray] = {}
        self.priors: dict[int, tuple[float, float] | None] = {}
        self.ref_of: dict[int, int] = {}
        self.dtype: str | None = None
        self.shape: tuple = (0, 0)
        self.warnings: Counter = Counter()
        self.lock = threading.Lock()
        self.warning_examples: dict[str, str] = {}
        # per set's superres path: the report's crop of bicubic and super-resolved, taken as
        # the set arrives (the report need not read the full-size PNGs back)
        self.crops: dict[str, SetCrop] = {}

    # --------------------------------------------------------- pipeline callbacks
    def on_reference(self, event: Any) -> None:
        """Record a new reference and mark the current frame as one."""
        frame = getattr(event, "frame", event)
        reason = str(getattr(event, "reason", "") or "")
        stamp = int(getattr(frame, "stamp_ns"))
        self.references.append({"stamp_ns": stamp, "reason": reason})
        rec = self.current
        if rec is not None and rec.stamp_ns == stamp:
            rec.status, rec.reason, rec.reference_stamp_ns = "reference", reason, stamp

    def on_aligned(self, aligned: Any) -> None:
        """Record an aligned frame: its homography, reference link and registration figures."""
        rec = self.current
        ref = int(aligned.reference.stamp_ns)
        self.ref_of[int(aligned.stamp_ns)] = ref
        self.homographies[int(aligned.stamp_ns)] = np.asarray(
            aligned.homography, np.float64
        ).reshape(3, 3)
        self.priors[int(aligned.stamp_ns)] = (
            tuple(aligned.prior) if getattr(aligned, "prior", None) is not None else None
        )
        self.writer.homography(aligned.stamp_ns, aligned.homography)
        self.writer.reference_link(aligned.stamp_ns, ref, getattr(aligned, "frame_id", ""))
        if rec is not None and rec.stamp_ns == int(aligned.stamp_ns):
            rec.status, rec.reference_stamp_ns = "aligned", ref
            stats = self.reg_stats  # the registration stage's figures of the frame just aligned
            if stats is not None:
                rec.inliers, rec.rms_px = stats.inliers, stats.rms_px
                rec.rms_along_px, rec.rms_cross_px = stats.rms_along_px, stats.rms_cross_px
                tracked, fallbacks = stats.tracked, stats.fallbacks
                if tracked > self._tracked:
                    rec.tracked = True
                elif fallbacks > self._fallbacks:
                    rec.tracked = False
                self._tracked, self._fallbacks = tracked, fallbacks
        self.shifts[int(aligned.stamp_ns)] = {
            "stamp_ns": int(aligned.stamp_ns),
            "reference_stamp_ns": ref,
            "converged": False,
            "reason": "no shift reported",
        }

    def on_skipped(self, item: Any) -> None:
        """Record a skip: of the frame (frame selection) or of its shift (shift stage)."""
        stage, skip = item if isinstance(item, tuple) else ("", item)
        rec = self.current
        reason = str(getattr(skip, "reason", skip))
        detail = str(getattr(skip, "detail", "") or "")
        if detail:
            reason = f"{reason}: {detail}"
        stamp = getattr(skip, "stamp_ns", None)
        stamp = rec.stamp_ns if stamp is None and rec is not None else stamp
        if stamp is not None and int(stamp) in self.shifts and (not stage or "shift" in stage):
            self.shifts[int(stamp)].update(converged=False, reason=reason)
            return
        if rec is not None and (stamp is None or int(stamp) == rec.stamp_ns):
            rec.status, rec.reason = "skipped", reason

    def on_shift(self, item: Any) -> None:
        """Record a converged shift estimate and write it to the results bag."""
        shift = item[0] if isinstance(item, tuple) else item
        row = self.shifts.setdefault(int(shift.stamp_ns), {"stamp_ns": int(shift.stamp_ns)})
        row.update(
            reference_stamp_ns=int(shift.reference_stamp_ns),
            u_px=rounded(shift.u),
            v_px=rounded(shift.v),
            u_std_px=rounded(shift.u_std),
            v_std_px=rounded(shift.v_std),
            converged=True,
            reason="",
        )
        frame_id = getattr(shift, "frame_id", "")
        self.writer.shift_std(shift.stamp_ns, shift.u_std, shift.v_std, frame_id)
        self.writer.shift(shift.stamp_ns, shift.u, shift.v, shift.z, frame_id)

    def on_super_resolved(self, sr: Any) -> None:
        """Write a super-resolved image and its bicubic reference; record the set.

        The bicubic image, the report's crop and the set's scores are made on the products
        thread (in order, after the set's writes): the pipeline goes on meanwhile.
        """
        ref = sr.reference
        stamp = int(ref.stamp_ns)
        image = np.asarray(sr.image)
        frame_id = getattr(ref, "frame_id", "")
        self.writer.png(
            f"superres/{stamp}.png", image, "/super_resolved/compressed", stamp, frame_id
        )
        factor = int(getattr(sr, "factor", 0))
        bicubic = _Bicubic(ref.image, factor, image.dtype, getattr(sr, "_bicubic", None))
        self.writer.png(f"bicubic/{stamp}.png", bicubic.get)
        members = []
        for shift in getattr(sr, "shifts", []) or []:
            members.append(
                {
                    "stamp_ns": int(shift.stamp_ns),
                    "u_px": rounded(shift.u),
                    "v_px": rounded(shift.v),
                }
            )
        entry = {
            "reference_stamp_ns": stamp,
            "frames": 1 + len(members),
            "members": members,
            "method": str(getattr(sr, "method", "")),
            "fell_back": bool(getattr(sr, "fell_back", False)),
            "reason": str(getattr(sr, "reason", "") or ""),
            "blur_sigma": getattr(sr, "blur_sigma", None),
            "blur_source": getattr(sr, "blur_source", None),
            "blur_reason": str(getattr(getattr(sr, "result", None), "blur_reason", "") or ""),
            "superres": f"superres/{stamp}.png",
            "bicubic": f"bicubic/{stamp}.png",
            "shape": list(image.shape),
            "dtype": str(image.dtype),
        }
        self.sets.append(entry)
        # the set's frames are not kept for this: only the reference and the two images
        self.writer.later(self._crop_and_score, entry, image, bicubic, ref, factor)

    def _crop_and_score(
        self, entry: dict, image: np.ndarray, bicubic: _Bicubic, ref: Any, factor: int
    ) -> None:
        """Cut the set's report crop and add its scores to ``entry`` (products thread)."""
        bic = bicubic.get()
        if factor >= 1 and bic.shape == image.shape:
            self.crops[entry["superres"]] = set_crop(bic, image, factor)
        if self.score is not None:
            self.score(entry, entry["reference_stamp_ns"], image, bic, ref, factor)

    def on_warning(self, item: Any) -> None:
        """Count a warning by stage and kind (the mosaic thread warns too)."""
        stage, msg = item if isinstance(item, tuple) else ("", item)
        key = f"{stage}: {reason_key(msg)}" if stage else reason_key(msg)
        with self.lock:  # the mosaic thread warns too
            self.warnings[key] += 1
            self.warning_examples.setdefault(key, f"{stage}: {msg}" if stage else str(msg))

    def on_error(self, error: Any) -> None:
        """Record a stage error; the current frame, if still undecided, is dropped.

        A reconstruction error belongs to a set, not to the frame being read when it is
        reported (the set is solved while later frames are read): no frame is dropped for it.
        """
        stage = error[0] if isinstance(error, tuple) else ""
        if isinstance(error, tuple):
            error = f"{error[0]}: {error[1]}"
        text = " ".join(str(error).split())[:200]
        self.errors.append(text)
        rec = self.current
        if rec is not None and rec.status in ("in",) and stage != "reconstruction_node":
            rec.status, rec.reason = "dropped", f"stage error: {text}"


def _pipe_stats(pipe: Any) -> dict:
    """Return the pipeline's statistics by node name ({} if it cannot give them)."""
    try:
        record = pipe.stats()
    except Exception:  # noqa: BLE001
        return {}
    return dict(record) if isinstance(record, dict) else {}


def _diag_statuses(stats: dict) -> dict[str, tuple[int, str, dict]]:
    """Turn stage statistics into /diagnostics statuses: (level, message, flat key values)."""
    out = {}
    for name, record in stats.items():
        d = {k: v for k, v in _stats_dict(record).items() if not _TIME_KEY.search(k)}
        flat = {}
        for k, v in d.items():
            if isinstance(v, dict):
                flat.update({f"{k}.{kk}": vv for kk, vv in v.items()})
            else:
                flat[k] = v
        err = d.get("last_error") or ""
        out[str(name)] = (1 if err else 0, f"last error: {err}" if err else "ok", flat)
    return out


class _Bicubic:
    """A set's bicubic reference image, made once when first asked for (products thread)."""

    def __init__(self, reference: np.ndarray, factor: int, dtype: Any, made=None) -> None:
        self.reference, self.factor, self.dtype, self.image = reference, factor, dtype, made

    def get(self) -> np.ndarray:
        """Return the bicubic image (made on the first call)."""
        if self.image is None:
            self.image = bicubic_upscale(self.reference, self.factor, self.dtype)
        return np.asarray(self.image)
