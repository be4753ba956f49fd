"""Stage parameters for ``subpix process``: read from config/*.yaml, checked, transport keys out."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

from subpix_ros.process.inputs import InputError

__all__ = [
    "EXPECTED_SHIFT_PARAMS",
    "load_params",
    "load_params_files",
    "pipeline_params",
    "check_params",
    "live_only_notes",
]

# The registration stage's parameters that the expected shift and frame interval use.
EXPECTED_SHIFT_PARAMS = (
    "focal_length_mm",
    "pixel_pitch_um",
    "camera_yaw_offset_deg",
    "telemetry_time_offset_s",
    "telemetry_timeout_s",
    "p",
    "min_speed_mps",
)


def load_params(path: str | Path | None) -> dict[str, dict]:
    """Stage parameters by node name from a config/*.yaml (``node: ros__parameters: {...}``)."""
    if path is None:
        return {}
    import yaml

    try:
        data = yaml.safe_load(Path(path).read_text()) or {}
    except (OSError, yaml.YAMLError) as exc:
        raise InputError(
            f"cannot read parameters {path}: {' '.join(str(exc).split())[:200]}"
        ) from None
    if not isinstance(data, dict):
        raise InputError(f"parameters {path}: expected a mapping of node names")
    out: dict[str, dict] = {}
    for node, body in data.items():
        if isinstance(body, dict) and "ros__parameters" in body:
            body = body["ros__parameters"]
        if not isinstance(body, dict):
            raise InputError(f"parameters {path}: {node} is not a mapping")
        out[str(node).lstrip("/")] = dict(body)
    return out


def load_params_files(paths: Sequence[str | Path]) -> dict[str, dict]:
    """Stage parameters by node name from several files, each on top of the ones before.

    As several ``--params-file`` of a ROS node: a later file's value of a node's parameter
    replaces an earlier one's; the others stay (:func:`load_params` reads each).
    """
    out: dict[str, dict] = {}
    for path in paths:
        for node, body in load_params(path).items():
            out.setdefault(node, {}).update(body)
    return out


# Parameters of the DDS transport only (QoS, queues, publication rate): meaningless in-process.
_TRANSPORT = {"camera_reliable", "queue_size", "publish_rate_hz", "jpeg_quality"}
# Live settings a batch job must not follow: the products would depend on the machine's speed.
_LIVE_ONLY = {"max_cpu_cores"}
_NODES = ("registration_node", "shift_node", "reconstruction_node", "mosaic_node")


def pipeline_params(params: dict[str, dict]) -> dict[str, dict]:
    """Return the four processing nodes' parameters, without transport and live-only keys.

    Live-only settings: :func:`live_only_notes`.
    """
    drop = _TRANSPORT | _LIVE_ONLY
    return {n: {k: v for k, v in params.get(n, {}).items() if k not in drop} for n in _NODES}


def live_only_notes(params: dict[str, dict]) -> list[str]:
    """Return one line per live-only setting in ``params`` that ``subpix process`` leaves out."""
    return [
        f"{node}.{key} = {body[key]!r} is a live setting, not used by subpix process: every set "
        "is reconstructed, so the products do not depend on the machine's speed"
        for node in _NODES
        for key in sorted(_LIVE_ONLY)
        if (body := params.get(node, {})).get(key) not in (None, 0, 0.0)
    ]


def check_params(params: dict[str, dict]) -> None:
    """Raise :class:`InputError` (one line) if a stage rejects a parameter."""
    from subpix_ros.stages import MosaicStage, Pipeline

    pp = pipeline_params(params)
    try:
        Pipeline(pp, with_mosaic=False)
        MosaicStage.from_params(pp["mosaic_node"])
    except (ValueError, TypeError) as exc:
        raise InputError(f"bad parameter: {exc}") from None
