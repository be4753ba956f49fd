"""The monitor on a small link: the essentials leave room for the images, or it is said.

A real Monitor over a real socket, fed by ``benchmarks/bench_monitor_link.py``'s flight: six nodes'
statuses (about 50 keys each, as the nodes report them), a survey track of 2000 fixes flown and 5
more a second, a footprint with each of the 4 camera frames a second, shifts at 10 Hz, telemetry at
5 Hz, the mosaic and super-resolved images. A foxglove.sdk.v1 client subscribes to everything.
"""

import json
import re
import time

from benchmarks.bench_monitor_link import NODES, Flight, per_channel_kbps
from subpix_ros.monitor import TOPICS, Monitor, MonitorConfig
from subpix_ros.monitor.client import FoxgloveClient
from subpix_ros.monitor.schemas import (
    ESSENTIAL_TOPICS,
    HEALTH_SCHEMA,
    HEALTH_VALUES_SCHEMA,
    SHIFT_SCHEMA,
    TELEMETRY_SCHEMA,
)

_TYPES = {
    "object": dict,
    "array": list,
    "string": str,
    "integer": int,
    "number": (int, float),
    "boolean": bool,
    "null": type(None),
}


def _check(value, schema, where="$"):
    """Check ``value`` against the JSON-schema subset the monitor's schemas use.

    type, properties (and no key the schema does not name, unless additionalProperties),
    required, items. Returns the problems found.
    """
    problems = []
    types = schema.get("type")
    if types is not None:
        types = [types] if isinstance(types, str) else types
        ok = any(
            isinstance(value, _TYPES[t]) and not (t in ("integer", "number") and value is True)
            for t in types
        )
        if not ok:
            return [f"{where}: {type(value).__name__} is not {types}"]
    if isinstance(value, dict):
        props = schema.get("properties", {})
        extra = schema.get("additionalProperties")
        for key in schema.get("required", []):
            if key not in value:
                problems.append(f"{where}: no {key!r}")
        for key, v in value.items():
            if key in props:
                problems += _check(v, props[key], f"{where}.{key}")
            elif isinstance(extra, dict):
                problems += _check(v, extra, f"{where}.{key}")
            elif props and extra is None:
                problems.append(f"{where}: {key!r} is not in the schema")
    if isinstance(value, list) and "items" in schema:
        for i, v in enumerate(value):
            problems += _check(v, schema["items"], f"{where}[{i}]")
    return problems


def _connect(url):
    c = FoxgloveClient(url)
    assert c.wait(lambda: len(c.channels) == len(TOPICS), 10), c.error
    time.sleep(0.3)  # the subscriptions reach the server
    return c


def test_at_100_kbps_the_essentials_leave_room_for_the_images():
    """A telemetry radio: before, the essentials alone took 196 kbit/s here and no image went."""
    kbps = 100.0
    mon = Monitor(MonitorConfig(port=0, bandwidth_kbps=kbps))
    flight = Flight(mon)  # 2000 fixes flown before the client connects
    client = _connect(mon.url)
    try:
        t0 = time.monotonic()
        flight.start()
        time.sleep(18.0)
        t1 = time.monotonic()
        flight.stop()
        time.sleep(0.5)
        assert mon.budget_problem() is None, mon.budget_problem()
    finally:
        client.close()
        mon.close()
    lo, hi = t0 + 4.0, t1  # after the start-up burst, while the flight is fed
    got = per_channel_kbps(client, lo, hi)
    essential = sum(got[t] for t in ESSENTIAL_TOPICS)
    table = ", ".join(f"{t} {k:.1f}" for t, k in got.items())
    assert essential < 0.6 * kbps, f"essentials {essential:.1f} kbit/s: {table}"
    assert sum(got.values()) < 1.1 * kbps, table
    # the images went: the mosaic and the camera more than once, the super-resolved pair
    for topic, least in (("/mosaic", 3), ("/camera", 5), ("/super_resolved", 1)):
        n = sum(lo <= r.t < hi for r in client.messages(topic))
        assert n >= least, f"{topic}: {n} images in {hi - lo:.0f} s; {table}"
    # every shift fed went (never throttled)
    assert len(client.messages("/shift")) == flight.fed_shifts
    # the health table every second or so, each message with every node's row
    health = [r for r in client.messages("/health") if lo <= r.t < hi]
    assert len(health) >= 0.7 * (hi - lo), len(health)
    for r in health:
        rows = {n["name"]: n for n in json.loads(r.payload)["nodes"]}
        assert set(rows) == set(NODES)
        assert all(n["level"] == "OK" and n["message"] == "ok" for n in rows.values())
    # every key of every node on /health/values, complete in each message
    values = [json.loads(r.payload)["values"] for r in client.messages("/health/values")]
    assert values and all(set(v) == set(NODES) for v in values)
    assert len(values[-1]["registration_node"]) >= 40
    # the messages are what their schemas say
    for topic, schema in (
        ("/health", HEALTH_SCHEMA),
        ("/health/values", HEALTH_VALUES_SCHEMA),
        ("/shift", SHIFT_SCHEMA),
        ("/telemetry", TELEMETRY_SCHEMA),
    ):
        for r in client.messages(topic)[-3:]:
            msg = json.loads(r.payload)
            assert not _check(msg, schema), (topic, _check(msg, schema))
    # the map: the track thinned (a survey's legs), the recent footprints in one MultiPolygon
    geo = json.loads(
        client.decode("/footprints", client.messages("/footprints")[-1].payload).geojson
    )
    kinds = {f["properties"]["name"]: f["geometry"] for f in geo["features"]}
    assert kinds["track"]["type"] == "LineString"
    assert 10 <= len(kinds["track"]["coordinates"]) <= 150, len(kinds["track"]["coordinates"])
    assert kinds["footprints"]["type"] == "MultiPolygon"
    assert len(kinds["footprints"]["coordinates"]) == 30  # max_footprints


def test_a_budget_too_small_for_the_essentials_is_said_once():
    """8 kbit/s: the shifts alone take 21. Said in /log once, held in link.over_budget."""
    mon = Monitor(MonitorConfig(port=0, bandwidth_kbps=8.0))
    flight = Flight(mon, track=200)
    client = _connect(mon.url)
    try:
        flight.start()
        assert client.wait(lambda: mon.budget_problem() is not None, 25), mon.link_stats()
        said = mon.budget_problem()
        assert said.startswith("link budget too small: the essentials alone")
        assert "of the 8 kbit/s budget: no images go" in said, said
        # the figures: the shifts (10 x 259 bytes a second) first among the channels named
        figures = re.search(r"take (\d+) kbit/s \(/shift (\d+),", said)
        assert figures and 25 <= int(figures[1]) <= 45 and 18 <= int(figures[2]) <= 24, said

        def logs():
            return [client.decode("/log", r.payload).message for r in client.messages("/log")]

        assert client.wait(lambda: said in logs(), 5), logs()
        assert client.wait(
            lambda: (
                json.loads(client.messages("/health")[-1].payload)["link"]["over_budget"] == said
            ),
            15,
        )
        time.sleep(3.0)  # it goes on: said once, the text the same
        assert logs().count(said) == 1 and mon.budget_problem() == said
        assert not client.messages("/mosaic") and not client.messages("/camera")
        # a larger budget: the essentials fit, that is said, and images go
        mon.set_bandwidth_kbps(1000.0)
        assert client.wait(lambda: any("fit the link budget again" in t for t in logs()), 15)
        assert mon.budget_problem() is None
        assert client.wait(lambda: client.messages("/mosaic") and client.messages("/camera"), 10)
        flight.stop()
    finally:
        client.close()
        mon.close()
