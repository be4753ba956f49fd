"""The DDS participant of an rclpy context: Fast DDS teardown work-arounds, shared by every process.

Used by :func:`subpix_ros.nodes.run.run_nodes` (every node process) and by the CLI commands that
talk ROS (``subpix record``, ``replay``, ``demo``).
"""

from __future__ import annotations

__all__ = ["detach_discovery_listener"]

#: rmw_fastrtps_cpp::get_domain_participant(rmw_node_t*): the node's Fast DDS DomainParticipant.
_GET_PARTICIPANT = "_ZN16rmw_fastrtps_cpp22get_domain_participantEP10rmw_node_s"
#: Fast DDS 2.x DomainParticipant::set_listener(DomainParticipantListener*, std::chrono::seconds).
_SET_LISTENER = (
    "_ZN8eprosima7fastdds3dds17DomainParticipant12set_listener"
    "EPNS1_25DomainParticipantListenerENSt6chrono8durationIlSt5ratioILl1ELl1EEEE"
)


def _loaded_library(prefix: str):
    """Return the shared library of this process whose file name starts with ``prefix`` (or None)."""
    import ctypes
    import os

    try:
        with open("/proc/self/maps") as maps:
            paths = {line.split()[-1] for line in maps if "/" + prefix in line}
    except OSError:
        return None
    for path in sorted(paths):
        if os.path.basename(path).startswith(prefix):
            return ctypes.CDLL(path)  # already loaded: the same handle, nothing run again
    return None


def detach_discovery_listener(node, timeout_s: int = 5) -> bool:
    """Take rmw_fastrtps's discovery listener off ``node``'s DDS participant, waiting properly.

    Why: deleting the participant (rclpy's ``destroy_node`` of a context's last node) starts with
    Fast DDS's ``DomainParticipant::set_listener(nullptr)`` and its infinite default timeout. In
    the Fast DDS 2.14 of the ROS wheels that deadline overflows when it is turned into a
    ``pthread_cond_timedwait`` time: the wait fails at once without releasing the listener's
    mutex, so a discovery callback in flight at that moment (a peer's endpoints going away: the
    replay leaving as the recorder stops) can never finish, and the process hangs for good in
    ``destroy_node``, deaf to Ctrl-C (eProsima/Fast-DDS#6513 describes the spin). The same call
    with a finite timeout waits on the condition as it should, and the later one then finds no
    listener and returns at once.

    Returns True when the listener was taken off; False where this does not apply (another RMW,
    another Fast DDS, no such symbols: the teardown is then left as it was) or did not finish
    within ``timeout_s``.
    """
    import ctypes

    try:
        import rclpy

        if rclpy.get_rmw_implementation_identifier() != "rmw_fastrtps_cpp":
            return False
        rcl, rmw, fastdds = (
            _loaded_library(p) for p in ("librcl.so", "librmw_fastrtps_cpp.so", "libfastrtps.so")
        )
        if rcl is None or rmw is None or fastdds is None:
            return False
        get_rmw_handle = rcl.rcl_node_get_rmw_handle
        get_participant = getattr(rmw, _GET_PARTICIPANT)
        set_listener = getattr(fastdds, _SET_LISTENER)
    except (AttributeError, OSError, ImportError):
        return False
    get_rmw_handle.argtypes = [ctypes.c_void_p]
    get_rmw_handle.restype = ctypes.c_void_p
    get_participant.argtypes = [ctypes.c_void_p]
    get_participant.restype = ctypes.c_void_p
    # (this, listener, std::chrono::seconds) -> ReturnCode_t, a uint32 returned in a register
    set_listener.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int64]
    set_listener.restype = ctypes.c_uint32
    try:
        with node.handle:
            rmw_node = get_rmw_handle(node.handle.pointer)
            participant = get_participant(rmw_node) if rmw_node else None
            if not participant:
                return False
            # ctypes releases the GIL for the call; RETCODE_OK is 0
            return set_listener(participant, None, int(timeout_s)) == 0
    except Exception:  # noqa: BLE001 - a node already destroyed, an invalid handle: leave it
        return False
