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
``/footprints``           foxglove.GeoJSON                     track + footprints, geo_period_s (*)
``/health``               JSON subpix.Health                   every health_period_s (*)
``/health/values``        JSON subpix.HealthValues             every values_period_s (*)
``/log``                  foxglove.Log                         warnings and errors (never throttled)
========================  ===================================  ==========================

Link budget (priority order). The monitor counts the bytes each channel puts
on the wire (frame bytes x clients subscribed). Health, log, shifts, telemetry,
fixes and the map always go and are charged to a token bucket of
``bandwidth_kbps`` (at most ``burst_s`` seconds saved up). (*) On a small link the
periodic ones come less often instead: each takes at most its share of the budget
(:data:`~subpix_ros.monitor.schemas.ESSENTIAL_SHARES`: /health 10 %, /health/values
/footprints and /telemetry 5 %, its latest figures coalesced); the health
table's rows (each node's level, message, age) are in every /health message, the
nodes' other keys on /health/values, the track is thinned to ``track_tolerance_m``.
When the essentials alone still take more than the budget (measured over 10 s), the
monitor says so once in /log, :meth:`Monitor.budget_problem` returns the text and
``link.over_budget`` carries it. Images wait for the bucket in strict priority: the mosaic, then the
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

import math
import threading
import time
from pathlib import Path
from typing import Any, Iterable, Sequence

import foxglove
import numpy as np
from foxglove.channels import CompressedImageChannel, GeoJsonChannel, LocationFixChannel, LogChannel
from foxglove.messages import LocationFix, Log, LogLevel

from .budget import ByteMeter, TokenBucket
from .config import MonitorConfig, MonitorError, check_exposure
from .encoding import TELEMETRY_DIGITS, _num, _px, _sig, _to_bgr, _ts, _ts_json
from .schemas import (
    HEALTH_SCHEMA,
    HEALTH_VALUES_SCHEMA,
    LEVEL_NAMES,
    SHIFT_SCHEMA,
    TELEMETRY_SCHEMA,
    TOPICS,
)
from .sender import _Out, _Sender, _Stream

__all__ = ["Monitor"]


class Monitor(_Sender):
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
        self._stale_said: dict[str, float] = {}  # node -> when its last status arrived
        self._levels_seen: dict[str, int] = {}
        self._track: list[tuple[float, float]] = []
        self._footprints: list[list[tuple[float, float]]] = []
        self._geo_dirty = False
        self._health_checked = -1e9
        # topic -> monotonic time its next periodic message may go (sender.ESSENTIAL_SHARES)
        self._due: dict[str, float] = {}
        self._telemetry: dict[str, float | None] = {}
        self._telemetry_pending: dict | None = None
        self._essential_meter = ByteMeter(window_s=10.0)
        self._budget_problem: str | None = None  # said while the essentials exceed the budget
        self._budget_problem_rate = 0.0  # the budget (bytes/s) it was said for
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
        """Open the server (and the MCAP recording) and start the sender thread (once)."""
        if self.server is not None:
            return  # already serving (started by the constructor): binding again would fail
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
            "/health/values": js(HEALTH_VALUES_SCHEMA),
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
        """Port the server listens on (0 before start)."""
        return self.server.port if self.server is not None else 0

    @property
    def url(self) -> str:
        """The ``ws://`` or ``wss://`` URL of the server."""
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
        """Change the link budget (kbit/s); whether the essentials fit it is said again."""
        self.cfg.bandwidth_kbps = float(kbps)
        self.bucket.set_rate(kbps * 125.0)
        with self._lock:
            self._due.clear()  # the periodic essentials' waits follow the new budget

    # ---------------------------------------------------------- server listener (SDK threads)
    def on_subscribe(self, client, channel) -> None:
        """Note a client's subscription and resend the channel's latest message (SDK thread)."""
        with self._lock:
            self._subs.setdefault(channel.id, set()).add(client.id)
            self._resend.add(channel.id)
        self._wake.set()

    def on_unsubscribe(self, client, channel) -> None:
        """Note that a client left a channel (SDK thread)."""
        with self._lock:
            self._subs.get(channel.id, set()).discard(client.id)

    def _client_count(self) -> int:
        with self._lock:
            return len(set().union(*self._subs.values())) if self._subs else 0

    def clients(self, topic: str) -> int:
        """Return how many clients subscribe to ``topic``."""
        with self._lock:
            return len(self._subs.get(self.outs[topic].ws_id, ()))

    # ------------------------------------------------------------------ inputs
    def on_mosaic(self, bgr: np.ndarray, stamp_ns: int | None = None) -> None:
        """Keep the latest mosaic (H x W x 3 or H x W, uint8).

        Sent when it changed, every mosaic_period_s at most.
        """
        self._put("mosaic", (_to_bgr(bgr), stamp_ns if stamp_ns is not None else time.time_ns()))

    def on_super_resolved(
        self,
        sr_image: np.ndarray,
        bicubic_image: np.ndarray | None,
        stamp_ns: int,
        factor: int | None = None,
        fallback: str | None = None,
    ) -> None:
        """Keep a super-resolved image and the bicubic enlargement of its reference.

        The bicubic image has the same size, or is None. ``fallback``: why the image is not
        super-resolved (the reconstruction fell back to the bicubic upscale); it is then
        labelled as such, not as super-resolved.
        """
        sr = _to_bgr(sr_image)
        bic = None if bicubic_image is None else _to_bgr(bicubic_image)
        if bic is not None and bic.shape[:2] != sr.shape[:2]:
            raise ValueError(
                f"monitor: bicubic {bic.shape[:2]} and super-resolved {sr.shape[:2]} differ in size"
            )
        self._put("sr", (sr, bic, stamp_ns, factor, fallback))

    def on_camera(self, image: np.ndarray, stamp_ns: int) -> None:
        """Keep the current camera frame (the newest is sent every camera_period_s)."""
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
        """Send one shift estimate (never throttled).

        Parameters
        ----------
        stamp_ns : int
            The frame's stamp.
        u, v : float
            The shift, px (rows, columns).
        u_std, v_std : float, optional
            Its standard errors, px.
        converged : bool
            Whether the estimator converged.
        expected_u, expected_v : float, optional
            Telemetry's expectation, px; the message carries the difference too.

        Notes
        -----
        Shifts and differences are sent to :data:`~.encoding.SHIFT_DECIMALS` decimals (px),
        the standard errors to :data:`~.encoding.STD_DIGITS` significant digits: the link
        carries what the estimator can tell, not float64's digits. A non-finite value is null.
        """
        eu, ev = _num(expected_u), _num(expected_v)
        msg = {
            "timestamp": _ts_json(stamp_ns),
            "header": _header(stamp_ns),
            "u": _px(u),
            "v": _px(v),
            "u_std": _sig(u_std),
            "v_std": _sig(v_std),
            "converged": bool(converged),
            "expected_u": _px(eu),
            "expected_v": _px(ev),
            "du": None if eu is None else _px(float(u) - eu),
            "dv": None if ev is None else _px(float(v) - ev),
        }
        self._essential("/shift", msg)

    def on_telemetry(self, stamp_ns: int, **values: float | None) -> None:
        """Send telemetry figures; the latest of each is repeated in every message.

        Keys: ``frame_interval_s``, ``expected_u``, ``expected_v``, ``height_m``, ``speed_mps``.
        Sent at once, unless /telemetry would take more than its share of a small budget
        (``ESSENTIAL_SHARES``): then the latest figures go when it is due (coalesced). Each
        figure is sent to :data:`~.encoding.TELEMETRY_DIGITS` significant digits.
        """
        with self._lock:
            self._telemetry.update({k: _sig(v, TELEMETRY_DIGITS) for k, v in values.items()})
            self._telemetry_pending = {
                "timestamp": _ts_json(stamp_ns),
                "header": _header(stamp_ns),
                **self._telemetry,
            }
        self._send_telemetry(time.monotonic())
        with self._lock:
            waiting = self._telemetry_pending is not None
        if waiting:
            self._wake.set()

    def on_fix(self, lat: float, lon: float, alt: float, stamp_ns: int) -> None:
        """Send a GNSS fix (degrees, m) as LocationFix and add it to the track."""
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
        """Add a frame's ground footprint: a closed (lon, lat) ring (:func:`geo.footprint_lonlat`)."""
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

        A row per ``name`` (the nodes' status names are their fully qualified names without
        the leading slash, ``drone1/registration_node``: the same node in two namespaces is
        two rows); a row whose ``pid`` value changes is said to have restarted.

        A node whose level rises to WARN or ERROR, or whose problem message changes, also
        gives a Log entry.
        """
        now = time.monotonic()
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
                    "received": now,
                }
                was_stale = self._stale_said.pop(name, None)
            if was_stale is not None:
                self.on_log(0, f"reporting again after {now - was_stale:.0f} s", name=name)
            old_pid = (prev or {}).get("values", {}).get("pid")
            new_pid = st.get("values", {}).get("pid")
            if old_pid and new_pid and old_pid != new_pid:  # a new process under the same name
                self.on_log(1, f"restarted (process {old_pid} -> {new_pid})", name=name)
            if level > 0 and (prev is None or prev["level"] < level or prev["message"] != msg):
                self.on_log(level, msg, name=name)

    def stale_nodes(self, now: float | None = None) -> dict[str, float]:
        """Return ``{node: seconds since its last status}`` for the nodes silent beyond ``stale_after_s``.

        A node that stopped (killed, crashed, its host gone) sends no /diagnostics, and its last
        status would otherwise stay on the operator's health table as it was, often ``OK``.
        """
        now = time.monotonic() if now is None else now
        limit = float(self.cfg.stale_after_s)
        with self._lock:
            ages = {n: now - st["received"] for n, st in self._health.items()}
        return {n: age for n, age in ages.items() if age > limit}

    def _say_stale(self, now: float) -> None:
        """Log once when a node's status goes stale (the health table marks it STALE meanwhile)."""
        for name, age in self.stale_nodes(now).items():
            with self._lock:
                if name in self._stale_said:
                    continue
                self._stale_said[name] = now - age
                last = self._health[name]
            self.on_log(
                3,
                f"no status for {age:.0f} s: the node stopped or its /diagnostics no longer "
                f"arrive (its last: {LEVEL_NAMES.get(last['level'], last['level'])} "
                f"{last['message']})",
                name=name,
            )

    def on_log(
        self, level: int | str, text: str, name: str = "subpix_ros", stamp_ns: int | None = None
    ) -> None:
        """Send a log entry (level 0-3 as diagnostics, or debug/info/warning/error/fatal)."""
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


def _header(stamp_ns: int) -> dict:
    """Return a JSON ``header`` with ``stamp`` (Foxglove plots order by ``header.stamp``)."""
    return {"stamp": _ts_json(stamp_ns), "frame_id": ""}
