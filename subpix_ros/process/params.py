"""Stage parameters for ``subpix process``: read from config/*.yaml, checked, transport keys out.

A params file is read as the nodes read it with ``--params-file`` (rclpy's rules): the sections
of every file are merged by their name as written, each where that name first appeared (a
later file's value of a key replaces an earlier one's), then each node takes the sections that
match it (``/**``: the keys it declares) in that order, the last value winning. What cannot
apply is said before any bag is processed: a key the node does not declare, or a node name
close to one ``subpix process`` runs, is an error (:class:`ParamsError`); another program's
node is ignored with a warning.
"""

from __future__ import annotations

import difflib
import functools
from pathlib import Path
from typing import Any, Callable, Sequence

from subpix_ros.process.inputs import InputError

__all__ = [
    "EXPECTED_SHIFT_PARAMS",
    "PROCESS_NODES",
    "ParamsError",
    "declared_params",
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


#: The nodes ``subpix process`` runs (as stages), in pipeline order.
PROCESS_NODES = ("registration_node", "shift_node", "reconstruction_node", "mosaic_node")

#: Parameters each of them declares that are the node's transport (QoS, queues, publication,
#: input watch), not its stage's: accepted in a params file, meaningless in-process.
#: test/process/test_params.py checks them against the nodes' declarations.
_NODE_ONLY = {
    "registration_node": (
        "camera_reliable",
        "queue_size",
        "input_timeout_s",
        "camera_delay_warn_ms",
    ),
    "shift_node": ("queue_size", "input_timeout_s"),
    "reconstruction_node": ("queue_size", "latch_output", "input_timeout_s"),
    "mosaic_node": (
        "camera_reliable",
        "publish_rate_hz",
        "jpeg_quality",
        "queue_size",
        "input_timeout_s",
    ),
}

#: The package's other nodes (not run by ``subpix process``) and their parameters, so that a
#: shared stack file's sections and ``/**`` keys for them are known, not taken for typos.
_OTHER_NODES = {
    "telemetry_node": (
        "source",
        "connection",
        "baud",
        "system_id",
        "link_timeout_s",
        "tlog_rate",
        "tlog_start_delay_s",
        "focal_length_mm",
        "pixel_pitch_um",
        "p",
        "phi_deg",
        "camera_rate_hz",
        "camera_yaw_offset_deg",
        "mavros_fix_topic",
        "mavros_velocity_topic",
        "mavros_height_topic",
        "mavros_imu_topic",
        "open_retry_s",
        "input_timeout_s",
        "gps_frame_id",
        "world_frame_id",
        "base_frame_id",
        "camera_frame_id",
    ),
    "monitor_node": (
        "host",
        "port",
        "tls_cert",
        "tls_key",
        "allow_insecure",
        "bandwidth_kbps",
        "burst_s",
        "backlog_messages",
        "mosaic_max_px",
        "mosaic_period_s",
        "sr_crop_px",
        "camera_max_px",
        "camera_period_s",
        "geo_period_s",
        "health_period_s",
        "values_period_s",
        "track_tolerance_m",
        "stale_after_s",
        "max_footprints",
        "record_mcap",
        "mosaic_compressed",
        "camera_reliable",
        "shift_std_wait_s",
        "focal_length_mm",
        "pixel_pitch_um",
        "telemetry_timeout_s",
        "camera_yaw_offset_deg",
        "input_timeout_s",
    ),
}

#: Parameters every ROS 2 node has (rclcpp/rclpy declare them): accepted anywhere, unused here.
_ROS_BUILTIN = frozenset({"use_sim_time", "start_type_description_service"})
_ROS_BUILTIN_PREFIX = "qos_overrides."

# Parameters of the DDS transport only (QoS, queues, publication, input watch): left out in-process.
_TRANSPORT = frozenset(k for keys in _NODE_ONLY.values() for k in keys)
# Live settings a batch job must not follow: the products would depend on the machine's speed.
_LIVE_ONLY = {"max_cpu_cores"}

_WILDCARDS = ("**", "*")
_CLOSE = 0.8  # difflib ratio from which a name is taken for a misspelling of a known one


class ParamsError(InputError):
    """A params file names a parameter or node that does not apply (exit status 2)."""


def stage_classes() -> dict[str, type]:
    """Return the stage class of each node of :data:`PROCESS_NODES`, in pipeline order."""
    from subpix_ros.stages import MosaicStage, ReconstructionStage, RegistrationStage, ShiftStage

    return dict(
        zip(PROCESS_NODES, (RegistrationStage, ShiftStage, ReconstructionStage, MosaicStage))
    )


@functools.cache
def declared_params(node: str) -> frozenset[str]:
    """Return the parameters ``node`` (one of :data:`PROCESS_NODES`) takes in a params file.

    Parameters
    ----------
    node : str
        A node name of :data:`PROCESS_NODES`.

    Returns
    -------
    frozenset of str
        Its stage's parameters, the node's own (transport) ones and, for
        ``reconstruction_node``, the core solver's options the stage passes on.

    Notes
    -----
    The stage's parameters come from the stage class (the node declares the same specs); the
    node-only ones from a table that test/process/test_params.py checks against the node.
    """
    stage = stage_classes()[node]
    names = {s.name for s in stage.PARAMS} | set(_NODE_ONLY[node])
    if node == "reconstruction_node":
        from subpix_ros.stages.reconstruction import solver_option_names

        names |= solver_option_names()
    return frozenset(names)


def _builtin(key: str) -> bool:
    """Return True for a parameter every ROS 2 node has (``use_sim_time``, QoS overrides)."""
    return key in _ROS_BUILTIN or key.startswith(_ROS_BUILTIN_PREFIX)


def _flatten(params: dict, prefix: str = "") -> dict[str, Any]:
    """Return nested parameter mappings as rcl names them: ``{"a": {"b": 1}}`` -> ``a.b``."""
    out: dict[str, Any] = {}
    for key, value in params.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(_flatten(value, f"{name}."))
        else:
            out[name] = value
    return out


def _has_sections(body: dict) -> bool:
    """Return True if ``body`` holds ``ros__parameters`` sections below it (a namespace)."""
    return any(
        isinstance(v, dict) and ("ros__parameters" in v or _has_sections(v)) for v in body.values()
    )


def _read_sections(path: str | Path) -> list[tuple[str, dict[str, Any]]]:
    """Return one params file's sections, in file order, as ``(node path, parameters)``.

    Parameters
    ----------
    path : str or Path
        A ROS 2 params file (``node: ros__parameters: {...}``; namespaces as ``/ns/node:`` or
        nested ``/ns: node: ros__parameters:``; ``node: {...}`` without ``ros__parameters``
        is read as the node's parameters too).

    Returns
    -------
    list of (str, dict)
        The node path with a leading ``/`` (``/registration_node``, ``/**``, ``/ns/shift_node``)
        and its parameters, nested names joined by ``.`` as rcl does.

    Raises
    ------
    InputError
        The file cannot be read, is not YAML, or a section is not a mapping.
    """
    import yaml

    try:
        data = yaml.safe_load(Path(path).read_text()) or {}
    except UnicodeDecodeError:
        raise InputError(
            f"cannot read parameters {path}: not a YAML text file (not UTF-8 text)"
        ) from None
    except (OSError, yaml.YAMLError) as exc:
        raise InputError(
            f"cannot read parameters {path}: {' '.join(str(exc).split())[:200]}"
        ) from None
    if not isinstance(data, dict):
        raise InputError(f"parameters {path}: expected a mapping of node names")
    out: list[tuple[str, dict[str, Any]]] = []

    def walk(prefix: str, level: dict) -> None:
        for key, body in level.items():
            name = f"{prefix}/{str(key).strip('/')}"
            if body is None:
                body = {}
            if not isinstance(body, dict):
                raise InputError(f"parameters {path}: {name.lstrip('/')} is not a mapping")
            if "ros__parameters" in body:
                params = body["ros__parameters"] or {}
                if not isinstance(params, dict):
                    raise InputError(f"parameters {path}: {name.lstrip('/')} is not a mapping")
                out.append((name, _flatten(params)))
            elif _has_sections(body):
                walk(name, body)
            else:
                out.append((name, _flatten(body)))

    walk("", data)
    return out


def _close(name: str, known: Sequence[str], cutoff: float = _CLOSE) -> str | None:
    """Return the name of ``known`` that ``name`` is likely a misspelling of, or None."""
    got = difflib.get_close_matches(name, known, n=1, cutoff=cutoff)
    return got[0] if got else None


def _close_node(name: str) -> str | None:
    """Return the node of :data:`PROCESS_NODES` that node ``name`` likely misspells, or None.

    Notes
    -----
    Names are compared whole (cutoff 0.85) and without a ``_node`` suffix (cutoff 0.8): the
    suffix all nodes share makes another program's ``gps_node`` look like ``shift_node`` whole.
    """
    whole = _close(name, PROCESS_NODES, 0.85)
    if whole:
        return whole
    stems = {n.removesuffix("_node"): n for n in PROCESS_NODES}
    stem = _close(name.removesuffix("_node"), list(stems))
    return stems[stem] if stem else None


def _unknown_key(path: Path | str, node: str, key: str) -> ParamsError:
    """Return the error for ``key`` in ``node``'s section, which the node does not declare."""
    hint = ""
    near = _close(key, sorted(declared_params(node)), 0.6)
    if near:
        hint = f" (did you mean {near}?)"
    else:
        owners = [n for n in PROCESS_NODES if key in declared_params(n)]
        if owners:
            hint = f" (a parameter of {' and '.join(owners)})"
    return ParamsError(f"parameters {path}: {node} has no parameter {key}{hint}")


def load_params_files(
    paths: Sequence[str | Path], say: Callable[[str], None] | None = None
) -> dict[str, dict]:
    """Return the parameters of the nodes ``subpix process`` runs, from params files.

    Parameters
    ----------
    paths : sequence of str or Path
        ROS 2 params files, in the order of ``--params`` (as several ``--params-file``).
    say : callable, optional
        Called with each warning or note line (``"warning: ..."``, ``"note: ..."``): a
        section of another program's node, ignored; a section of the package's nodes that
        ``subpix process`` does not run; a ``/**`` key no node here declares.

    Returns
    -------
    dict of str to dict
        Parameters by node name, for the nodes of :data:`PROCESS_NODES` that a file gives a
        value (their own section, even empty, or a ``/**`` key they declare).

    Raises
    ------
    InputError
        A file cannot be read or is not a params file.
    ParamsError
        A key that the node whose section holds it does not declare, a ``/**`` key close to a
        declared one, a node name close to one of :data:`PROCESS_NODES`, or one node given
        under two namespaces: one line naming the file, node and key, with a suggestion.

    Notes
    -----
    rclpy's rules (Jazzy, measured against it in test/process/test_params.py), so that a file
    gives ``subpix process`` what it gives the nodes: rcl merges the files' sections by their
    name as written (``/**``, ``/**/registration_node``, ``registration_node``), each at the
    place where that name first appeared, a later file's value of a key replacing an earlier
    one; a node then takes every section that matches it in that order, the last value of a
    key winning (so a ``/**`` key overrides the node's own section when ``/**`` first appeared
    after it). ``subpix process`` runs its nodes without a namespace and takes a namespaced
    section (``/ns/registration_node``, ``/**/registration_node``) as the node's own. Keys
    every ROS 2 node has (``use_sim_time``, ``qos_overrides.*``) are accepted and unused.
    """
    say = say or (lambda line: None)
    # section name as written -> (the node it is for, or "**"; its parameters), in the order
    # the names first appeared: rcl's merged parameter list
    entries: dict[str, tuple[str, dict[str, Any]]] = {}
    namespaces: dict[str, tuple[str, Path | str]] = {}
    said: set[tuple[str, str]] = set()
    for path in paths:
        sections = _read_sections(path)
        other, foreign = [], []
        for name, params in sections:
            parts = name.strip("/").split("/")
            node, ns = parts[-1], "/" + "/".join(parts[:-1])
            params = {k: v for k, v in params.items() if not _builtin(k)}
            if node in _WILDCARDS:
                _check_wildcard(path, params, say, said)
                entries.setdefault(name, ("**", {}))[1].update(params)
            elif node in PROCESS_NODES:
                accepted = declared_params(node)
                for key in params:
                    if key not in accepted:
                        raise _unknown_key(path, node, key)
                if "*" not in ns:
                    first = namespaces.setdefault(node, (ns, path))
                    if first[0] != ns:
                        raise ParamsError(
                            f"parameters {path}: {node} is given in namespace {first[0]} "
                            f"({first[1]}) and {ns}: subpix process runs one {node}, give one"
                        )
                entries.setdefault(name, (node, {}))[1].update(params)
            elif node in _OTHER_NODES:
                other.append(node)
            else:
                near = _close_node(node)
                if near:
                    raise ParamsError(
                        f"parameters {path}: no node {name.lstrip('/')} in subpix process "
                        f"(did you mean {near}?)"
                    )
                foreign.append(name.lstrip("/"))
        if other:
            names = list(dict.fromkeys(other))
            many = len(names) > 1
            say(
                f"note: parameters {path}: {', '.join(names)}: not used, subpix process does "
                f"not run {'these nodes' if many else 'this node'}"
            )
        for node in dict.fromkeys(foreign):
            say(
                f"warning: parameters {path}: {node} is not a node of subpix_ros: "
                "its parameters are ignored"
            )
    out: dict[str, dict] = {}
    for node in PROCESS_NODES:
        accepted = declared_params(node)
        merged: dict[str, Any] = {}
        given = False  # its own section (even empty), or a /** key it declares
        for target, params in entries.values():
            if target == "**":
                mine = {k: v for k, v in params.items() if k in accepted}
                given = given or bool(mine)
                merged.update(mine)
            elif target == node:
                given = True
                merged.update(params)
        if given:
            out[node] = merged
    return out


def _check_wildcard(
    path: Path | str, params: dict[str, Any], say: Callable[[str], None], said: set
) -> None:
    """Check a ``/**`` section's keys: declared by a node here, by another of ours, or said.

    Notes
    -----
    A ``/**`` section is shared with every node of a stack, other programs' too, so a key no
    node of subpix_ros declares is not an error unless it is close to one ``subpix process``
    takes (a misspelling): it is ignored with a warning, as the nodes ignore it.
    """
    known = sorted(set().union(*(declared_params(n) for n in PROCESS_NODES)))
    others = set().union(*_OTHER_NODES.values())
    for key in params:
        if key in known or key in others:
            continue
        near = _close(key, known)
        if near:
            raise ParamsError(
                f"parameters {path}: /** has {key}, which no node of subpix process declares "
                f"(did you mean {near}?)"
            )
        if (str(path), key) not in said:
            said.add((str(path), key))
            say(
                f"warning: parameters {path}: /** has {key}, which no node of subpix_ros "
                "declares: ignored"
            )


def load_params(
    path: str | Path | None, say: Callable[[str], None] | None = None
) -> dict[str, dict]:
    """Return the parameters of the nodes ``subpix process`` runs, from one params file.

    Parameters
    ----------
    path : str or Path or None
        A ROS 2 params file (config/*.yaml layout); None: no parameters.
    say : callable, optional
        Called with each warning or note line (:func:`load_params_files`).

    Returns
    -------
    dict of str to dict
        Parameters by node name (:func:`load_params_files`).
    """
    return {} if path is None else load_params_files([path], say)


def pipeline_params(params: dict[str, dict]) -> dict[str, dict]:
    """Return the four processing nodes' parameters, without transport and live-only keys.

    Parameters
    ----------
    params : dict of str to dict
        Parameters by node name (:func:`load_params_files`).

    Returns
    -------
    dict of str to dict
        For each of :data:`PROCESS_NODES`, the parameters in effect in ``subpix process``:
        what ``summary.json`` and the report show.

    Notes
    -----
    Transport keys (queues, QoS, publication rate, input watch) mean nothing in-process; live-only
    settings are said by :func:`live_only_notes`.
    """
    drop = _TRANSPORT | _LIVE_ONLY
    return {n: {k: v for k, v in params.get(n, {}).items() if k not in drop} for n in PROCESS_NODES}


def live_only_notes(params: dict[str, dict]) -> list[str]:
    """Return one line per live-only setting in ``params`` that ``subpix process`` leaves out."""
    return [
        f"{node}.{key} = {body[key]!r} is a live setting, not used by subpix process: every set "
        "is reconstructed, so the products do not depend on the machine's speed"
        for node in PROCESS_NODES
        for key in sorted(_LIVE_ONLY)
        if (body := params.get(node, {})).get(key) not in (None, 0, 0.0)
    ]


def check_params(params: dict[str, dict]) -> None:
    """Raise :class:`InputError` (one line, naming the node) if a stage rejects a parameter.

    Parameters
    ----------
    params : dict of str to dict
        Parameters by node name (:func:`load_params_files`).

    Raises
    ------
    InputError
        A value of the wrong type or out of range, e.g. a ``/**`` ``method`` one of the two
        nodes that declare it does not take.
    """
    pp = pipeline_params(params)
    for node, stage in stage_classes().items():
        try:
            stage.from_params(pp[node])
        except (ValueError, TypeError) as exc:
            raise InputError(f"bad parameter: {node}: {exc}") from None
