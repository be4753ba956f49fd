"""Thin rclpy nodes: parameters, message conversion, stage calls, diagnostics.

The helpers every node shares live in :mod:`.params` (declared parameters), :mod:`.qos`
(profiles, lazy publishing), :mod:`.stamps`, :mod:`.worker` (rate meter, drop-oldest worker),
:mod:`.diagnostics` and :mod:`.run` (the console entry points' ``main``). They are exported
here lazily, so importing :mod:`subpix_ros.nodes.payloads` (``subpix process``) loads no rclpy.
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    "Param": "params",
    "declare_params": "params",
    "camera_qos": "qos",
    "reliable_qos": "qos",
    "latched_qos": "qos",
    "publish_if_subscribed": "qos",
    "qos_event_callbacks": "qos",
    "stamp_to_ns": "stamps",
    "ns_to_stamp": "stamps",
    "RateMeter": "worker",
    "DropOldestWorker": "worker",
    "Diagnostics": "diagnostics",
    "run_nodes": "run",
}

__all__ = list(_EXPORTS)


def __getattr__(name: str):
    """Import the module that defines ``name`` on first access (PEP 562)."""
    if name not in _EXPORTS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f".{_EXPORTS[name]}", __name__), name)
