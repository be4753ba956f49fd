"""Stage parameters for ``subpix process``: read from config/*.yaml, checked, transport keys out."""

from __future__ import annotations

from pathlib import Path

from subpix_ros.process.inputs import InputError

__all__ = ["EXPECTED_SHIFT_PARAMS", "load_params", "pipeline_params", "check_params"]

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


# Parameters of the DDS transport only (QoS, queues, publication rate): meaningless in-process.
_TRANSPORT = {"camera_reliable", "queue_size", "publish_rate_hz", "jpeg_quality"}


def pipeline_params(params: dict[str, dict]) -> dict[str, dict]:
    """Return the stage pipeline's parameters: the four processing nodes, transport keys left out."""
    keep = ("registration_node", "shift_node", "reconstruction_node", "mosaic_node")
    return {n: {k: v for k, v in params.get(n, {}).items() if k not in _TRANSPORT} for n in keep}


def check_params(params: dict[str, dict]) -> None:
    """Raise :class:`InputError` (one line) if a stage rejects a parameter."""
    from subpix_ros.stages import MosaicStage, Pipeline

    pp = pipeline_params(params)
    try:
        Pipeline(pp, with_mosaic=False)
        MosaicStage.from_params(pp["mosaic_node"])
    except (ValueError, TypeError) as exc:
        raise InputError(f"bad parameter: {exc}") from None
