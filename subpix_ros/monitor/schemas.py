"""The monitor's channels: topics, the JSON schemas of its own messages, health level names."""

from __future__ import annotations

__all__ = [
    "TOPICS",
    "SHIFT_SCHEMA",
    "TELEMETRY_SCHEMA",
    "HEALTH_SCHEMA",
    "HEALTH_VALUES_SCHEMA",
    "ESSENTIAL_SHARES",
]

# the message's time again as a ROS-style header: Foxglove's plots order series by header.stamp
_HEADER = {
    "type": "object",
    "description": "the same time as timestamp, for Foxglove's header-stamp plots",
    "properties": {
        "stamp": {
            "type": "object",
            "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}},
        },
        "frame_id": {"type": "string"},
    },
}

SHIFT_SCHEMA = {
    "title": "subpix.Shift",
    "type": "object",
    "properties": {
        "timestamp": {
            "type": "object",
            "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}},
        },
        "header": _HEADER,
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
        "header": _HEADER,
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
                    "level": {
                        "type": "string",
                        "description": "OK, WARN, ERROR, or STALE: no status for stale_after_s",
                    },
                    "message": {"type": "string"},
                    "status_age_s": {
                        "type": "number",
                        "description": "seconds since the node's last /diagnostics status",
                    },
                    "input_hz": {"type": "string"},
                    "output_hz": {"type": "string"},
                    "dropped": {"type": "string"},
                    "latency_p50_ms": {"type": "string"},
                    "queue_depth": {"type": "string"},
                    "last_error": {"type": "string"},
                },
                "required": ["name", "level", "message", "status_age_s"],
                "description": "a column the node does not report (or reports empty) is left "
                "out; every key of every node is on /health/values",
            },
        },
        "link": {
            "type": "object",
            "description": "the monitor's own link budget, bytes/s per channel, the essentials' "
            "kbit/s and, when they alone exceed the budget, the problem said",
        },
    },
}
HEALTH_VALUES_SCHEMA = {
    "title": "subpix.HealthValues",
    "type": "object",
    "description": "every key/value of every node's latest status (the health table's detail), "
    "complete in each message, sent every values_period_s at most",
    "properties": {
        "timestamp": {
            "type": "object",
            "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}},
        },
        "values": {
            "type": "object",
            "description": "node name -> {key: value}",
            "additionalProperties": {
                "type": "object",
                "additionalProperties": {"type": "string"},
            },
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
    "/health/values": "subpix.HealthValues",
    "/log": "foxglove.Log",
}
ESSENTIAL_TOPICS = (
    "/shift",
    "/telemetry",
    "/fix",
    "/footprints",
    "/health",
    "/health/values",
    "/log",
)
# the most of the link budget a periodic essential takes: a message of n bytes (times the
# clients subscribed) waits at least n / (share * budget) after the previous one, so on a small
# link these come less often instead of starving the images
ESSENTIAL_SHARES = {
    "/health": 0.10,
    "/health/values": 0.05,
    "/footprints": 0.05,
    "/telemetry": 0.05,
}
LEVEL_NAMES = {0: "OK", 1: "WARN", 2: "ERROR", 3: "STALE"}
