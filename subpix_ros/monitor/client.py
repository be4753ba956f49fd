"""A small Foxglove WebSocket client (subprotocol ``foxglove.sdk.v1``).

For the tests, the benchmarks and a headless check of a drone's monitor.

Needs the ``websockets`` package (and ``protobuf`` for :meth:`FoxgloveClient.decode`);
neither is needed to serve. ``python -m subpix_ros.monitor.client ws://HOST:8765``
prints the advertised channels and the bytes per second received on each.
"""

from __future__ import annotations

import asyncio
import base64
import json
import ssl
import struct
import sys
import threading
import time
from dataclasses import dataclass, field

__all__ = ["FoxgloveClient", "Received"]


@dataclass
class Received:
    """One message received: receive time, log time, payload bytes and frame size."""

    t: float  # time.monotonic() at arrival
    log_time: int
    payload: bytes
    wire: int  # bytes of the WebSocket message (frame header not included)


@dataclass
class FoxgloveClient:
    """Connect in a background thread, subscribe to ``topics`` (None: all), keep what arrives.

    ``received[topic]`` lists :class:`Received`; ``channels[topic]`` is the advertised channel
    (id, encoding, schemaName, schema, schemaEncoding).
    """

    url: str
    topics: tuple[str, ...] | None = None
    ssl_context: ssl.SSLContext | None = None
    channels: dict = field(default_factory=dict)
    received: dict = field(default_factory=dict)
    server_info: dict = field(default_factory=dict)
    error: BaseException | None = None
    closed: bool = False

    def __post_init__(self) -> None:
        self._lock = threading.Lock()
        self._sub_topic: dict[int, str] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=lambda: asyncio.run(self._main()), daemon=True)
        self._thread.start()

    async def _main(self) -> None:
        import websockets

        try:
            async with websockets.connect(
                self.url,
                subprotocols=["foxglove.sdk.v1"],
                ssl=self.ssl_context,
                max_size=None,
                open_timeout=10,
            ) as ws:
                next_id = 1
                while not self._stop.is_set():
                    try:
                        m = await asyncio.wait_for(ws.recv(), 0.1)
                    except asyncio.TimeoutError:
                        continue
                    now = time.monotonic()
                    if isinstance(m, str):
                        d = json.loads(m)
                        if d.get("op") == "serverInfo":
                            self.server_info = d
                        elif d.get("op") == "advertise":
                            subs = []
                            for ch in d["channels"]:
                                self.channels[ch["topic"]] = ch
                                if self.topics is None or ch["topic"] in self.topics:
                                    self._sub_topic[next_id] = ch["topic"]
                                    subs.append({"id": next_id, "channelId": ch["id"]})
                                    next_id += 1
                            if subs:
                                await ws.send(
                                    json.dumps({"op": "subscribe", "subscriptions": subs})
                                )
                    elif m and m[0] == 1:
                        sub, log_time = struct.unpack_from("<IQ", m, 1)
                        topic = self._sub_topic.get(sub, f"?{sub}")
                        with self._lock:
                            self.received.setdefault(topic, []).append(
                                Received(now, log_time, bytes(m[13:]), len(m))
                            )
        except BaseException as exc:  # noqa: BLE001 - reported to the caller
            if not self._stop.is_set():
                self.error = exc
        finally:
            self.closed = True

    def close(self) -> None:
        """Close the connection and stop the client thread."""
        self._stop.set()
        self._thread.join(5.0)

    def wait(self, until, timeout: float) -> bool:
        """Wait until ``until()`` is true, ``timeout`` s pass or the link closes; return ``until()``."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if until():
                return True
            if self.closed:
                break
            time.sleep(0.02)
        return bool(until())

    def messages(self, topic: str) -> list[Received]:
        """Return the messages received on ``topic`` so far."""
        with self._lock:
            return list(self.received.get(topic, []))

    def decode(self, topic: str, payload: bytes):
        """JSON channels: a dict; protobuf: the message, built from the advertised schema."""
        ch = self.channels[topic]
        if ch["encoding"] == "json":
            return json.loads(payload)
        return _message_class(ch["schemaName"], ch["schema"]).FromString(payload)


_CLASSES: dict = {}


def _message_class(name: str, schema_b64: str):
    """Return the protobuf class of ``name`` from its advertised FileDescriptorSet (base64)."""
    if name in _CLASSES:
        return _CLASSES[name]
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    fds = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(schema_b64))
    pool = descriptor_pool.DescriptorPool()
    for f in fds.file:
        pool.Add(f)
    cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(name))
    _CLASSES[name] = cls
    return cls


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    usage = (
        "usage: python -m subpix_ros.monitor.client ws://HOST:PORT [seconds]\n"
        "Connects to a subpix_ros monitor (a Foxglove WebSocket server), subscribes to every "
        "channel for [seconds] (default 10) and prints each channel's messages and bytes/s."
    )
    if argv and argv[0] in ("-h", "--help"):
        print(usage)
        return 0
    if not argv or not argv[0].startswith(("ws://", "wss://")):
        print(usage, file=sys.stderr)
        return 2
    seconds = float(argv[1]) if len(argv) > 1 else 10.0
    c = FoxgloveClient(argv[0])
    time.sleep(seconds)
    c.close()
    if c.error:
        print(f"error: {c.error}", file=sys.stderr)
        return 1
    for topic, ch in sorted(c.channels.items()):
        got = c.received.get(topic, [])
        print(
            f"{topic:18s} {ch['schemaName']:28s} {len(got):6d} msgs "
            f"{sum(r.wire for r in got) / seconds:10.0f} B/s"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
