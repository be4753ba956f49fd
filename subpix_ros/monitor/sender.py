"""The monitor's sender: the link budget, image encoding to fit it, health messages.

:class:`_Sender` is the half of :class:`~subpix_ros.monitor.Monitor` that runs on its sender
thread; the attributes it reads (``cfg``, ``outs``, ``streams``, ``bucket``, the locks and
queues) are set by :meth:`Monitor.__init__` and :meth:`Monitor.start`.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from typing import Any, Sequence

import foxglove
from foxglove.messages import GeoJson

from .budget import LEVELS, ByteMeter, wire_bytes
from .encoding import _jpeg, _label, _shrink, _to_u8, _ts_json, sr_label
from .geo import feature_collection
from .schemas import ESSENTIAL_SHARES, ESSENTIAL_TOPICS, LEVEL_NAMES


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


class _Sender:
    """Sending within the link budget (mixed into :class:`~subpix_ros.monitor.Monitor`)."""

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
            if topic in ESSENTIAL_TOPICS:
                self._essential_meter.add(n)
            if charge:
                self.bucket.charge(n)
        return n

    def _essential(self, topic: str, msg: Any) -> int:
        """Health, log, shifts, telemetry, fixes: never throttled (charged to the bucket).

        Returns the bytes put on the wire (0 when it failed).
        """
        try:
            return self._log(topic, msg)
        except Exception as exc:  # noqa: BLE001 - a monitor must not take its feeder down
            self._note_error(f"{topic}: {type(exc).__name__}: {exc}")
            return 0

    def _next_due(self, topic: str, period_s: float, n: int, now: float) -> float:
        """When the next message of a periodic essential may go, after one of ``n`` wire bytes.

        ``period_s`` apart, or further so that the channel takes at most its share of the
        budget (:data:`~subpix_ros.monitor.schemas.ESSENTIAL_SHARES`). The health table still
        goes every ``stale_after_s`` at least: the nodes' levels and stale state are what the
        operator must see, whatever the link.
        """
        share = ESSENTIAL_SHARES[topic] * self.bucket.rate
        wait = max(period_s, n / share if share > 0 else 0.0)
        if topic == "/health":
            wait = min(wait, max(period_s, float(self.cfg.stale_after_s)))
        return now + wait

    def _check_budget(self, now: float) -> None:
        """Say once when the essentials alone take more than the budget (and when they fit again).

        Measured over 10 s (:attr:`_essential_meter`); the figures said are the ones when the
        problem began, so the text stays the same while it lasts.
        """
        if not self._essential_meter.full(now):
            return  # the first seconds: a partial window, and the start-up messages
        ess = self._essential_meter.rate(now)
        budget = self.bucket.rate
        with self._lock:
            over, over_rate = self._budget_problem, self._budget_problem_rate
        if ess > budget and (over is None or over_rate != budget):  # (a new budget: said anew)
            per = sorted(
                ((self.outs[t].meter.rate(now), t) for t in ESSENTIAL_TOPICS), reverse=True
            )
            top = ", ".join(f"{t} {r * 8 / 1000:.0f}" for r, t in per[:3] if r > 0)
            text = (
                f"link budget too small: the essentials alone (health, shifts, telemetry, fixes, "
                f"map, log) take {ess * 8 / 1000:.0f} kbit/s ({top}) of the "
                f"{self.cfg.bandwidth_kbps:g} kbit/s budget: no images go; raise bandwidth_kbps "
                "or send fewer shifts"
            )
            with self._lock:
                self._budget_problem, self._budget_problem_rate = text, budget
            self.on_log(1, text)
        elif over is not None and ess < 0.9 * budget:
            with self._lock:
                self._budget_problem = None
            self.on_log(
                0,
                f"the essentials fit the link budget again ({ess * 8 / 1000:.0f} of "
                f"{self.cfg.bandwidth_kbps:g} kbit/s)",
            )

    def budget_problem(self) -> str | None:
        """Return what is said while the essentials alone exceed the budget, else None."""
        with self._lock:
            return self._budget_problem

    def _note_error(self, text: str) -> None:
        with self._lock:
            self.errors.append(text)
            del self.errors[:-20]

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
        if now - self._health_checked >= self.cfg.health_period_s:
            self._health_checked = now
            self._say_stale(now)
            self._check_budget(now)
        # the periodic essentials: each within its share of the budget (_next_due)
        next_at = self._due
        if now >= next_at.get("/health", -1.0):
            n = self._essential("/health", self.health_message(now))
            next_at["/health"] = self._next_due("/health", self.cfg.health_period_s, n, now)
        if self._health and now >= next_at.get("/health/values", -1.0):
            n = self._essential("/health/values", self.values_message())
            next_at["/health/values"] = self._next_due(
                "/health/values", self.cfg.values_period_s, n, now
            )
        self._send_telemetry(now)
        for stream in self.streams.values():  # encode the newest input of each stream that is due
            with self._lock:
                item, seq = stream.item, stream.seq
            due = now - stream.last_sent >= getattr(self.cfg, stream.period_attr, 0.0)
            stale = (
                stream.pending is not None
                and seq != stream.pending_seq
                and now - stream.pending_t > 0.5
            )
            if (
                item is not None
                and seq != stream.sent_seq
                and due
                and (stream.pending is None or stale)
            ):
                if stream.pending is None:  # waiting since (kept when replaced by a newer)
                    stream.pending_t = now
                stream.pending = self._encode_to_fit(stream, item, now)
                stream.pending_seq = seq
        # the track and footprints: small, rate-limited by geo_period_s, charged like the essentials
        if self._geo_dirty and now >= next_at.get("/footprints", -1.0):
            with self._lock:
                track, footprints = list(self._track), list(self._footprints)
                self._geo_dirty = False
            text = feature_collection(
                track, footprints, tolerance_m=float(self.cfg.track_tolerance_m)
            )
            n = self._essential("/footprints", GeoJson(geojson=text).encode())
            next_at["/footprints"] = self._next_due("/footprints", self.cfg.geo_period_s, n, now)

        def order(x: _Stream) -> tuple[int, int]:
            # strict priority, except that a stream kept waiting 4 periods (>= 4 s) goes first:
            # the camera is starved of rate and quality first, but not for ever
            period = getattr(self.cfg, x.period_attr, 0.0)
            starved = x.pending is not None and now - x.pending_t > max(4.0, 4 * period)
            return (0 if starved else 1, x.priority)

        for stream in sorted(self.streams.values(), key=order):
            if stream.pending is None:
                continue
            n = sum(wire_bytes(len(m)) for _, m in stream.pending) * max(
                1, max(self.clients(t) for t in stream.topics)
            )
            if not self.bucket.allows(n, now):
                break  # strict priority: nothing lower goes while this waits
            for topic, m in stream.pending:
                self._log(topic, m)
            stream.sent_seq, stream.last_sent, stream.sent = (
                stream.pending_seq,
                now,
                stream.sent + 1,
            )
            stream.pending = None

    def target_bytes(self, stream: _Stream, now: float) -> float:
        """Return the bytes one message of ``stream`` should take.

        Its share of what the essentials leave:
        ``share = max(0.1 B, B - essentials) * w_stream / sum(w of streams fed in the last 10 s)``,
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
        w = stream.weight / max(
            1e-9, sum(x.weight for x in active) if stream in active else stream.weight
        )
        clients = max(1, max(self.clients(t) for t in stream.topics))
        return avail * w * max(getattr(self.cfg, stream.period_attr, 0.0), 1.0) / clients

    def _encode_to_fit(self, stream: _Stream, item, now: float) -> list:
        """Encode ``item`` at the stream's rung, stepping down the ladder until it fits.

        The rung goes down while the message is 25 % over its target, and one rung up for next
        time when it is under half of it.
        """
        target = self.target_bytes(stream, now)
        msgs = self._encode(stream, item)
        size = sum(len(m) for _, m in msgs)
        while size > 1.25 * target and stream.level < len(LEVELS) - 1:
            stream.level += 1
            msgs = self._encode(stream, item)
            size = sum(len(m) for _, m in msgs)
        if size < 0.5 * target and stream.level > 0:
            stream.level -= 1
        return msgs

    def _encode(self, stream: _Stream, item) -> list:
        rung = LEVELS[stream.level]
        for topic, max_px, frame_id in (
            ("/mosaic", self.cfg.mosaic_max_px, "mosaic"),
            ("/camera", self.cfg.camera_max_px, "camera"),
        ):
            if stream.topics == (topic,):
                img, stamp = item
                small = _shrink(_to_u8(img), int(max_px * rung.scale))
                return [(topic, self._jpeg(small, rung.quality, stamp, frame_id))]
        sr, bic, stamp, factor, fallback = item
        crop = max(32, int(self.cfg.sr_crop_px))
        h, w = sr.shape[:2]
        r0, c0 = max(0, (h - crop) // 2), max(0, (w - crop) // 2)
        win = (slice(r0, r0 + crop), slice(c0, c0 + crop))
        f = f" x{factor}" if factor else ""
        where = f" rows {r0}-{min(h, r0 + crop)} cols {c0}-{min(w, c0 + crop)}"
        side = int(crop * rung.scale)
        out = [
            (
                "/super_resolved",
                self._jpeg(
                    _label(_shrink(_to_u8(sr[win]), side), sr_label(f + where, fallback)),
                    rung.quality,
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
                        rung.quality,
                        stamp,
                        "super_resolved",
                    ),
                )
            )
        return out

    _jpeg = staticmethod(_jpeg)

    def _send_telemetry(self, now: float) -> None:
        """Send the latest telemetry if some is waiting and the channel is due (its share)."""
        with self._lock:
            msg = self._telemetry_pending
            if msg is None or now < self._due.get("/telemetry", -1.0):
                return
            self._telemetry_pending = None
            # set before sending: a feeder's on_telemetry meanwhile waits for its turn
            self._due["/telemetry"] = now
        n = self._essential("/telemetry", msg)
        with self._lock:
            self._due["/telemetry"] = self._next_due("/telemetry", 0.0, n, now)

    # ------------------------------------------------------------------ health
    def link_stats(self) -> dict:
        """Return the budget (kbit/s), bytes/s per channel, total, and each image stream's rung."""
        per = {t: round(o.meter.rate()) for t, o in self.outs.items()}
        return {
            "budget_kbps": self.cfg.bandwidth_kbps,
            "sent_kbps": round(sum(per.values()) * 8 / 1000, 1),
            "essential_kbps": round(self._essential_meter.rate() * 8 / 1000, 1),
            "over_budget": self.budget_problem() or "",
            "bytes_per_s": per,
            "levels": {
                n: {
                    "quality": LEVELS[stream.level].quality,
                    "scale": LEVELS[stream.level].scale,
                    "sent": stream.sent,
                }
                for n, stream in self.streams.items()
            },
            "clients": self._client_count(),
            "errors": list(self.errors[-3:]),
        }

    def health_message(self, now: float | None = None) -> dict:
        """Return the health table: a row per node, STALE when silent beyond ``stale_after_s``.

        Each row has what the operator reads at a glance (level, message, the status's age and
        six columns); every key of every node goes on ``/health/values`` (:meth:`values_message`).
        """
        now = time.monotonic() if now is None else now
        stale = self.stale_nodes(now)
        keys = {
            "input_hz": "input_hz",
            "output_hz": "output_hz",
            "dropped": "dropped_frames",
            "latency_p50_ms": "latency_p50_ms",
            "queue_depth": "queue_depth",
            "last_error": "last_error",
        }
        with self._lock:
            nodes = []
            for name, st in sorted(self._health.items()):
                v = st["values"]
                level = LEVEL_NAMES.get(st["level"], str(st["level"]))
                message = st["message"]
                if name in stale:
                    message = f"no status for {stale[name]:.0f} s (its last: {level} {message})"
                    level = "STALE"
                nodes.append(
                    {
                        "name": name,
                        "level": level,
                        "message": message,
                        "status_age_s": round(now - st["received"], 1),
                        # a column the node does not report is left out (blank in the table)
                        **{k: str(v[src]) for k, src in keys.items() if v.get(src, "") != ""},
                    }
                )
        return {"timestamp": _ts_json(time.time_ns()), "nodes": nodes, "link": self.link_stats()}

    def values_message(self) -> dict:
        """Return every key/value of every node's latest status (``/health/values``)."""
        with self._lock:
            values = {
                name: {k: str(x) for k, x in st["values"].items()}
                for name, st in sorted(self._health.items())
            }
        return {"timestamp": _ts_json(time.time_ns()), "values": values}
