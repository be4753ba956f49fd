"""Thin rclpy nodes: parameters, message conversion, stage calls, diagnostics.

The helpers every node shares live in :mod:`.params` (declared parameters), :mod:`.qos`
(profiles, lazy publishing), :mod:`.stamps`, :mod:`.worker` (rate meter, drop-oldest worker),
:mod:`.diagnostics` and :mod:`.run` (the console entry points' ``main``). They are exported
here lazily, so importing :mod:`subpix_ros.nodes.payloads` (``subpix process``) loads no rclpy.
"""

from __future__ import annotations

from subpix_ros._lazy import lazy_exports

_EXPORTS = {
    "Param": "params",
    "declare_params": "params",
    "camera_qos": "qos",
    "best_effort_qos": "qos",
    "reliable_qos": "qos",
    "latched_qos": "qos",
    "output_qos": "qos",
    "FollowingSubscription": "qos",
    "publish_if_subscribed": "qos",
    "qos_event_callbacks": "qos",
    "stamp_to_ns": "stamps",
    "ns_to_stamp": "stamps",
    "steady_timer": "stamps",
    "RateMeter": "worker",
    "DropOldestWorker": "worker",
    "Diagnostics": "diagnostics",
    "run_nodes": "run",
}

__all__ = list(_EXPORTS)

__getattr__ = lazy_exports(__name__, _EXPORTS)
