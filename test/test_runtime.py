"""subpix_ros.runtime: freed frame buffers are reused, not faulted in again for every frame.

Each case runs in a fresh Python process (the allocator settings are process-wide).
"""

import json
import os
import re
import subprocess
import sys
import textwrap

import pytest

from subpix_ros.runtime import keep_freed_memory


def _is_glibc() -> bool:
    try:
        return sys.platform.startswith("linux") and bool(os.confstr("CS_GNU_LIBC_VERSION"))
    except (ValueError, OSError):
        return False


glibc = pytest.mark.skipif(not _is_glibc(), reason="mallopt is glibc's")

# "probe": only whether the setting was applied. Otherwise registers the first bundled pair 2 times to warm up,
# then 4 times counting the process's minor page faults.
CHILD = textwrap.dedent("""
    import json, resource, sys
    from subpix_ros.runtime import keep_freed_memory
    applied = keep_freed_memory() if sys.argv[1] in ("keep", "probe") else None
    if sys.argv[1] == "probe":
        print(json.dumps({"applied": applied}))
        sys.exit(0)
    import cv2
    from subpix_ros.core.registration import register
    from subpix_ros.data import seneca_frame_paths
    a, b = (cv2.imread(str(p)) for p in seneca_frame_paths()[:2])
    for _ in range(2):
        register(a, b)
    f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(4):
        assert register(a, b).ok
    print(json.dumps({"applied": applied, "faults": (resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0) / 4}))
""")


def _child(mode: str, env: dict | None = None) -> dict:
    e = {
        k: v
        for k, v in os.environ.items()
        if not k.startswith("MALLOC_") and k not in ("GLIBC_TUNABLES", "SUBPIX_DEFAULT_MALLOC")
    }
    e.update(env or {})
    r = subprocess.run(
        [sys.executable, "-c", CHILD, mode], capture_output=True, text=True, timeout=120, env=e
    )
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout.strip().splitlines()[-1])


@glibc
def test_registration_reuses_freed_frame_buffers():
    # One 1800x1350 float32 luminance alone is 2373 pages: a count far below that per pair means the
    # frame-sized buffers were reused. (glibc's defaults measured 3264 faults per pair here.)
    kept = _child("keep")
    assert kept["applied"] is True
    if kept["faults"] >= 500:
        default = _child("default")
        pytest.fail(
            f"{kept['faults']:.0f} minor faults per pair with keep_freed_memory "
            f"(glibc defaults: {default['faults']:.0f})"
        )


# A 4K float32 colour image (100 MB) allocated and freed in a worker thread, as the reconstruction
# does once per set: with glibc's per-thread arenas it is mapped fresh (25,000 pages) every time.
THREAD_CHILD = textwrap.dedent("""
    import json, resource, sys, threading
    import numpy as np
    from subpix_ros.runtime import favour_throughput
    applied = favour_throughput() if sys.argv[1] == "throughput" else None
    out = {}
    def work():
        for _ in range(2):
            np.ones((2160, 3840, 3), np.float32)
        f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
        for _ in range(4):
            np.ones((2160, 3840, 3), np.float32)
        out["faults"] = (resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0) / 4
    t = threading.Thread(target=work)
    t.start()
    t.join()
    print(json.dumps({"applied": applied, **out}))
""")


@glibc
def test_throughput_settings_reuse_large_blocks_freed_in_threads():
    def child(mode):
        e = {
            k: v
            for k, v in os.environ.items()
            if not k.startswith("MALLOC_") and k not in ("GLIBC_TUNABLES", "SUBPIX_DEFAULT_MALLOC")
        }
        e["NUMPY_MADVISE_HUGEPAGE"] = "0"  # count 4 KiB pages, not 2 MiB ones
        r = subprocess.run(
            [sys.executable, "-c", THREAD_CHILD, mode],
            capture_output=True,
            text=True,
            timeout=120,
            env=e,
        )
        assert r.returncode == 0, r.stderr
        return json.loads(r.stdout.strip().splitlines()[-1])

    fast, default = child("throughput"), child("default")
    assert fast["applied"] is True
    assert default["faults"] > 10000  # the fresh mapping this setting is there to avoid
    assert fast["faults"] < 1000, (fast, default)


# Four threads allocate 8 MB each; glibc's malloc_stats() (on stderr) lists one "Arena N:" per arena.
ARENA_CHILD = textwrap.dedent("""
    import ctypes, sys, threading
    import numpy as np
    from subpix_ros.runtime import configure_allocator
    print(configure_allocator())
    keep = []
    def work():
        keep.append(np.ones((1000, 1000)))
    ts = [threading.Thread(target=work) for _ in range(4)]
    [t.start() for t in ts]
    [t.join() for t in ts]
    sys.stdout.flush()
    ctypes.CDLL("libc.so.6").malloc_stats()
""")


def _profile_child(script: str, profile: str) -> subprocess.CompletedProcess:
    """Run ``script`` in a Python child with ``SUBPIX_MALLOC=profile`` and no malloc settings."""
    e = {
        k: v
        for k, v in os.environ.items()
        if not k.startswith("MALLOC_") and k not in ("GLIBC_TUNABLES", "SUBPIX_DEFAULT_MALLOC")
    }
    e["SUBPIX_MALLOC"] = profile
    r = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=120, env=e
    )
    assert r.returncode == 0, r.stderr
    return r


@glibc
@pytest.mark.parametrize("profile,arenas", [("memory", 1), ("", 2)])
def test_memory_profile_puts_every_thread_in_one_arena(profile, arenas):
    r = _profile_child(ARENA_CHILD, profile)
    assert r.stdout.split()[0] == (profile or "reuse")
    n = len(re.findall(r"^Arena \d+:", r.stderr, re.M))
    assert (n == 1) if arenas == 1 else (n >= arenas), r.stderr


@glibc
@pytest.mark.parametrize(
    "env",
    [
        {"MALLOC_TRIM_THRESHOLD_": "1000000"},
        {"MALLOC_MMAP_THRESHOLD_": "65536"},
        {"GLIBC_TUNABLES": "glibc.malloc.trim_threshold=1000000"},
        {"SUBPIX_DEFAULT_MALLOC": "1"},
        {"MALLOC_ARENA_MAX": "2"},
    ],
)
def test_operator_malloc_settings_are_kept(env):
    assert _child("probe", env)["applied"] is False


@glibc
def test_unrelated_tunables_do_not_block_it():
    assert _child("probe", {"GLIBC_TUNABLES": "glibc.cpu.hwcap_mask=0"})["applied"] is True


@pytest.mark.parametrize(
    "kw",
    [{"mmap_threshold": 0}, {"trim_threshold": -1}, {"trim_threshold": 2**31}, {"arena_max": 0}],
)
def test_bad_thresholds_raise(kw):
    with pytest.raises(ValueError):
        keep_freed_memory(**kw)


# ------------------------------------------------------------- ROS / DDS environment (issue 19)
from subpix_ros.runtime import (  # noqa: E402
    RuntimeSetupError,
    configure_ros_environment,
    fastdds_profile,
    profile_in_use,
)

MISSING = "names no file (unset it to use subpix_ros's Fast DDS profile)"


def test_the_package_profile_is_set_in_a_plain_environment(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    env = {"PATH": "/usr/bin"}
    configure_ros_environment(env)
    assert env["FASTRTPS_DEFAULT_PROFILES_FILE"] == str(fastdds_profile())
    text = fastdds_profile().read_text()
    assert "<segment_size>67108864</segment_size>" in text and 'is_default_profile="true"' in text


def test_a_process_that_writes_no_image_gets_the_small_segment(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    env = {"PATH": "/usr/bin"}
    configure_ros_environment(env, large_messages=False)
    small = fastdds_profile(large_messages=False)
    assert env["FASTRTPS_DEFAULT_PROFILES_FILE"] == str(small) != str(fastdds_profile())
    text = small.read_text()
    assert "<segment_size>1048576</segment_size>" in text and 'is_default_profile="true"' in text
    # the same transports as the large profile, only the segment differs
    large = fastdds_profile().read_text()
    body = text[text.index("<profiles") :]
    assert body == large[large.index("<profiles") :].replace("67108864", "1048576")
    assert profile_in_use(env) == "fastdds_profile_small.xml"


@pytest.mark.parametrize("var", ["FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE"])
@pytest.mark.parametrize("large", [True, False])
def test_an_inherited_package_profile_is_chosen_again(tmp_path, monkeypatch, var, large):
    # a parent subpix process (or scripts/env.sh) exported one of the package's profiles: a
    # child takes the one that fits what it writes, not the parent's
    monkeypatch.chdir(tmp_path)
    env = {var: str(fastdds_profile(large_messages=not large))}
    configure_ros_environment(env, large_messages=large)
    env.pop("AMENT_PREFIX_PATH", None)
    assert env == {"FASTRTPS_DEFAULT_PROFILES_FILE": str(fastdds_profile(large_messages=large))}


def test_the_profile_in_use_is_named(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert profile_in_use({}) == "none (Fast DDS defaults)"
    assert profile_in_use({"FASTDDS_DEFAULT_PROFILES_FILE": "/x/mine.xml"}) == "mine.xml"
    (tmp_path / "DEFAULT_FASTRTPS_PROFILES.xml").write_text("<profiles/>")
    assert profile_in_use({}) == "DEFAULT_FASTRTPS_PROFILES.xml"


@pytest.mark.parametrize(
    "env",
    [
        {"FASTRTPS_DEFAULT_PROFILES_FILE": "{own}"},
        {"FASTDDS_DEFAULT_PROFILES_FILE": "{own}"},
        {"SKIP_DEFAULT_XML": "1"},
        {"RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp"},
    ],
)
@pytest.mark.parametrize("large", [True, False])
def test_the_operators_choice_is_kept(tmp_path, monkeypatch, env, large):
    monkeypatch.chdir(tmp_path)
    own = tmp_path / "mine.xml"
    own.write_text("<profiles/>")
    env = {k: v.format(own=own) for k, v in env.items()}
    before = dict(env)
    configure_ros_environment(env, large_messages=large)
    assert {k: v for k, v in env.items() if k != "AMENT_PREFIX_PATH"} == before


def test_a_default_profile_in_the_working_directory_is_kept(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "DEFAULT_FASTRTPS_PROFILES.xml").write_text("<profiles/>")
    env = {}
    configure_ros_environment(env)
    assert "FASTRTPS_DEFAULT_PROFILES_FILE" not in env


def test_a_named_profile_that_does_not_exist_refuses(tmp_path):
    with pytest.raises(
        RuntimeSetupError, match="FASTRTPS_DEFAULT_PROFILES_FILE=/nonexistent/x.xml names no file"
    ):
        configure_ros_environment({"FASTRTPS_DEFAULT_PROFILES_FILE": "/nonexistent/x.xml"})


def _plain_env(**extra):
    """As `source .venv/bin/activate` leaves it: no ROS / DDS variable but the domain id."""
    drop = ("ROS_", "RMW_", "AMENT_", "FASTRTPS_", "FASTDDS_")
    env = {k: v for k, v in os.environ.items() if not k.startswith(drop)}
    venv = os.path.dirname(os.path.dirname(sys.executable))
    env.update(
        VIRTUAL_ENV=venv,
        PATH=f"{venv}/bin:{env.get('PATH', '')}",
        ROS_DOMAIN_ID=os.environ.get("SUBPIX_TEST_DOMAIN_ID", "0"),
        **extra,
    )
    return env


@pytest.mark.parametrize(
    "module",
    [
        "registration_node",
        "shift_node",
        "reconstruction_node",
        "mosaic_node",
        "telemetry_node",
        "pipeline",
    ],
)
def test_every_node_entry_point_refuses_a_missing_profile_with_one_line(module):
    env = _plain_env(FASTRTPS_DEFAULT_PROFILES_FILE="/nonexistent/p.xml")
    r = subprocess.run(
        [sys.executable, "-m", f"subpix_ros.nodes.{module}"],
        capture_output=True,
        text=True,
        timeout=60,
        env=env,
    )
    assert r.returncode == 2, r.stderr
    assert r.stderr.strip().splitlines() == [
        f"error: FASTRTPS_DEFAULT_PROFILES_FILE=/nonexistent/p.xml {MISSING}"
    ]


def test_subpix_refuses_a_missing_profile_with_one_line():
    env = _plain_env(FASTDDS_DEFAULT_PROFILES_FILE="/nonexistent/p.xml")
    r = subprocess.run(
        [sys.executable, "-m", "subpix_ros.cli", "replay", "x"],
        capture_output=True,
        text=True,
        timeout=60,
        env=env,
    )
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [
        f"subpix replay: error: FASTDDS_DEFAULT_PROFILES_FILE=/nonexistent/p.xml {MISSING}"
    ]


def _new_segments(before, pid):
    """Sizes of the new Fast DDS segments (since ``before``; not port files) ``pid`` maps.

    Mapped by that process: not another process's segment that appeared meanwhile.
    """
    try:
        with open(f"/proc/{pid}/maps") as f:
            mapped = {line.split("/dev/shm/")[1].strip() for line in f if "/dev/shm/" in line}
    except FileNotFoundError:
        return []
    sizes = []
    for n in (set(os.listdir("/dev/shm")) - before) & mapped:
        if n.startswith("fastrtps_") and not n.startswith("fastrtps_port") and "_el" not in n:
            try:
                sizes.append(os.stat(f"/dev/shm/{n}").st_size)
            except FileNotFoundError:
                pass
    return sizes


@pytest.mark.parametrize(
    "command, low, high",
    [
        (["-m", "subpix_ros.nodes.registration_node"], 64 << 20, 80 << 20),  # writes images
        (["-m", "subpix_ros.nodes.shift_node"], 1 << 20, 2 << 20),  # shifts only: the small one
        (
            ["-m", "subpix_ros.cli", "record", "-o", "{tmp}/bag", "/shift"],
            1 << 20,
            2 << 20,
        ),  # reads only
    ],
)
def test_a_node_in_a_plain_venv_loads_the_profile(command, low, high, tmp_path):
    # The process's Fast DDS read FASTRTPS_DEFAULT_PROFILES_FILE: shown by the segment it maps in
    # /dev/shm (64 MiB or 1 MiB, not Fast DDS's 512 KiB), which exists while it runs.
    import time

    before = set(os.listdir("/dev/shm"))
    p = subprocess.Popen(
        [sys.executable, *(c.format(tmp=tmp_path) for c in command)],
        env=_plain_env(),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        sizes = []
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and not sizes:
            time.sleep(0.5)
            sizes = _new_segments(before, p.pid)
        time.sleep(0.5)  # one participant, one segment of its own: no second one later
        sizes = _new_segments(before, p.pid)
        assert len(sizes) == 1 and low <= sizes[0] < high, f"segments of the new process: {sizes}"
    finally:
        p.send_signal(2)
        p.wait(20)


def test_the_venvs_ament_prefix_is_added(tmp_path, monkeypatch):
    # `make venv` indexes the package under <venv>/subpix_prefix: get_package_share_directory finds
    # it in a plain venv once an entry point has run configure_ros_environment.
    from pathlib import Path

    monkeypatch.chdir(tmp_path)
    prefix = Path(sys.prefix) / "subpix_prefix"
    assert (prefix / "share" / "ament_index").is_dir(), "run `make venv`"
    env = {"AMENT_PREFIX_PATH": "/opt/other"}
    configure_ros_environment(env)
    assert env["AMENT_PREFIX_PATH"] == f"{prefix}{os.pathsep}/opt/other"
    configure_ros_environment(env)  # not twice
    assert env["AMENT_PREFIX_PATH"] == f"{prefix}{os.pathsep}/opt/other"


# ---------------------------------------------------------------- stale shared-memory segments
def _pair(d, name, age_s=3600.0, size=4096):
    import os
    import time

    seg, lock = d / name, d / (name + "_el")
    seg.write_bytes(b"\0" * size)
    lock.write_bytes(b"")
    old = time.time() - age_s
    os.utime(seg, (old, old))
    return seg, lock


def test_stale_segments_are_removed_and_live_ones_kept(tmp_path):
    import subprocess
    import sys

    from subpix_ros.runtime import remove_stale_shm_segments

    dead = _pair(tmp_path, "fastrtps_00112233aabbccdd")
    live = _pair(tmp_path, "fastrtps_99887766aabbccdd")
    young = _pair(tmp_path, "fastrtps_0123456789abcdef", age_s=1.0)
    port = _pair(tmp_path, "fastrtps_port7411")
    alone = tmp_path / "fastrtps_fedcba9876543210"  # no lock file: not ours to judge
    alone.write_bytes(b"x")
    holder = subprocess.Popen(  # a "participant" holding its segment's lock
        [
            sys.executable,
            "-c",
            "import fcntl, os, sys, time\n"
            f"fd = os.open({str(live[1])!r}, os.O_RDWR)\n"
            "fcntl.flock(fd, fcntl.LOCK_EX)\nprint('held', flush=True)\ntime.sleep(60)\n",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "held"
        n, freed = remove_stale_shm_segments(tmp_path, min_age_s=60.0)
    finally:
        holder.kill()
        holder.wait()
    assert n == 1 and freed >= 4096
    assert not dead[0].exists() and not dead[1].exists()
    assert all(p.exists() for p in (*live, *young, *port, alone))


def test_a_killed_nodes_segment_is_removed_and_a_live_nodes_kept(tmp_path):
    """Real Fast DDS: a SIGKILLed node leaves its segment; the clean-up removes it, not a live one."""
    import os
    import signal
    import subprocess
    import time
    from pathlib import Path

    from subpix_ros.runtime import remove_stale_shm_segments

    shm = Path("/dev/shm")
    env = dict(os.environ, ROS_DOMAIN_ID=str(200 + os.getpid() % 30), SUBPIX_KEEP_SHM="1")
    exe = str(Path(sys.executable).with_name("shift_node"))

    def owned(pid: int) -> set[str]:
        """Return the Fast DDS segments process ``pid`` owns: it holds the flock on ``<name>_el``.

        (Others may map a segment to write to it; the lock is its owner's alone.)
        """
        holders = {}
        for line in Path("/proc/locks").read_text().splitlines():
            f = line.split()
            if len(f) > 5 and f[1] == "FLOCK":
                holders[int(f[5].rsplit(":", 1)[1])] = int(f[4])
        out = set()
        for n in os.listdir(shm):
            if re.match(r"^fastrtps_[0-9a-f]{16}$", n):
                try:
                    if holders.get(os.stat(shm / (n + "_el")).st_ino) == pid:
                        out.add(n)
                except OSError:
                    pass
        return out

    def start():
        p = subprocess.Popen([exe], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            own = owned(p.pid)
            if own:
                return p, own
            time.sleep(0.2)
        p.kill()
        raise AssertionError("the node made no shared-memory segment in 30 s")

    killed, seg_killed = start()
    live, seg_live = start()
    try:
        seg_killed |= owned(killed.pid)  # any it made after start() returned
        killed.send_signal(signal.SIGKILL)
        killed.wait()
        assert all((shm / n).exists() for n in seg_killed)  # what a killed process leaves behind
        remove_stale_shm_segments(shm, min_age_s=0.0)
        assert not any((shm / n).exists() for n in seg_killed)
        assert all((shm / n).exists() for n in seg_live) and live.poll() is None
    finally:
        live.send_signal(signal.SIGINT)
        try:
            live.wait(10)
        except subprocess.TimeoutExpired:
            live.kill()


def test_plain_venv_environ_is_a_shell_with_only_the_venv_activated(tmp_path):
    from subpix_ros.runtime import plain_venv_environ

    src = {
        "PATH": "/usr/bin",
        "HOME": "/root",
        "ROS_DISTRO": "jazzy",
        "RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp",
        "AMENT_PREFIX_PATH": "/opt/ros/jazzy",
        "FASTRTPS_DEFAULT_PROFILES_FILE": "/x.xml",
        "PYTHONPATH": "/opt/ros/jazzy/lib/python3.12/site-packages",
    }
    env = plain_venv_environ(tmp_path / ".venv", 17, src)
    assert env == {
        "PATH": f"{tmp_path / '.venv' / 'bin'}:/usr/bin",
        "HOME": "/root",
        "VIRTUAL_ENV": str(tmp_path / ".venv"),
        "ROS_DOMAIN_ID": "17",
    }
    assert src["ROS_DISTRO"] == "jazzy"  # the caller's mapping is left alone


def test_an_unknown_allocator_profile_is_refused_loudly(monkeypatch, capsys):
    import subpix_ros.runtime as rt

    monkeypatch.setattr(rt, "keep_freed_memory", lambda: True)  # not this test process's
    monkeypatch.setenv("SUBPIX_MALLOC", "memroy")
    assert rt.configure_allocator() == "reuse"
    assert "not a known allocator profile" in capsys.readouterr().err
    monkeypatch.setenv("SUBPIX_MALLOC", "")
    assert rt.configure_allocator() == "reuse"
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("env, want", [({}, 1), ({"OPENCV_FOR_THREADS_NUM": "2"}, 2)])
def test_node_processes_give_opencv_one_thread_unless_the_operator_chose(env, want):
    """configure_opencv_threads: 1 by default (as run_nodes applies it), the operator's value kept."""
    code = (
        "from subpix_ros.runtime import configure_opencv_threads; import cv2; "
        "n = configure_opencv_threads(); print(n, cv2.getNumThreads())"
    )
    base = {k: v for k, v in os.environ.items() if k != "OPENCV_FOR_THREADS_NUM"}
    out = subprocess.run(
        [sys.executable, "-c", code],
        env={**base, **env},
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split()
    assert out == [str(want), str(want)]


def test_the_stack_dump_goes_to_the_process_stderr_whatever_sys_stderr_is(monkeypatch):
    """``subpix`` called in-process (sys.stderr a capture without a file): no crash."""
    import io

    from subpix_ros.runtime import dump_stacks_on_sigusr1

    monkeypatch.setattr(sys, "stderr", io.StringIO())
    assert dump_stacks_on_sigusr1() is True
    monkeypatch.setattr(sys, "__stderr__", io.StringIO())  # no file descriptor: nothing to print to
    assert dump_stacks_on_sigusr1() is False


TRIM_CHILD = """
import ctypes
from subpix_ros.runtime import configure_allocator
import numpy as np
profile = configure_allocator()

class Info(ctypes.Structure):
    _fields_ = [(n, ctypes.c_size_t) for n in (
        "arena ordblks smblks hblks hblkhd usmblks fsmblks uordblks fordblks keepcost".split())]
libc = ctypes.CDLL("libc.so.6")
libc.mallinfo2.restype = Info
libc.mallinfo2()  # ctypes' own set-up done before the block (nothing allocated above it after)
a = np.ones(40 << 20, np.uint8)  # 40 MiB: from the heap in both profiles (under 64 MiB)
info = libc.mallinfo2()
del a
after = libc.mallinfo2()
# MiB the heap shrank by (its top returned to the kernel), MiB in blocks mapped on their own
print(profile, (info.arena - after.arena) >> 20, info.hblkhd >> 20)
"""


@glibc
@pytest.mark.parametrize("profile,returned", [("memory", True), ("", False)])
def test_memory_profile_returns_a_freed_frame_sized_block_the_reuse_profile_keeps(
    profile, returned
):
    """40 MiB freed at the heap's top: trimmed beyond 16 MiB (memory), kept up to 64 (reuse)."""
    r = _profile_child(TRIM_CHILD, profile)
    name, freed_mib, mapped_mib = r.stdout.split()
    assert name == (profile or "reuse")
    assert int(mapped_mib) < 40, "a frame-sized block from the heap, not mapped: " + r.stdout
    assert (int(freed_mib) >= 30) if returned else (int(freed_mib) < 10), r.stdout


def test_process_load_gives_the_cpu_in_cores_and_the_resident_memory():
    import resource
    import time

    import numpy as np

    from subpix_ros.runtime import ProcessLoad

    load = ProcessLoad()
    w0, c0 = time.monotonic(), time.process_time()
    load.cores()  # from now on
    stop = time.monotonic() + 0.5
    while time.monotonic() < stop:  # one core busy (less of one on a loaded machine)
        pass
    busy = load.cores()
    # against this process's own CPU over the same wall time, whatever else the machine runs
    own = (time.process_time() - c0) / (time.monotonic() - w0)
    assert busy > 0.2 and abs(busy - own) < 0.1, (busy, own)
    time.sleep(0.3)
    assert load.cores() < 0.3  # asleep
    block = np.ones(64 << 20, np.uint8)  # 64 MB resident
    v = load.values()
    assert set(v) == {"process_cpu_cores", "process_rss_mb", "process_rss_peak_mb"}
    rss, peak = float(v["process_rss_mb"]), float(v["process_rss_peak_mb"])
    assert rss >= 64 and peak >= rss - 1
    # the peak is the kernel's, as getrusage counts it (kB on Linux)
    assert abs(peak - resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024) < 16
    del block
