"""Process-level settings of subpix_ros processes (nodes, ``subpix`` commands, benchmarks).

:func:`keep_freed_memory` keeps freed frame-sized buffers in the heap for
reuse: glibc's mmap and trim thresholds are raised to 64 MiB, so the
frame-sized numpy/OpenCV temporaries of each frame are not fresh pages the
kernel maps in on first touch (the measurements behind it are in
docs/design-notes.md, "Process settings (runtime.py)"). Every node's
``main``, the ``subpix`` command and the benchmarks call it. It is a no-op
where glibc's ``mallopt`` is missing (musl, macOS, Windows), an operator's
own ``MALLOC_MMAP_THRESHOLD_`` / ``MALLOC_TRIM_THRESHOLD_`` or
``GLIBC_TUNABLES=glibc.malloc.*`` environment settings win, and
``SUBPIX_DEFAULT_MALLOC=1`` opts out: nothing is changed then.

:func:`configure_ros_environment` (also called by every entry point, before
rclpy creates a DDS participant) gives a plainly activated venv what the
nodes need to exchange camera frames: the package's Fast DDS profile
(``config/fastdds_profile.xml``, a shared-memory segment that holds whole
frames; see docs/design-notes.md, "Camera frames between processes") and the
venv's ament prefix. Settings the operator made are kept.

:func:`clean_stale_shm_segments` removes the Fast DDS shared-memory segments
that killed processes left in ``/dev/shm``.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import faulthandler
import fcntl
import os
import re
import signal
import sys
import time
from pathlib import Path

__all__ = [
    "DIE_WITH_PARENT_ENV",
    "die_with_parent_if_asked",
    "keep_freed_memory",
    "favour_throughput",
    "favour_memory",
    "configure_allocator",
    "MALLOC_PROFILE",
    "release_freed_memory",
    "THROUGHPUT",
    "allocator_line",
    "add_malloc_argument",
    "MMAP_THRESHOLD",
    "TRIM_THRESHOLD",
    "OPT_OUT",
    "configure_ros_environment",
    "fastdds_profile",
    "profile_in_use",
    "PROFILE_VARS",
    "RuntimeSetupError",
    "remove_stale_shm_segments",
    "clean_stale_shm_segments",
    "ProcessLoad",
    "proc_status_mb",
]

#: glibc's ``mallopt`` parameter numbers (malloc.h).
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
_M_ARENA_MAX = -8

#: Blocks up to this size come from the heap (more than a float32 4K frame).
MMAP_THRESHOLD = 64 * 1024 * 1024
#: Freed heap kept for reuse before the top of the heap is returned to the kernel.
TRIM_THRESHOLD = 64 * 1024 * 1024
#: ``subpix process`` (a batch job, throughput first): one arena, and blocks up to 512 MiB
#: (a 4K colour set's largest arrays) reused from the heap; the heap's top returned beyond
#: 256 MiB. Measured in docs/design-notes.md ("CPU of `subpix process`, and an onboard profile").
THROUGHPUT = {"mmap_threshold": 512 << 20, "trim_threshold": 256 << 20, "arena_max": 1}
#: ``SUBPIX_MALLOC=memory`` (onboard, memory first): one arena, frame-sized blocks reused from
#: the heap (as :data:`MMAP_THRESHOLD`), and the heap's top returned beyond 16 MiB instead of 64.
#: Measured in docs/design-notes.md ("Allocators").
MEMORY = {"mmap_threshold": MMAP_THRESHOLD, "trim_threshold": 16 << 20, "arena_max": 1}

_ENV = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "MALLOC_ARENA_MAX")

#: ``memory``: the nodes allocate from one arena (:func:`favour_memory`) instead of keeping
#: freed frame buffers (:func:`keep_freed_memory`). Read by :func:`configure_allocator`.
MALLOC_PROFILE = "SUBPIX_MALLOC"

#: Set to 1 to leave glibc's allocator alone (inherited by child processes: a benchmark's nodes).
OPT_OUT = "SUBPIX_DEFAULT_MALLOC"


def _operator_set() -> bool:
    """Tell whether the environment opts out or sets glibc's malloc thresholds (or tunables)."""
    return (
        os.environ.get(OPT_OUT, "") not in ("", "0")
        or any(os.environ.get(k) for k in _ENV)
        or "glibc.malloc." in os.environ.get("GLIBC_TUNABLES", "")
    )


def _glibc_function(name: str, argtypes: list):
    """Return the C library's function ``name`` (returning int), or None where it is missing."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        fn = getattr(ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6"), name)
    except (OSError, AttributeError):
        return None
    fn.argtypes = argtypes
    fn.restype = ctypes.c_int
    return fn


def _mallopt():
    """Return glibc's ``mallopt``, or None where there is none."""
    return _glibc_function("mallopt", [ctypes.c_int, ctypes.c_int])


def keep_freed_memory(
    mmap_threshold: int = MMAP_THRESHOLD,
    trim_threshold: int = TRIM_THRESHOLD,
    arena_max: int | None = None,
) -> bool:
    """Keep freed frame buffers in the heap for reuse (glibc ``mallopt``).

    Process-wide and harmless to call twice.

    Parameters
    ----------
    mmap_threshold : int
        Blocks up to this size (bytes) come from the heap.
    trim_threshold : int
        Freed heap kept on top for reuse before it is returned to the kernel, bytes.
    arena_max : int, optional
        Most malloc arenas (``M_ARENA_MAX``; default: glibc's, 8 per core). A thread's own
        arena is a set of 64 MiB heaps, so a block larger than that (a 4K float32 colour image
        is 100 MB) is mapped fresh from the kernel whatever the mmap threshold; with one arena
        every thread allocates from the main heap, where the thresholds apply. Takes effect for
        threads that have not allocated yet: call it before starting threads.

    Returns
    -------
    bool
        True if all were applied; False if this is not glibc, if the operator
        set glibc's malloc tunables in the environment (theirs are kept), or if
        glibc refused a value.

    Raises
    ------
    ValueError
        If a threshold is not positive or does not fit a C int.
    """
    if not (0 < int(mmap_threshold) <= 2**31 - 1 and 0 < int(trim_threshold) <= 2**31 - 1):
        raise ValueError("thresholds must be positive and fit a C int (bytes)")
    if arena_max is not None and not 0 < int(arena_max) <= 2**31 - 1:
        raise ValueError("arena_max must be positive and fit a C int")
    if _operator_set():
        return False
    fn = _mallopt()
    if fn is None:
        return False
    mmap_ok = fn(_M_MMAP_THRESHOLD, int(mmap_threshold)) == 1
    trim_ok = fn(_M_TRIM_THRESHOLD, int(trim_threshold)) == 1
    arena_ok = arena_max is None or fn(_M_ARENA_MAX, int(arena_max)) == 1
    return mmap_ok and trim_ok and arena_ok


def release_freed_memory() -> float | None:
    """Return the heap's free pages to the kernel (glibc ``malloc_trim(0)``).

    Freed blocks inside the heap stay resident until glibc reuses them; trimming hands their
    whole pages back (``madvise(MADV_DONTNEED)``), so the next allocations of that size fault
    fresh pages in again. For a process that must stay small between large jobs.

    Returns
    -------
    float or None
        The resident memory released (MB, from VmRSS in ``/proc/self/status``; 0 if it did not fall);
        None where there is no glibc ``malloc_trim``.
    """
    fn = _glibc_function("malloc_trim", [ctypes.c_size_t])
    if fn is None:
        return None
    before = _rss_bytes()
    fn(0)
    after = _rss_bytes()
    if before is None or after is None:
        return 0.0
    return max(0.0, (before - after) / 1e6)


def _rss_bytes() -> int | None:
    """Return this process's resident set size in bytes, or None (no /proc)."""
    rss = proc_status_mb(("VmRSS",)).get("VmRSS")
    return None if rss is None else int(rss * 2**20)


def proc_status_mb(keys: tuple[str, ...], pid: int | str = "self") -> dict[str, float]:
    """Return the named ``kB`` fields of ``/proc/<pid>/status`` in MB (e.g. VmRSS, VmHWM).

    Empty when the file cannot be read (no /proc, or the process is gone).
    """
    try:
        lines = Path(f"/proc/{pid}/status").read_text().splitlines()
    except OSError:
        return {}
    out = {}
    for line in lines:
        key, _, rest = line.partition(":")
        if key in keys and rest.split():
            out[key] = int(rest.split()[0]) / 1024
    return out


class ProcessLoad:
    """The load of the process as a node reports it: CPU in cores since the last reading, RSS.

    ``values()`` gives ``process_cpu_cores`` (CPU seconds of every thread per second of wall
    time since the previous call; the first call counts from construction),
    ``process_rss_mb`` (VmRSS) and ``process_rss_peak_mb`` (VmHWM, the kernel's high-water
    mark since the process started), read from /proc/self/status (RSS keys absent without
    /proc). In a process with several nodes each reports the same process.
    """

    def __init__(self, clock=time.monotonic, cpu=time.process_time) -> None:
        self.clock, self.cpu = clock, cpu
        self._last = (clock(), cpu())

    def cores(self) -> float:
        """CPU cores used since the previous call (0 when no wall time has passed)."""
        now = (self.clock(), self.cpu())
        wall, used = now[0] - self._last[0], now[1] - self._last[1]
        self._last = now
        return used / wall if wall > 0 else 0.0

    def values(self) -> dict[str, str]:
        """Return the /diagnostics key/values (strings)."""
        out = {"process_cpu_cores": f"{self.cores():.2f}"}
        mem = proc_status_mb(("VmRSS", "VmHWM"))
        if "VmRSS" in mem:
            out["process_rss_mb"] = f"{mem['VmRSS']:.0f}"
        if "VmHWM" in mem:
            out["process_rss_peak_mb"] = f"{mem['VmHWM']:.0f}"
        return out


def favour_memory() -> bool:
    """One malloc arena and a low trim threshold (``SUBPIX_MALLOC=memory``: onboard).

    Every thread allocates from the main heap, so the blocks one thread frees (frames, a
    set's arrays) are reused by the others instead of sitting in per-thread arenas; blocks up
    to 64 MiB come from that heap (a frame is not mapped and faulted in afresh each time), and
    free memory at the heap's top beyond 16 MiB goes back to the kernel (:data:`MEMORY`).

    Returns
    -------
    bool
        True if applied; False if this is not glibc or the operator set glibc's malloc
        tunables (theirs are kept).

    Notes
    -----
    Chosen against one arena with glibc's dynamic thresholds (this profile before) and
    jemalloc on the onboard soak: docs/design-notes.md, "Allocators".
    """
    return keep_freed_memory(**MEMORY)


def configure_allocator() -> str:
    """Apply the allocator a node process runs with; return which (``"memory"``, ``"reuse"``, ``""``).

    ``SUBPIX_MALLOC=memory`` in the environment: :func:`favour_memory` (the onboard
    profile's choice, docs/design-notes.md "Onboard profile"); unset or empty:
    :func:`keep_freed_memory`; any other value is refused with one line on stderr and the
    default applies. ``""`` when nothing was changed (not glibc, or the operator's own
    settings).
    """
    profile = os.environ.get(MALLOC_PROFILE, "")
    if profile == "memory":
        return "memory" if favour_memory() else ""
    if profile:
        print(
            f"warning: {MALLOC_PROFILE}={profile!r} is not a known allocator profile (only "
            f"'memory'): the default (freed frame buffers kept for reuse) applies",
            file=sys.stderr,
        )
    return "reuse" if keep_freed_memory() else ""


#: OpenCV's own variable for its worker threads (read when cv2 is imported); an operator's
#: value is left alone.
CV_THREADS_VAR = "OPENCV_FOR_THREADS_NUM"

#: OpenCV worker threads of a node process when the operator did not choose
#: (docs/design-notes.md, "OpenCV threads in the node processes").
NODE_CV_THREADS = 1


def configure_opencv_threads(default: int = NODE_CV_THREADS) -> int:
    """Give OpenCV ``default`` worker threads unless ``OPENCV_FOR_THREADS_NUM`` is set.

    Parameters
    ----------
    default : int, optional
        Threads for OpenCV's parallel loops (1: each call runs in its calling thread).

    Returns
    -------
    int
        ``cv2.getNumThreads()`` afterwards.

    Notes
    -----
    A node process already runs its stages in threads of its own (executor, workers, the
    reconstruction); OpenCV's pool on top of them oversubscribes a small computer's cores and
    spins while it waits (figures: docs/design-notes.md, "OpenCV threads in the node
    processes"). ``subpix process`` (a batch job that wants the wall time down) sets its own
    count.
    """
    import cv2

    if os.environ.get(CV_THREADS_VAR, "").strip() == "":
        cv2.setNumThreads(int(default))
    return int(cv2.getNumThreads())


def favour_throughput() -> bool:
    """Apply :data:`THROUGHPUT` (``subpix process``: CPU before resident memory).

    Returns
    -------
    bool
        As :func:`keep_freed_memory`.
    """
    return keep_freed_memory(**THROUGHPUT)


def add_malloc_argument(parser, where: str = "") -> None:
    """Add the benchmarks' ``--default-malloc`` flag to ``parser``.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The benchmark's parser.
    where : str
        Which processes the flag reaches, for the help text.
    """
    parser.add_argument(
        "--default-malloc",
        action="store_true",
        help=f"glibc's default allocator thresholds{where} (subpix_ros.runtime)",
    )


def allocator_line(default_malloc: bool = False) -> str:
    """Apply :func:`keep_freed_memory` for a benchmark, as the nodes and ``subpix`` do.

    Parameters
    ----------
    default_malloc : bool
        Leave glibc's defaults instead (also in the processes this one starts).

    Returns
    -------
    str
        One line describing the allocator the timings ran with.
    """
    if default_malloc:
        os.environ[OPT_OUT] = "1"  # and in the processes this one starts
        return (
            "allocator: glibc defaults (--default-malloc; the nodes and subpix keep freed "
            "frame buffers)"
        )
    if keep_freed_memory():
        return (
            f"allocator: freed frame buffers kept for reuse, as in the nodes and subpix "
            f"(mmap threshold {MMAP_THRESHOLD >> 20} MiB, "
            f"trim threshold {TRIM_THRESHOLD >> 20} MiB; "
            f"--default-malloc for glibc's defaults)"
        )
    return (
        "allocator: unchanged (not glibc, or SUBPIX_DEFAULT_MALLOC, MALLOC_* or GLIBC_TUNABLES "
        "set in the environment)"
    )


def dump_stacks_on_sigusr1() -> bool:
    """Print every thread's Python stack to stderr on ``SIGUSR1`` (``kill -USR1 <pid>``).

    For a process that hangs (a node that stops publishing, a recorder that does not stop): the
    stacks show where, and the process keeps running. The tests send it before they give up on
    a process.

    Returns
    -------
    bool
        False where the platform has no ``SIGUSR1`` or the process has no stderr file
        (``sys.__stderr__`` closed or not a file: nothing to print to).
    """
    if not hasattr(signal, "SIGUSR1"):
        return False
    try:  # the process's own stderr (file descriptor 2), whatever sys.stderr is replaced with
        faulthandler.register(signal.SIGUSR1, file=sys.__stderr__, all_threads=True)
    except (AttributeError, OSError, ValueError):  # io.UnsupportedOperation is both
        return False
    return True


# --------------------------------------------------------------------------- ROS / DDS environment
#: Variables a ROS install or an operator's shell may set for ROS, DDS or colcon.
ROS_ENV_PREFIXES = (
    "ROS_",
    "RMW_",
    "AMENT_",
    "FASTRTPS_",
    "FASTDDS_",
    "COLCON_",
    "CYCLONEDDS_",
    "ZENOH_",
)


#: Environment variable: ``1`` makes a node process or a ``subpix`` command end with the
#: process that started it (:func:`die_with_parent_if_asked`), as ``subpix demo`` asks of its
#: pipeline and replays: a demo killed with SIGKILL leaves none of them running.
DIE_WITH_PARENT_ENV = "SUBPIX_DIE_WITH_PARENT"


def die_with_parent_if_asked(environ=None) -> bool:
    """Call :func:`die_with_parent` when ``SUBPIX_DIE_WITH_PARENT=1``; return whether it did.

    The variable is taken out of the environment, so that processes this one starts do not
    inherit the request.
    """
    environ = os.environ if environ is None else environ
    if environ.pop(DIE_WITH_PARENT_ENV, "") != "1":
        return False
    die_with_parent()
    return True


def die_with_parent() -> None:
    """Ask the kernel to send this worker SIGTERM when its parent dies (Linux; else nothing).

    A pool worker left waiting for a task when the parent is gone (e.g. one the pool started
    while it was being stopped) then stops too instead of living on as an orphan.
    """
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, int(signal.SIGTERM), 0, 0, 0)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass
    if os.getppid() == 1:  # the parent died before the request took effect
        os.kill(os.getpid(), signal.SIGTERM)


def plain_venv_environ(venv: str | Path, domain_id: int | str, environ=None) -> dict[str, str]:
    """Return the environment of a shell that only ran ``source <venv>/bin/activate``.

    Parameters
    ----------
    venv : path
        The virtual environment.
    domain_id : int or str
        ``ROS_DOMAIN_ID`` to keep traffic apart (the only ROS variable set).
    environ : mapping, optional
        The environment to start from (default ``os.environ``).

    Returns
    -------
    dict
        ``environ`` without any ROS / DDS / colcon variable (:data:`ROS_ENV_PREFIXES`) and
        ``PYTHONPATH``, with the venv's ``bin`` first on ``PATH``: how a user without a ROS
        install runs the package (tests and benchmarks that start it as users do).
    """
    src = os.environ if environ is None else environ
    env = {k: v for k, v in src.items() if not k.startswith(ROS_ENV_PREFIXES)}
    env.pop("PYTHONPATH", None)
    env["VIRTUAL_ENV"] = str(venv)
    env["PATH"] = f"{Path(venv) / 'bin'}:{env.get('PATH', '')}"
    env["ROS_DOMAIN_ID"] = str(domain_id)
    return env


#: Fast DDS reads its XML profiles from the first of these that is set (FASTDDS_* from Fast DDS 3).
PROFILE_VARS = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")
#: What Fast DDS loads by itself from the working directory when no variable is set.
_CWD_PROFILES = ("DEFAULT_FASTRTPS_PROFILES.xml", "DEFAULT_FASTDDS_PROFILES.xml")
_PROFILE_NAME = "fastdds_profile.xml"
#: The profile of the nodes that write no image: a 1 MiB segment instead of 64 MiB.
_SMALL_PROFILE_NAME = "fastdds_profile_small.xml"
_FASTDDS_RMWS = ("rmw_fastrtps_cpp", "rmw_fastrtps_dynamic_cpp")


class RuntimeSetupError(RuntimeError):
    """The process cannot run as configured; the message is one line saying what is missing."""


def fastdds_profile(large_messages: bool = True) -> Path | None:
    """Find the package's Fast DDS profile.

    Parameters
    ----------
    large_messages : bool, optional
        True (default): ``fastdds_profile.xml``, a 64 MiB shared-memory segment, for a process
        that writes images; False: ``fastdds_profile_small.xml`` (1 MiB), for one that writes
        only small messages.

    Returns
    -------
    pathlib.Path or None
        That file in ``config/`` of the checkout (venv / editable install), else of
        ``share/subpix_ros`` next to the interpreter's prefix or on ``AMENT_PREFIX_PATH``.
    """
    name = _profile_name(large_messages)
    candidates = [
        Path(__file__).resolve().parents[1] / "config" / name,
        Path(sys.prefix) / "share" / "subpix_ros" / "config" / name,
    ]
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if prefix:
            candidates.append(Path(prefix) / "share" / "subpix_ros" / "config" / name)
    return next((c for c in candidates if c.is_file()), None)


def _profile_name(large_messages: bool) -> str:
    """File name of the package's profile for a process that writes images, or not."""
    return _PROFILE_NAME if large_messages else _SMALL_PROFILE_NAME


def _cwd_profile() -> str | None:
    """Fast DDS's own default profile file in the working directory, if there is one."""
    return next((n for n in _CWD_PROFILES if Path(n).is_file()), None)


def profile_in_use(environ=None) -> str:
    """Name the Fast DDS profile file this process's participant loads (for /diagnostics).

    Returns
    -------
    str
        The file name of the first of :data:`PROFILE_VARS` that is set, else Fast DDS's own
        default file in the working directory, else ``"none (Fast DDS defaults)"``.
    """
    env = os.environ if environ is None else environ
    named = next((env[v] for v in PROFILE_VARS if env.get(v)), "")
    if named:
        return Path(named).name
    return _cwd_profile() or "none (Fast DDS defaults)"


def configure_ros_environment(environ=None, *, large_messages: bool = True) -> list[str]:
    """Set the defaults a plainly activated venv needs, before rclpy creates a participant.

    Parameters
    ----------
    environ : mapping, optional
        The environment to complete (default ``os.environ``).
    large_messages : bool, optional
        Whether this process writes images (default True): which of the package's profiles
        it gets (:func:`fastdds_profile`).

    Returns
    -------
    list of str
        What was set, as ``VAR=value`` lines.

    Notes
    -----
    * The package's Fast DDS profile (``FASTRTPS_DEFAULT_PROFILES_FILE``), when the RMW is Fast
      DDS (``RMW_IMPLEMENTATION`` unset or ``rmw_fastrtps_*``) and the operator chose no profile
      of their own (neither variable of :data:`PROFILE_VARS` set, no ``SKIP_DEFAULT_XML=1``, no
      Fast DDS default profile file in the working directory). Without it a best-effort
      subscriber loses camera frames larger than Fast DDS's 512 KiB shared-memory segment
      (docs/design-notes.md, "Camera frames between processes"). The segment is the
      writer's and is backed in full from the start, so a process that writes no image
      (``large_messages=False``) gets a 1 MiB one instead (the readers' side needs none).
      A variable naming one of the package's own profiles (inherited from a parent process,
      or ``scripts/env.sh``) is not the operator's choice: it is replaced by the fitting one.
    * The venv's ament prefix (``<venv>/subpix_prefix``, made by ``make venv``) on
      ``AMENT_PREFIX_PATH``, so ``get_package_share_directory('subpix_ros')`` and ``ros2``
      tools started from this process find the package.

    Raises
    ------
    RuntimeSetupError
        When the profile the operator named does not exist (Fast DDS would go on with its
        defaults after a log line), or the package's profile is not found.
    """
    env = os.environ if environ is None else environ
    done: list[str] = []
    chosen = [v for v in PROFILE_VARS if env.get(v)]
    ours = {str(p.resolve()) for p in map(fastdds_profile, (True, False)) if p is not None}
    if chosen and all(str(Path(env[v]).resolve()) in ours for v in chosen):
        # one of the package's own profiles, inherited from a parent subpix process or set
        # by scripts/env.sh: this process takes the one that fits what it writes
        for var in chosen:
            del env[var]
        chosen = []
    for var in chosen:
        if not Path(env[var]).is_file():
            raise RuntimeSetupError(
                f"{var}={env[var]} names no file (unset it to use subpix_ros's Fast DDS profile)"
            )
    rmw = env.get("RMW_IMPLEMENTATION", "")
    own = chosen or env.get("SKIP_DEFAULT_XML", "") not in ("", "0") or _cwd_profile() is not None
    if not own and (not rmw or rmw in _FASTDDS_RMWS):
        profile = fastdds_profile(large_messages)
        if profile is None:
            raise RuntimeSetupError(
                f"subpix_ros's Fast DDS profile {_profile_name(large_messages)} not found "
                f"(reinstall the package, or set "
                f"FASTRTPS_DEFAULT_PROFILES_FILE)"
            )
        env[PROFILE_VARS[0]] = str(profile)
        done.append(f"{PROFILE_VARS[0]}={profile}")
    prefix = Path(sys.prefix) / "subpix_prefix"
    paths = [entry for entry in env.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if entry]
    if (prefix / "share" / "ament_index").is_dir() and str(prefix) not in paths:
        env["AMENT_PREFIX_PATH"] = os.pathsep.join([str(prefix), *paths])
        done.append(f"AMENT_PREFIX_PATH+={prefix}")
    return done


#: A Fast DDS shared-memory segment: ``fastrtps_<16 hex digits>`` (its lock file adds ``_el``);
#: port files (``fastrtps_port<N>``) are shared between processes and left to Fast DDS.
_SEGMENT_RE = re.compile(r"^fastrtps_[0-9a-f]{16}$")


def remove_stale_shm_segments(shm_dir: str | Path = "/dev/shm", min_age_s: float = 60.0):
    """Remove the shared-memory segments of Fast DDS participants that no longer exist.

    Parameters
    ----------
    shm_dir : str or Path
        Where Fast DDS keeps its segments (``/dev/shm`` on Linux).
    min_age_s : float
        Segments modified more recently than this are left alone (a starting participant).

    Returns
    -------
    tuple of (int, int)
        Segments removed and the bytes they held.

    Notes
    -----
    A live participant holds an exclusive ``flock`` on its segment's ``<name>_el`` file for its
    whole life; a process that was killed (SIGKILL, OOM) cannot release the segment, which stays
    in ``/dev/shm`` (64 MiB each with the package's profile). A segment whose lock can be taken
    has no owner: it is removed while the lock is held. Nothing else is touched.
    """
    removed = freed = 0
    d = Path(shm_dir)
    try:
        names = os.listdir(d)
    except OSError:
        return 0, 0
    now = time.time()
    for name in names:
        if not _SEGMENT_RE.match(name) or name + "_el" not in names:
            continue
        seg, lock = d / name, d / (name + "_el")
        try:
            st = seg.stat()
            if now - st.st_mtime < min_age_s:
                continue
            fd = os.open(lock, os.O_RDWR)
        except OSError:
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)  # held: its participant is alive
            continue
        try:
            seg.unlink()
            lock.unlink()
            removed += 1
            freed += st.st_blocks * 512
        except OSError:
            pass
        finally:
            os.close(fd)
    return removed, freed


def clean_stale_shm_segments() -> int:
    """Run :func:`remove_stale_shm_segments` at an entry point's start (``SUBPIX_KEEP_SHM=1``: not).

    Quiet: the commands' own stderr stays theirs (scripts read it).

    Returns
    -------
    int
        Segments removed.
    """
    if os.environ.get("SUBPIX_KEEP_SHM", "") not in ("", "0"):
        return 0
    return remove_stale_shm_segments()[0]
