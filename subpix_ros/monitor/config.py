"""Settings of the live monitor and the exposure rule checked before anything binds."""

from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

__all__ = ["LOOPBACK", "MonitorError", "MonitorConfig", "check_exposure"]

LOOPBACK = ("127.0.0.1", "localhost", "::1")


class MonitorError(RuntimeError):
    """The monitor cannot start as configured (one line, for the operator)."""


@dataclass
class MonitorConfig:
    """Settings of a :class:`Monitor` (the ``monitor_node`` parameters of the same names)."""

    host: str = "127.0.0.1"
    port: int = 8765
    tls_cert: str = ""
    tls_key: str = ""
    allow_insecure: bool = False
    bandwidth_kbps: float = 2000.0
    burst_s: float = 0.5
    backlog_messages: int = 64
    mosaic_max_px: int = 1024
    mosaic_period_s: float = 2.0
    sr_crop_px: int = 512
    camera_max_px: int = 640
    camera_period_s: float = 1.0
    geo_period_s: float = 2.0
    health_period_s: float = 1.0
    values_period_s: float = 5.0
    stale_after_s: float = 5.0
    max_footprints: int = 30
    track_tolerance_m: float = 2.0
    record_mcap: str = ""
    name: str = "subpix_ros monitor"

    @classmethod
    def from_mapping(cls, values: dict[str, Any]) -> "MonitorConfig":
        """Build a config from the keys of ``values`` that are its fields (others ignored)."""
        names = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in values.items() if k in names})


def check_exposure(cfg: MonitorConfig) -> tuple[bytes | None, bytes | None]:
    """Refuse an exposed server without TLS; return the PEM certificate and key (or None, None).

    Raises
    ------
    MonitorError
        ``host`` is not a loopback address and neither TLS nor ``allow_insecure`` is set;
        only one of ``tls_cert`` / ``tls_key`` is set; a file cannot be read.
    """
    if bool(cfg.tls_cert) != bool(cfg.tls_key):
        raise MonitorError("monitor: tls_cert and tls_key must be set together")
    if cfg.tls_cert:
        pem = []
        for what, path in (("tls_cert", cfg.tls_cert), ("tls_key", cfg.tls_key)):
            p = Path(path)
            if not p.is_file():
                raise MonitorError(f"monitor: {what} {path!r} is not a readable file")
            pem.append(p.read_bytes())
        return pem[0], pem[1]
    if cfg.host not in LOOPBACK and not cfg.allow_insecure:
        raise MonitorError(
            f"monitor: refusing to serve on {cfg.host!r} without TLS: set tls_cert and tls_key, "
            "or allow_insecure:=true on a trusted link, or keep host 127.0.0.1 and use an SSH "
            "tunnel"
        )
    return None, None
