"""The live operator monitor: one Foxglove WebSocket server, bandwidth-bounded, secure by default.

:class:`Monitor` owns the server (``foxglove-sdk``), its channels, the link
budget and the optional MCAP recording. It is fed by plain method calls
(``on_mosaic``, ``on_super_resolved``, ``on_camera``, ``on_shift``, ``on_fix``,
``on_footprint``, ``on_telemetry``, ``on_diagnostics``, ``on_log``), so a ROS
node, the single-process pipeline or a command-line tool can drive it. No ROS
import here.

Channels (``TOPICS``):

========================  ===================================  ==========================
topic                     schema                               sent
========================  ===================================  ==========================
``/mosaic``               foxglove.CompressedImage (JPEG)      changed, >= mosaic_period_s apart
``/super_resolved``       foxglove.CompressedImage (crop)      each new image, labelled
``/bicubic``              foxglove.CompressedImage (crop)      with it: same crop, bicubic
``/camera``               foxglove.CompressedImage             every camera_period_s
``/shift``                JSON subpix.Shift                    every shift (never throttled)
``/telemetry``            JSON subpix.Telemetry                every sample (never throttled)
``/fix``                  foxglove.LocationFix                 every fix (never throttled)
``/footprints``           foxglove.GeoJSON                     track + footprints, geo_period_s
``/health``               JSON subpix.Health                   every health_period_s (always)
``/log``                  foxglove.Log                         warnings and errors (never throttled)
========================  ===================================  ==========================

Link budget (priority order). The monitor counts the bytes each channel puts
on the wire (frame bytes x clients subscribed). Health, log, shifts, telemetry,
fixes and the footprints (at most every ``geo_period_s``) always go and are
charged to a token bucket of ``bandwidth_kbps`` (at most ``burst_s`` seconds
saved up). Images wait for the bucket in strict priority: the mosaic, then the
super-resolved / bicubic pair, then the camera frame; a lower one goes only when no higher one
waits, or when it has waited four of its periods (at least 4 s). Each image
stream is sized to its share of what the essentials leave (mosaic 0.45,
super-resolved pair 0.30, camera 0.25 of it, shared among the streams fed;
:meth:`Monitor.target_bytes`): an image over its target steps down the rungs
of :data:`~subpix_ros.monitor.budget.LEVELS` (JPEG quality first, then size)
until it fits, one under half of it steps back up. Below the last rung the
bucket stretches the period: rates drop. So images degrade and the essentials
never starve, and a stalled link sends the newest image when it can, never a
queue of old ones.

Slow clients: the server keeps at most ``backlog_messages`` outgoing messages
per client and drops the oldest data message beyond that (foxglove-sdk's
``message_backlog_size``, set explicitly). A client that subscribes to an
image channel gets its latest image at once.

Security: ``host`` 127.0.0.1 by default; any other address needs ``tls_cert``
and ``tls_key`` (wss://) or ``allow_insecure``, else :class:`MonitorError`
at start. No client-publish, parameter or service capability is offered.
"""

from __future__ import annotations

import json
import math
import threading
import time
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Iterable, Sequence

import cv2
import foxglove
import numpy as np
from foxglove.channels import CompressedImageChannel, GeoJsonChannel, LocationFixChannel, LogChannel
from foxglove.messages import CompressedImage, GeoJson, LocationFix, Log, LogLevel, Timestamp

from .budget import LEVELS, ByteMeter, TokenBucket, wire_bytes
from .geo import feature_collection

__all__ = ["Monitor", "MonitorConfig", "MonitorError", "TOPICS", "LOOPBACK", "check_exposure"]

LOOPBACK = ("127.0.0.1", "localhost", "::1")

SHIFT_SCHEMA = {
    "title": "subpix.Shift",
    "type": "object",
    "properties": {
        "timestamp": {
            "type": "object",
            "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}},
        },
        "u": {
            "type": "number",
            "description": "shift along rows, px (content moved from reference to frame)",
        },
        "v": {"type": "number", "description": "shift along columns, px"},
        "u_std": {"type": ["number", "null"]},
        "v_std": {"type": ["number", "null"]},
        "converged": {"type": "boolean"},
        "expected_u": {
            "type": ["number", "null"],
            "description": "telemetry's expected shift, px (eq. 1)",
        },
        "expected_v": {"type": ["number", "null"]},
        "du": {"type": ["number", "null"], "description": "u - expected_u"},
        "dv": {"type": ["number", "null"], "description": "v - expected_v"},
    },
}
TELEMETRY_SCHEMA = {
    "title": "subpix.Telemetry",
    "type": "object",
    "properties": {
        "timestamp": {
            "type": "object",
            "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}},
        },
        "frame_interval_s": {"type": ["number", "null"], "description": "METHODS eq. 1"},
        "expected_u": {"type": ["number", "null"]},
        "expected_v": {"type": ["number", "null"]},
        "height_m": {"type": ["number", "null"]},
        "speed_mps": {"type": ["number", "null"]},
    },
}
HEALTH_SCHEMA = {
    "title": "subpix.Health",
    "type": "object",
    "properties": {
        "timestamp": {
            "type": "object",
            "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}},
        },
        "nodes": {
            "type": "array",
            "items": {
                "type": "object",
                "properties": {
                    "name": {"type": "string"},
                    "level": {"type": "string"},
                    "message": {"type": "string"},
                    "input_hz": {"type": "string"},
                    "output_hz": {"type": "string"},
                    "dropped": {"type": "string"},
                    "latency_p50_ms": {"type": "string"},
                    "queue_depth": {"type": "string"},
                    "last_error": {"type": "string"},
                },
            },
        },
        "link": {
            "type": "object",
            "description": "the monitor's own link budget and bytes/s per channel",
        },
        "values": {
            "type": "object",
            "description": "every key/value of every node, '<node>/<key>'",
        },
    },
}

TOPICS: dict[str, str] = {
    "/mosaic": "foxglove.CompressedImage",
    "/super_resolved": "foxglove.CompressedImage",
    "/bicubic": "foxglove.CompressedImage",
    "/camera": "foxglove.CompressedImage",
    "/shift": "subpix.Shift",
    "/telemetry": "subpix.Telemetry",
    "/fix": "foxglove.LocationFix",
    "/footprints": "foxglove.GeoJSON",
    "/health": "subpix.Health",
    "/log": "foxglove.Log",
}
ESSENTIAL_TOPICS = ("/shift", "/telemetry", "/fix", "/footprints", "/health", "/log")
LEVEL_NAMES = {0: "OK", 1: "WARN", 2: "ERROR", 3: "STALE"}


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
    max_footprints: int = 30
    record_mcap: str = ""
    name: str = "subpix_ros monitor"

    @classmethod
    def from_mapping(cls, values: dict[str, Any]) -> "MonitorConfig":
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


def _ts(stamp_ns: int) -> Timestamp:
    return Timestamp(sec=int(stamp_ns // 1_000_000_000), nsec=int(stamp_ns % 1_000_000_000))


def _ts_json(stamp_ns: int) -> dict:
    return {"sec": int(stamp_ns // 1_000_000_000), "nsec": int(stamp_ns % 1_000_000_000)}


def _num(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(float(x)) else float(x)


def _to_bgr(image: np.ndarray) -> np.ndarray:
    if image.ndim == 2 or (image.ndim == 3 and image.shape[2] == 1):
        return image.reshape(image.shape[:2])
    if image.ndim == 3 and image.shape[2] in (3, 4):
        return image[:, :, :3]
    raise ValueError(f"monitor: image of shape {image.shape} is neither mono nor colour")


def _to_u8(image: np.ndarray) -> np.ndarray:
    if image.dtype == np.uint8:
        return image
    if image.dtype == np.uint16:
        return (image >> 8).astype(np.uint8)
    return np.clip(image, 0, 255).astype(np.uint8)


def _shrink(image: np.ndarray, max_px: int) -> np.ndarray:
    h, w = image.shape[:2]
    s = max_px / max(h, w)
    if s >= 1.0:
        return image
    return cv2.resize(
        image, (max(1, round(w * s)), max(1, round(h * s))), interpolation=cv2.INTER_AREA
    )


def _label(image: np.ndarray, text: str) -> np.ndarray:
    out = (
        cv2.cvtColor(image, cv2.COLOR_GRAY2BGR) if image.ndim == 2 else np.ascontiguousarray(image)
    )
    scale = max(0.4, out.shape[1] / 900)
    th = max(1, round(scale * 2))
    (tw, tht), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, th)
    cv2.rectangle(out, (0, 0), (tw + 8, tht + base + 8), (0, 0, 0), -1)
    cv2.putText(
        out, text, (4, tht + 4), cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), th, cv2.LINE_AA
    )
    return out


class _Out:
    """One served topic: its channel on the server's context and, when recording, on the MCAP's."""

    def __init__(self, topic: str, make, contexts: Sequence[foxglove.Context]) -> None:
        self.topic = topic
        self.channels = [make(topic, c) for c in contexts]
        self.meter = ByteMeter()
        self.last: Any = None  # the latest message, for a client that subscribes later

    @property
    def ws_id(self) -> int:
        return self.channels[0].id()


@dataclass
class _Stream:
    """An image stream waiting for the link: latest input, encoded message pending, its rung."""

    topics: tuple[str, ...]
    priority: int
    period_attr: str
    seq: int = 0  # bumped by each new input
    item: Any = None
    pending: list | None = None  # [(topic, message, wire bytes per client)]
    pending_seq: int = -1
    pending_t: float = 0.0
    sent_seq: int = 0
    last_sent: float = -1e9
    weight: float = 1.0  # share of the image budget
    last_input: float = -1e9
    level: int = 0
    sent: int = 0


class Monitor:
    """Serve the flight to Foxglove over one WebSocket server (see the module docstring).

    Parameters
    ----------
    config : MonitorConfig
        Settings; the exposure rules are checked before anything binds.
    start : bool
        Start the server and the sender thread now (else call :meth:`start`).

    Notes
    -----
    The ``on_*`` methods are cheap and thread-safe: images are only kept (the
    caller must not write into an array it handed over), encoding happens on the
    monitor's sender thread at the rate the link allows.
    """

    def __init__(self, config: MonitorConfig | None = None, *, start: bool = True) -> None:
        self.cfg = config or MonitorConfig()
        self._tls = check_exposure(self.cfg)
        self._lock = threading.RLock()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self.bucket = TokenBucket(self.cfg.bandwidth_kbps * 125.0, self.cfg.burst_s)
        self.server = None
        self.mcap = None
        self._subs: dict[int, set[int]] = {}  # ws channel id -> client ids subscribed
        self._resend: set[int] = set()
        self._health: dict[str, dict] = {}
        self._levels_seen: dict[str, int] = {}
        self._track: list[tuple[float, float]] = []
        self._footprints: list[list[tuple[float, float]]] = []
        self._geo_dirty = False
        self._geo_sent = -1e9
        self._health_sent = -1e9
        self._telemetry: dict[str, float | None] = {}
        self.errors: list[str] = []
        self.streams = {
            "mosaic": _Stream(("/mosaic",), 1, "mosaic_period_s", weight=0.45),
            "sr": _Stream(("/super_resolved", "/bicubic"), 2, "sr_period_s", weight=0.30),
            "camera": _Stream(("/camera",), 3, "camera_period_s", weight=0.25),
        }
        self._thread: threading.Thread | None = None
        self.outs: dict[str, _Out] = {}
        if start:
            self.start()

    # ------------------------------------------------------------------ life cycle
    def start(self) -> None:
        cfg = self.cfg
        self._ws_ctx = foxglove.Context()
        contexts = [self._ws_ctx]
        if cfg.record_mcap:
            path = Path(cfg.record_mcap)
            if not path.parent.is_dir():
                raise MonitorError(
                    f"monitor: record_mcap directory {str(path.parent)!r} does not exist"
                )
            self._mcap_ctx = foxglove.Context()
            self.mcap = foxglove.open_mcap(str(path), allow_overwrite=True, context=self._mcap_ctx)
            contexts.append(self._mcap_ctx)

        def js(schema):
            return lambda topic, ctx: foxglove.Channel(
                topic, schema=schema, message_encoding="json", context=ctx
            )

        def typed(cls):
            # the SDK's typed channel gives the schema (foxglove.<Type>, protobuf); messages are
            # encoded once (``msg.encode()``) and the same bytes go to every context and are
            # counted
            schema = cls("/schema_of_" + cls.__name__, context=foxglove.Context()).schema()
            return lambda topic, ctx: foxglove.Channel(
                topic, schema=schema, message_encoding="protobuf", context=ctx
            )

        makers = {
            "/mosaic": typed(CompressedImageChannel),
            "/super_resolved": typed(CompressedImageChannel),
            "/bicubic": typed(CompressedImageChannel),
            "/camera": typed(CompressedImageChannel),
            "/shift": js(SHIFT_SCHEMA),
            "/telemetry": js(TELEMETRY_SCHEMA),
            "/fix": typed(LocationFixChannel),
            "/footprints": typed(GeoJsonChannel),
            "/health": js(HEALTH_SCHEMA),
            "/log": typed(LogChannel),
        }
        self.outs = {t: _Out(t, makers[t], contexts) for t in TOPICS}
        self._by_ws_id = {o.ws_id: o for o in self.outs.values()}
        cert, key = self._tls
        try:
            self.server = foxglove.start_server(
                name=cfg.name,
                host=cfg.host,
                port=cfg.port,
                capabilities=[],
                context=self._ws_ctx,
                server_listener=self,
                message_backlog_size=int(cfg.backlog_messages),
                tls_cert=cert,
                tls_key=key,
            )
        except Exception as exc:  # noqa: BLE001 - one line for the operator, whatever the SDK raised
            if self.mcap is not None:
                self.mcap.close()
            raise MonitorError(f"monitor: cannot serve on {cfg.host}:{cfg.port}: {exc}") from exc
        self._thread = threading.Thread(target=self._run, name="monitor_sender", daemon=True)
        self._thread.start()

    @property
    def port(self) -> int:
        return self.server.port if self.server is not None else 0

    @property
    def url(self) -> str:
        scheme = "wss" if self._tls[0] else "ws"
        return f"{scheme}://{self.cfg.host}:{self.port}"

    def close(self) -> None:
        """Stop the sender thread and the server; finish the MCAP file."""
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(5.0)
        if self.server is not None:
            self.server.stop()
            self.server = None
        if self.mcap is not None:
            self.mcap.close()
            self.mcap = None

    def __enter__(self) -> "Monitor":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def set_bandwidth_kbps(self, kbps: float) -> None:
        self.cfg.bandwidth_kbps = float(kbps)
        self.bucket.set_rate(kbps * 125.0)

    # ---------------------------------------------------------- server listener (SDK threads)
    def on_subscribe(self, client, channel) -> None:
        with self._lock:
            self._subs.setdefault(channel.id, set()).add(client.id)
            self._resend.add(channel.id)
        self._wake.set()

    def on_unsubscribe(self, client, channel) -> None:
        with self._lock:
            self._subs.get(channel.id, set()).discard(client.id)

    def _client_count(self) -> int:
        with self._lock:
            return len(set().union(*self._subs.values())) if self._subs else 0

    def clients(self, topic: str) -> int:
        with self._lock:
            return len(self._subs.get(self.outs[topic].ws_id, ()))

    # ------------------------------------------------------------------ sending
    def _log(self, topic: str, msg: Any, *, charge: bool = True, recorded: bool = True) -> int:
        """Log ``msg`` on ``topic``; count and charge its wire bytes; return them."""
        out = self.outs[topic]
        payload = json.dumps(msg, separators=(",", ":")).encode() if isinstance(msg, dict) else msg
        n = wire_bytes(
            len(payload if isinstance(payload, bytes) else payload.encode())
        ) * self.clients(topic)
        chans = out.channels if recorded else out.channels[:1]
        for ch in chans:
            ch.log(payload)
        out.last = payload
        if n:
            out.meter.add(n)
            if charge:
                self.bucket.charge(n)
        return n

    def _essential(self, topic: str, msg: Any) -> None:
        """Health, log, shifts, telemetry, fixes: never throttled (charged to the bucket)."""
        try:
            self._log(topic, msg)
        except Exception as exc:  # noqa: BLE001 - a monitor must not take its feeder down
            self._note_error(f"{topic}: {type(exc).__name__}: {exc}")

    def _note_error(self, text: str) -> None:
        with self._lock:
            self.errors.append(text)
            del self.errors[:-20]

    # ------------------------------------------------------------------ inputs
    def on_mosaic(self, bgr: np.ndarray, stamp_ns: int | None = None) -> None:
        """The latest mosaic (H x W x 3 or H x W, uint8); sent when changed, every
        mosaic_period_s at most."""
        self._put("mosaic", (_to_bgr(bgr), stamp_ns if stamp_ns is not None else time.time_ns()))

    def on_super_resolved(
        self,
        sr_image: np.ndarray,
        bicubic_image: np.ndarray | None,
        stamp_ns: int,
        factor: int | None = None,
    ) -> None:
        """A super-resolved image and the bicubic enlargement of its reference (same size) or
        None."""
        sr = _to_bgr(sr_image)
        bic = None if bicubic_image is None else _to_bgr(bicubic_image)
        if bic is not None and bic.shape[:2] != sr.shape[:2]:
            raise ValueError(
                f"monitor: bicubic {bic.shape[:2]} and super-resolved {sr.shape[:2]} differ in size"
            )
        self._put("sr", (sr, bic, stamp_ns, factor))

    def on_camera(self, image: np.ndarray, stamp_ns: int) -> None:
        """The current camera frame (kept; the newest is sent every camera_period_s)."""
        self._put("camera", (_to_bgr(image), stamp_ns))

    def _put(self, name: str, item: Any) -> None:
        s = self.streams[name]
        with self._lock:
            s.item = item
            s.seq += 1
            s.last_input = time.monotonic()
        self._wake.set()

    def on_shift(
        self,
        stamp_ns: int,
        u: float,
        v: float,
        u_std: float | None = None,
        v_std: float | None = None,
        converged: bool = True,
        expected_u: float | None = None,
        expected_v: float | None = None,
    ) -> None:
        """One shift estimate (px, rows/columns), its standard errors, telemetry's expectation."""
        eu, ev = _num(expected_u), _num(expected_v)
        msg = {
            "timestamp": _ts_json(stamp_ns),
            "u": float(u),
            "v": float(v),
            "u_std": _num(u_std),
            "v_std": _num(v_std),
            "converged": bool(converged),
            "expected_u": eu,
            "expected_v": ev,
            "du": None if eu is None else float(u) - eu,
            "dv": None if ev is None else float(v) - ev,
        }
        self._essential("/shift", msg)

    def on_telemetry(self, stamp_ns: int, **values: float | None) -> None:
        """Telemetry figures (``frame_interval_s``, ``expected_u``, ``expected_v``, ``height_m``,
        ``speed_mps``); the latest of each is repeated in every message."""
        with self._lock:
            self._telemetry.update({k: _num(v) for k, v in values.items()})
            msg = {"timestamp": _ts_json(stamp_ns), **self._telemetry}
        self._essential("/telemetry", msg)

    def on_fix(self, lat: float, lon: float, alt: float, stamp_ns: int) -> None:
        """A GNSS fix (degrees, m): served as LocationFix, and added to the track."""
        if not (
            math.isfinite(lat) and math.isfinite(lon) and -90 <= lat <= 90 and -180 <= lon <= 180
        ):
            self.on_log(1, f"fix ignored: latitude {lat}, longitude {lon}")
            return
        msg = LocationFix(
            timestamp=_ts(stamp_ns),
            frame_id="gnss",
            latitude=float(lat),
            longitude=float(lon),
            altitude=float(alt) if math.isfinite(alt) else 0.0,
        )
        self._essential("/fix", msg.encode())
        with self._lock:
            if not self._track or self._track[-1] != (lon, lat):
                self._track.append((float(lon), float(lat)))
                del self._track[:-20000]
                self._geo_dirty = True

    def on_footprint(
        self, corners_lonlat: Sequence[tuple[float, float]], stamp_ns: int | None = None
    ) -> None:
        """A frame's ground footprint, closed (lon, lat) ring (see :func:`geo.footprint_lonlat`)."""
        ring = [(float(x), float(y)) for x, y in corners_lonlat]
        if len(ring) < 4 or not all(math.isfinite(x) and math.isfinite(y) for x, y in ring):
            raise ValueError("monitor: a footprint needs a closed ring of finite (lon, lat)")
        with self._lock:
            self._footprints.append(ring)
            del self._footprints[: -max(1, self.cfg.max_footprints)]
            self._geo_dirty = True
        self._wake.set()

    def on_diagnostics(self, statuses: Iterable[dict]) -> None:
        """Pipeline health: dicts ``{name, level (0-3), message, values: {key: str}}``.

        A node whose level rises to WARN or ERROR, or whose problem message changes, also
        gives a Log entry.
        """
        for st in statuses:
            name = str(st.get("name", "?"))
            level = int(st.get("level", 0))
            msg = str(st.get("message", ""))
            with self._lock:
                prev = self._health.get(name)
                self._health[name] = {
                    "level": level,
                    "message": msg,
                    "values": dict(st.get("values", {})),
                }
            if level > 0 and (prev is None or prev["level"] < level or prev["message"] != msg):
                self.on_log(level, msg, name=name)

    def on_log(
        self, level: int | str, text: str, name: str = "subpix_ros", stamp_ns: int | None = None
    ) -> None:
        """A log entry (level 0-3 as diagnostics, or debug/info/warning/error/fatal)."""
        lv = {
            "debug": LogLevel.Debug,
            "info": LogLevel.Info,
            "warning": LogLevel.Warning,
            "warn": LogLevel.Warning,
            "error": LogLevel.Error,
            "fatal": LogLevel.Fatal,
            0: LogLevel.Info,
            1: LogLevel.Warning,
            2: LogLevel.Error,
            3: LogLevel.Warning,
        }.get(level.lower() if isinstance(level, str) else int(level), LogLevel.Unknown)
        msg = Log(
            timestamp=_ts(time.time_ns() if stamp_ns is None else stamp_ns),
            level=lv,
            message=str(text),
            name=name,
        )
        self._essential("/log", msg.encode())

    # ------------------------------------------------------------------ sender thread
    def _run(self) -> None:
        while not self._stop.is_set():
            self._wake.wait(0.02)
            self._wake.clear()
            try:
                self._tick(time.monotonic())
            except Exception as exc:  # noqa: BLE001 - keep serving
                self._note_error(f"sender: {type(exc).__name__}: {exc}")

    def _tick(self, now: float) -> None:
        with self._lock:
            resend, self._resend = self._resend, set()
        for cid in resend:  # a client that subscribes later gets the latest message at once
            out = self._by_ws_id.get(cid)
            if out is not None and out.last is not None and out.topic not in ("/shift", "/log"):
                self._log(out.topic, out.last, recorded=False)
        if now - self._health_sent >= self.cfg.health_period_s:
            self._health_sent = now
            self._essential("/health", self.health_message())
        for s in self.streams.values():  # encode the newest input of each stream that is due
            with self._lock:
                item, seq = s.item, s.seq
            due = now - s.last_sent >= getattr(self.cfg, s.period_attr, 0.0)
            stale = s.pending is not None and seq != s.pending_seq and now - s.pending_t > 0.5
            if item is not None and seq != s.sent_seq and due and (s.pending is None or stale):
                if s.pending is None:  # waiting for the link since (kept when replaced by a newer)
                    s.pending_t = now
                s.pending = self._encode_to_fit(s, item, now)
                s.pending_seq = seq
        # the track and footprints: small, rate-limited by geo_period_s, charged like the essentials
        if self._geo_dirty and now - self._geo_sent >= self.cfg.geo_period_s:
            with self._lock:
                text = feature_collection(self._track, self._footprints)
                self._geo_dirty = False
            self._geo_sent = now
            self._essential("/footprints", GeoJson(geojson=text).encode())

        def order(x: _Stream) -> tuple[int, int]:
            # strict priority, except that a stream kept waiting 4 periods (>= 4 s) goes first:
            # the camera is starved of rate and quality first, but not for ever
            period = getattr(self.cfg, x.period_attr, 0.0)
            starved = x.pending is not None and now - x.pending_t > max(4.0, 4 * period)
            return (0 if starved else 1, x.priority)

        for s in sorted(self.streams.values(), key=order):
            if s.pending is None:
                continue
            n = sum(wire_bytes(len(m)) for _, m in s.pending) * max(
                1, max(self.clients(t) for t in s.topics)
            )
            if not self.bucket.allows(n, now):
                break  # strict priority: nothing lower goes while this waits
            for topic, m in s.pending:
                self._log(topic, m)
            s.pending, s.sent_seq, s.last_sent, s.sent = None, s.pending_seq, now, s.sent + 1

    def target_bytes(self, s: _Stream, now: float) -> float:
        """Bytes one message of stream ``s`` should take: its share of what the essentials leave.

        ``share = max(0.1 B, B - essentials) * w_s / sum(w of streams fed in the last 10 s)``,
        ``B`` the budget (bytes/s), ``essentials`` the measured bytes/s of health, log, shifts,
        telemetry, fixes and footprints; one message is sized for ``max(period, 1 s)`` of its
        share (divided among the clients subscribed): below that, images come less often
        instead of smaller, and the token bucket sets their rate.
        """
        essential = sum(self.outs[t].meter.rate(now) for t in ESSENTIAL_TOPICS)
        avail = max(0.1 * self.bucket.rate, self.bucket.rate - essential)
        active = [
            x for x in self.streams.values() if x.item is not None and now - x.last_input < 10.0
        ]
        w = s.weight / max(1e-9, sum(x.weight for x in active) if s in active else s.weight)
        clients = max(1, max(self.clients(t) for t in s.topics))
        return avail * w * max(getattr(self.cfg, s.period_attr, 0.0), 1.0) / clients

    def _encode_to_fit(self, s: _Stream, item, now: float) -> list:
        """Encode at the stream's rung; step down the ladder while the message is 25 % over its
        target, and one rung up for next time when it is under half of it."""
        target = self.target_bytes(s, now)
        msgs = self._encode(s, item)
        size = sum(len(m) for _, m in msgs)
        while size > 1.25 * target and s.level < len(LEVELS) - 1:
            s.level += 1
            msgs = self._encode(s, item)
            size = sum(len(m) for _, m in msgs)
        if size < 0.5 * target and s.level > 0:
            s.level -= 1
        return msgs

    def _encode(self, s: _Stream, item) -> list:
        lv = LEVELS[s.level]
        if s.topics == ("/mosaic",):
            img, stamp = item
            return [
                (
                    "/mosaic",
                    self._jpeg(
                        _shrink(_to_u8(img), int(self.cfg.mosaic_max_px * lv.scale)),
                        lv.quality,
                        stamp,
                        "mosaic",
                    ),
                )
            ]
        if s.topics == ("/camera",):
            img, stamp = item
            return [
                (
                    "/camera",
                    self._jpeg(
                        _shrink(_to_u8(img), int(self.cfg.camera_max_px * lv.scale)),
                        lv.quality,
                        stamp,
                        "camera",
                    ),
                )
            ]
        sr, bic, stamp, factor = item
        crop = max(32, int(self.cfg.sr_crop_px))
        h, w = sr.shape[:2]
        r0, c0 = max(0, (h - crop) // 2), max(0, (w - crop) // 2)
        win = (slice(r0, r0 + crop), slice(c0, c0 + crop))
        f = f" x{factor}" if factor else ""
        where = f" rows {r0}-{min(h, r0 + crop)} cols {c0}-{min(w, c0 + crop)}"
        side = int(crop * lv.scale)
        out = [
            (
                "/super_resolved",
                self._jpeg(
                    _label(_shrink(_to_u8(sr[win]), side), "super-resolved" + f + where),
                    lv.quality,
                    stamp,
                    "super_resolved",
                ),
            )
        ]
        if bic is not None:
            out.append(
                (
                    "/bicubic",
                    self._jpeg(
                        _label(_shrink(_to_u8(bic[win]), side), "bicubic" + f + where),
                        lv.quality,
                        stamp,
                        "super_resolved",
                    ),
                )
            )
        return out

    @staticmethod
    def _jpeg(img: np.ndarray, quality: int, stamp_ns: int, frame_id: str) -> bytes:
        ok, buf = cv2.imencode(
            ".jpg", np.ascontiguousarray(img), [cv2.IMWRITE_JPEG_QUALITY, int(quality)]
        )
        if not ok:
            raise ValueError("JPEG encoding failed")
        return CompressedImage(
            timestamp=_ts(stamp_ns), frame_id=frame_id, data=buf.tobytes(), format="jpeg"
        ).encode()

    # ------------------------------------------------------------------ health
    def link_stats(self) -> dict:
        """The budget (kbit/s), bytes/s per channel, total, and each image stream's rung."""
        per = {t: round(o.meter.rate(), 1) for t, o in self.outs.items()}
        return {
            "budget_kbps": self.cfg.bandwidth_kbps,
            "sent_kbps": round(sum(per.values()) * 8 / 1000, 1),
            "bytes_per_s": per,
            "levels": {
                n: {
                    "quality": LEVELS[s.level].quality,
                    "scale": LEVELS[s.level].scale,
                    "sent": s.sent,
                }
                for n, s in self.streams.items()
            },
            "clients": self._client_count(),
            "errors": list(self.errors[-3:]),
        }

    def health_message(self) -> dict:
        keys = {
            "input_hz": "input_hz",
            "output_hz": "output_hz",
            "dropped": "dropped_frames",
            "latency_p50_ms": "latency_p50_ms",
            "queue_depth": "queue_depth",
            "last_error": "last_error",
        }
        with self._lock:
            nodes, values = [], {}
            for name, st in sorted(self._health.items()):
                v = st["values"]
                nodes.append(
                    {
                        "name": name,
                        "level": LEVEL_NAMES.get(st["level"], str(st["level"])),
                        "message": st["message"],
                        **{k: str(v.get(src, "")) for k, src in keys.items()},
                    }
                )
                values.update({f"{name}/{k}": str(x) for k, x in v.items()})
        return {
            "timestamp": _ts_json(time.time_ns()),
            "nodes": nodes,
            "link": self.link_stats(),
            "values": values,
        }
