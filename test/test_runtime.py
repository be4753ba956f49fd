"""subpix_ros.runtime: freed frame buffers are reused, not faulted in again for every frame.

Each case runs in a fresh Python process (the allocator settings are process-wide).
"""
import json
import os
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
    e = {k: v for k, v in os.environ.items()
         if not k.startswith("MALLOC_") and k not in ("GLIBC_TUNABLES", "SUBPIX_DEFAULT_MALLOC")}
    e.update(env or {})
    r = subprocess.run([sys.executable, "-c", CHILD, mode], capture_output=True, text=True, timeout=120, env=e)
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
        pytest.fail(f"{kept['faults']:.0f} minor faults per pair with keep_freed_memory "
                    f"(glibc defaults: {default['faults']:.0f})")


@glibc
@pytest.mark.parametrize("env", [{"MALLOC_TRIM_THRESHOLD_": "1000000"}, {"MALLOC_MMAP_THRESHOLD_": "65536"},
                                 {"GLIBC_TUNABLES": "glibc.malloc.trim_threshold=1000000"},
                                 {"SUBPIX_DEFAULT_MALLOC": "1"}])
def test_operator_malloc_settings_are_kept(env):
    assert _child("probe", env)["applied"] is False


@glibc
def test_unrelated_tunables_do_not_block_it():
    assert _child("probe", {"GLIBC_TUNABLES": "glibc.cpu.hwcap_mask=0"})["applied"] is True


@pytest.mark.parametrize("kw", [{"mmap_threshold": 0}, {"trim_threshold": -1}, {"trim_threshold": 2**31}])
def test_bad_thresholds_raise(kw):
    with pytest.raises(ValueError):
        keep_freed_memory(**kw)
