"""The Monitor over real sockets, fed in-process: link budget, security, MCAP recording, layout.

A foxglove.sdk.v1 client (`websockets`) reads what Foxglove would; the frames are the sample
bag's (data/bags/subpixel) and a real Seneca frame for the mosaic.
"""

import json
import ssl
import subprocess
import threading
import time

import cv2
import numpy as np
import pytest
from conftest import ROOT

from subpix_ros.io import cdr
from subpix_ros.io.bags import read_messages
from subpix_ros.monitor import TOPICS, Monitor, MonitorConfig, MonitorError
from subpix_ros.monitor.client import FoxgloveClient


@pytest.fixture(scope="module")
def frames(sample_bags):
    return [
        cdr.cdr_to_image(m.raw)[0].copy()
        for m in read_messages(sample_bags / "subpixel", ["/camera/image_raw"])
    ]


@pytest.fixture(scope="module")
def mosaic_image():
    img = cv2.imread(str(sorted((ROOT / "data" / "seneca").glob("*.jpg"))[0]), cv2.IMREAD_COLOR)
    assert img is not None
    return img


def _connect(url, **kw):
    c = FoxgloveClient(url, **kw)
    assert c.wait(lambda: len(c.channels) == len(TOPICS), 10), c.error
    time.sleep(0.3)  # the subscriptions reach the server
    return c


class Feeder:
    """A flight fed to the monitor: camera and shifts at 30 Hz, the mosaic changing every 0.5 s."""

    def __init__(self, mon, frames, mosaic, rate_hz=30.0):
        self.mon, self.frames, self.mosaic, self.rate = mon, frames, mosaic, rate_hz
        self.shifts = []  # (monotonic time fed, stamp)
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self):
        i, t0 = 0, time.monotonic()
        while not self._stop.is_set():
            stamp = 1_700_000_000_000_000_000 + i * 33_333_333
            self.mon.on_camera(self.frames[i % len(self.frames)], stamp)
            self.mon.on_shift(stamp, 0.41 * (i % 8), 0.27 * (i % 8), 0.002, 0.002, True, 0.41, 0.27)
            self.shifts.append((time.monotonic(), stamp))
            if i % 15 == 0:
                m = np.roll(self.mosaic, 7 * i, axis=1)  # a changed mosaic every 0.5 s
                self.mon.on_mosaic(m, stamp)
            if i % 60 == 0:
                sr = cv2.resize(
                    self.frames[i % len(self.frames)],
                    None,
                    fx=2,
                    fy=2,
                    interpolation=cv2.INTER_CUBIC,
                )
                self.mon.on_super_resolved(sr, sr, stamp, 2)
                self.mon.on_fix(42.8, -76.7 + i * 1e-6, 120.0, stamp)
            i += 1
            time.sleep(max(0.0, t0 + i / self.rate - time.monotonic()))

    def stop(self):
        self._stop.set()
        self.thread.join()


@pytest.mark.parametrize("kbps", [300.0, 1200.0])
def test_link_budget_holds_and_shifts_keep_full_rate(frames, mosaic_image, kbps):
    mon = Monitor(
        MonitorConfig(
            port=0,
            bandwidth_kbps=kbps,
            camera_period_s=0.05,
            mosaic_period_s=0.5,
            mosaic_max_px=1024,
            camera_max_px=448,
        )
    )
    try:
        client = _connect(mon.url)
        feeder = Feeder(mon, frames, mosaic_image)
        time.sleep(12.0)
        feeder.stop()
        time.sleep(0.5)
        got = [r for msgs in client.received.values() for r in msgs]
        t_start = min(r.t for r in got)
        lo, hi = t_start + 4.0, t_start + 11.0  # after the start-up burst, while the feed runs
        rate = sum(r.wire for r in got if lo <= r.t < hi) / (hi - lo) * 8 / 1000
        assert abs(rate / kbps - 1) <= 0.10, (
            f"received {rate:.1f} kbit/s against a budget of {kbps}"
        )
        # every shift fed arrived (never throttled), none lost
        served = {
            client.decode("/shift", r.payload)["timestamp"]["nsec"]
            + 10**9 * client.decode("/shift", r.payload)["timestamp"]["sec"]
            for r in client.messages("/shift")
        }
        fed = {s for _, s in feeder.shifts}
        assert fed == served, f"{len(fed - served)} of {len(fed)} shifts not served"
        stats = mon.link_stats()
        shift_times = [r.t for r in client.messages("/shift") if lo <= r.t < hi]
        assert len(shift_times) >= 0.95 * 30 * (hi - lo)
        # the images degraded (the camera first), the mosaic still went
        assert (
            stats["levels"]["camera"]["quality"] < 85 or stats["levels"]["camera"]["scale"] < 1
        ), stats
        assert len(client.messages("/mosaic")) >= 2
        client.close()
    finally:
        mon.close()


def test_stalled_client_does_not_hold_back_the_others(frames, mosaic_image):
    import socket

    mon = Monitor(
        MonitorConfig(port=0, bandwidth_kbps=4000, backlog_messages=16, camera_period_s=0.1)
    )
    try:
        # a client that handshakes, subscribes to everything, and then never reads
        stalled = socket.create_connection(("127.0.0.1", mon.port))
        stalled.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        stalled.sendall(
            b"GET / HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
            b"Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n"
            b"Sec-WebSocket-Protocol: foxglove.sdk.v1\r\n\r\n"
        )
        good = _connect(mon.url)
        feeder = Feeder(mon, frames, mosaic_image)
        time.sleep(6.0)
        feeder.stop()
        time.sleep(0.5)
        fed = len(feeder.shifts)
        assert len(good.messages("/shift")) == fed
        assert len(good.messages("/camera")) >= 30
        stalled.close()
        good.close()
    finally:
        mon.close()


def test_exposed_host_needs_tls_or_allow_insecure(tmp_path):
    with pytest.raises(MonitorError, match="refusing to serve on '0.0.0.0' without TLS"):
        Monitor(MonitorConfig(host="0.0.0.0", port=0))
    with pytest.raises(MonitorError, match="set together"):
        Monitor(MonitorConfig(port=0, tls_cert=str(tmp_path / "c.pem")))
    with pytest.raises(MonitorError, match="not a readable file"):
        Monitor(
            MonitorConfig(port=0, tls_cert=str(tmp_path / "c.pem"), tls_key=str(tmp_path / "k.pem"))
        )
    with Monitor(MonitorConfig(host="0.0.0.0", port=0, allow_insecure=True)) as mon:
        c = _connect(f"ws://127.0.0.1:{mon.port}")
        assert c.server_info["capabilities"] == []
        c.close()


def test_tls_serves_wss_only(tmp_path):
    cert, key = tmp_path / "cert.pem", tmp_path / "key.pem"
    subprocess.run(
        [
            "openssl",
            "req",
            "-x509",
            "-newkey",
            "rsa:2048",
            "-nodes",
            "-keyout",
            str(key),
            "-out",
            str(cert),
            "-days",
            "1",
            "-subj",
            "/CN=localhost",
            "-addext",
            "subjectAltName=DNS:localhost,IP:127.0.0.1",
        ],
        check=True,
        capture_output=True,
    )
    with Monitor(
        MonitorConfig(host="0.0.0.0", port=0, tls_cert=str(cert), tls_key=str(key))
    ) as mon:
        assert mon.url.startswith("wss://")
        ctx = ssl.create_default_context(cafile=str(cert))
        c = _connect(f"wss://127.0.0.1:{mon.port}", ssl_context=ctx)
        mon.on_shift(5, 0.1, 0.2)
        assert c.wait(lambda: c.messages("/shift"), 5)
        c.close()
        plain = FoxgloveClient(f"ws://127.0.0.1:{mon.port}")
        assert not plain.wait(lambda: plain.channels, 3)
        plain.close()


def test_everything_served_is_recorded_to_mcap(tmp_path, frames, mosaic_image):
    from mcap.reader import make_reader

    path = tmp_path / "flight.mcap"
    with Monitor(
        MonitorConfig(port=0, record_mcap=str(path), camera_period_s=0.1, mosaic_period_s=1.0)
    ) as mon:
        c = _connect(mon.url)
        feeder = Feeder(mon, frames, mosaic_image)
        time.sleep(4.0)
        feeder.stop()
        mon.set_bandwidth_kbps(1e6)  # what still waits for the link goes now: the client sees it
        deadline = time.monotonic() + 5.0  # every stream's last input sent (after its period)
        while time.monotonic() < deadline and any(
            x.sent_seq != x.seq for x in mon.streams.values()
        ):
            time.sleep(0.05)
        time.sleep(0.5)
        served = {t: [r.payload for r in c.messages(t)] for t in TOPICS}
        c.close()
    with open(path, "rb") as f:
        reader = make_reader(f)
        schemas = {
            ch.topic: reader.get_summary().schemas[ch.schema_id].name
            for ch in reader.get_summary().channels.values()
        }
        recorded = {}
        for _, channel, message in reader.iter_messages():
            recorded.setdefault(channel.topic, []).append(message.data)
    assert schemas == {
        t: TOPICS[t] for t in recorded
    }  # a channel is written with its first message
    for topic in ("/shift", "/camera", "/mosaic", "/fix", "/super_resolved", "/bicubic"):
        assert served[topic], topic
        assert recorded[topic] == served[topic], topic


def test_layout_panels_use_advertised_topics():
    layout = json.loads((ROOT / "config" / "foxglove_layout.json").read_text())
    panels = layout["configById"]

    def topics_of(cfg):
        out = []
        if "imageMode" in cfg:
            out.append(cfg["imageMode"]["imageTopic"])
        out += [p["value"].split(".")[0] for p in cfg.get("paths", [])]
        if "topicPath" in cfg:
            out.append(cfg["topicPath"].split(".")[0])
        if "topicToRender" in cfg:
            out.append(cfg["topicToRender"])
        out += list(cfg.get("topicColors", {}))
        if "followTopic" in cfg:
            out.append(cfg["followTopic"])
        return out

    used = {t for cfg in panels.values() for t in topics_of(cfg)}
    assert used <= set(TOPICS), (
        f"panels refer to topics the monitor does not advertise: {used - set(TOPICS)}"
    )
    assert {"/mosaic", "/super_resolved", "/bicubic", "/shift", "/fix", "/health"} <= used

    def leaves(node):
        return [node] if isinstance(node, str) else leaves(node["first"]) + leaves(node["second"])

    assert sorted(leaves(layout["layout"])) == sorted(panels)
    # a plotted JSON field exists in the schema the monitor advertises
    from subpix_ros.monitor.schemas import HEALTH_SCHEMA, SHIFT_SCHEMA, TELEMETRY_SCHEMA

    schema = {"/shift": SHIFT_SCHEMA, "/telemetry": TELEMETRY_SCHEMA, "/health": HEALTH_SCHEMA}
    for cfg in panels.values():
        for path in [p["value"] for p in cfg.get("paths", [])] + (
            [cfg["topicPath"]] if "topicPath" in cfg else []
        ):
            topic, field = path.split(".", 1)
            assert field in schema[topic]["properties"], path
        for series in cfg.get("paths", []):  # ordered by header.stamp: the messages carry one
            if series.get("timestampMethod") == "headerStamp":
                props = schema[series["value"].split(".")[0]]["properties"]
                assert "stamp" in props["header"]["properties"], series


def test_a_node_that_stops_reporting_is_shown_stale_and_its_return_said():
    """A killed node sends no /diagnostics: its last OK must not stay on the operator's table."""
    mon = Monitor(MonitorConfig(port=0, health_period_s=0.1, stale_after_s=1.0))
    client = _connect(mon.url)
    try:
        alive = {"name": "shift_node", "level": 0, "message": "ok", "values": {}}
        gone = {"name": "registration_node", "level": 0, "message": "ok", "values": {"pid": "100"}}
        mon.on_diagnostics([alive, gone])

        def rows():
            msgs = client.messages("/health")
            if not msgs:
                return {}
            return {n["name"]: n for n in json.loads(msgs[-1].payload)["nodes"]}

        assert client.wait(lambda: rows().get("registration_node", {}).get("level") == "OK", 5)
        t0 = time.monotonic()
        while time.monotonic() - t0 < 2.0:  # shift_node keeps reporting at 5 Hz
            mon.on_diagnostics([alive])
            time.sleep(0.2)
        table = rows()
        assert table["shift_node"]["level"] == "OK"
        assert table["shift_node"]["status_age_s"] < 1.0
        gone_row = table["registration_node"]
        assert gone_row["level"] == "STALE", gone_row
        assert gone_row["status_age_s"] >= 1.0
        assert gone_row["message"].startswith("no status for ")
        assert "(its last: OK ok)" in gone_row["message"]
        assert mon.stale_nodes().keys() == {"registration_node"}

        def logs():
            return [client.decode("/log", m.payload).message for m in client.messages("/log")]

        assert client.wait(lambda: any("no status for" in t for t in logs()), 3), logs()
        assert sum("no status for" in t for t in logs()) == 1  # said once, not every period
        mon.on_diagnostics([dict(gone, values={"pid": "200"})])  # restarted: a new process
        assert client.wait(lambda: any("reporting again" in t for t in logs()), 3), logs()
        assert client.wait(lambda: "restarted (process 100 -> 200)" in logs(), 3), logs()
        assert client.wait(lambda: rows()["registration_node"]["level"] == "OK", 3)
        assert mon.stale_nodes() == {}
    finally:
        client.close()
        mon.close()


def test_the_client_command_answers_help_and_refuses_a_non_websocket_url(capsys):
    from subpix_ros.monitor.client import main

    assert main(["--help"]) == 0 and "ws://HOST:PORT" in capsys.readouterr().out
    assert main(["http://127.0.0.1:8765"]) == 2 and "usage" in capsys.readouterr().err


def test_shift_served_rounded_and_short():
    """A shift goes out rounded to 1e-5 px (errors to 3 digits), a NaN as null, in under 270 bytes."""
    with Monitor(MonitorConfig(port=0)) as mon:
        c = _connect(mon.url)
        stamp = 1_700_000_123_456_789_012
        mon.on_shift(
            stamp,
            0.41372619342803955,
            -0.2712873459124,
            0.0003337983861,
            float("nan"),
            True,
            0.40011234567,
            0.29912345678,
        )
        assert c.wait(lambda: c.messages("/shift"), 5)
        raw = c.messages("/shift")[0].payload
        c.close()
    msg = json.loads(raw)
    assert (msg["u"], msg["v"]) == (0.41373, -0.27129)
    assert (msg["u_std"], msg["v_std"]) == (0.000334, None)
    assert (msg["expected_u"], msg["expected_v"]) == (0.40011, 0.29912)
    assert (msg["du"], msg["dv"]) == (0.01361, -0.57041)
    assert msg["header"]["stamp"] == {"sec": 1_700_000_123, "nsec": 456_789_012}
    assert len(raw) < 270  # 322 bytes with every digit of the floats
