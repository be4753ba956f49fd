"""The 8-bit previews of a processed flight: the mosaic product and the live monitor's feed."""

from __future__ import annotations

from typing import Any

import numpy as np

from subpix_ros.core.telemetry import TelemetrySample
from subpix_ros.process.products import ProductWriter


class _MonitorFeed:
    """Hands what the bag's pipeline produces to a live :class:`~subpix_ros.monitor.Monitor`.

    The monitor keeps only the newest item per image stream and sends within its link budget, so
    feeding it every frame costs a reference each; the mosaic canvas is drawn once every
    ``MOSAIC_EVERY`` frames.
    """

    MOSAIC_EVERY = 10

    def __init__(self, monitor: Any, mosaic: Any) -> None:
        self.monitor = monitor
        self.mosaic = mosaic

    def frame(self, frame: Any, n: int) -> None:
        self.monitor.on_camera(_to8(frame.image), int(frame.stamp_ns))  # JPEGs are 8-bit
        if n % self.MOSAIC_EVERY == 0:
            canvas = self.mosaic.canvas()
            if canvas is not None:
                self.monitor.on_mosaic(canvas, int(frame.stamp_ns))

    def shift(self, item: Any) -> None:
        s = item[0] if isinstance(item, tuple) else item
        self.monitor.on_shift(int(s.stamp_ns), s.u, s.v, s.u_std, s.v_std, True)

    def super_resolved(self, sr: Any) -> None:
        stamp = int(sr.reference.stamp_ns)
        why = (sr.reason or "fell back") if getattr(sr, "fell_back", False) else None
        self.monitor.on_super_resolved(_to8(sr.image), _to8(sr.bicubic), stamp, sr.factor, why)

    def diagnostics(self, statuses: dict[str, tuple[int, str, dict]]) -> None:
        """Hand the stages' statuses (``results.mcap``'s /diagnostics) to the health table."""
        self.monitor.on_diagnostics(
            {"name": name, "level": level, "message": message, "values": values}
            for name, (level, message, values) in statuses.items()
        )

    def telemetry(self, s: TelemetrySample) -> None:
        self.monitor.on_fix(s.lat_deg, s.lon_deg, s.alt_msl_m, int(round(s.t * 1e9)))


def _preview(frame: Any) -> Any:
    """Return the frame as the mosaic draws it: 8 bit (16-bit frames scaled by 255/65535)."""
    if frame.image.dtype == np.uint8:
        return frame
    from subpix_ros.stages import Frame

    return Frame(frame.stamp_ns, _to8(frame.image), frame.frame_id, frame.received)


def _to8(img: np.ndarray) -> np.ndarray:
    """Return an image as 8 bit (16-bit values scaled by 255/65535), unchanged if already 8 bit."""
    if img.dtype == np.uint8:
        return img
    return np.clip(np.rint(img.astype(np.float32) * (255.0 / 65535.0)), 0, 255).astype(np.uint8)


def _mosaic(stage: Any, w: ProductWriter, last_ns: int | None) -> dict:
    """mosaic.png and the frame footprints on it (canvas px)."""
    canvas = stage.canvas()
    if canvas is None or getattr(canvas, "size", 0) == 0:
        return {"written": False}
    if last_ns is not None:
        w.png("mosaic.png", canvas, "/mosaic/compressed", last_ns, "mosaic")
    else:
        w.png("mosaic.png", canvas)
    info: dict = {
        "written": True,
        "size": [int(canvas.shape[1]), int(canvas.shape[0])],
        "footprints": [],
    }
    core = getattr(stage, "mosaic", None)
    geos = getattr(core, "geometries", None)
    if core is not None and geos is not None:
        for i, g in enumerate(geos):
            if g is None:
                continue
            hh, ww = g.shape
            corners = np.array([[0, 0], [ww - 1, 0], [ww - 1, hh - 1], [0, hh - 1]], np.float64)
            try:
                info["footprints"].append(np.round(core.to_canvas(i, corners), 1).tolist())
            except Exception:  # noqa: BLE001
                continue
    return info
