"""Process-level settings of subpix_ros processes (nodes, ``subpix`` commands, benchmarks).

Why: the frames pass through frame-sized numpy/OpenCV temporaries (an 1800x1350
float32 luminance is 9.7 MB, its pyramid and Harris buffers a few MB more).
glibc's allocator serves blocks above its mmap threshold (128 KiB, raised on
the fly up to the size of the largest block freed so far) straight from the
kernel with ``mmap`` and returns them with ``munmap`` when they are freed, and
it gives the top of the heap back to the kernel once more than its trim
threshold is free. So a fresh frame-sized buffer is often new memory, which
the kernel maps in page by page on first touch: measured on this project's
2-core VM, 3300-6300 minor page faults per registered 1800x1350 pair and
97-103 ms per pair (median of all runs), against 0-20 faults and 80-84 ms once
freed blocks stay in the heap and are reused (``benchmarks/bench_registration.py``,
best of 2 runs per pair, median over the pairs: 0.091-0.103 s with
``--default-malloc``, 0.080-0.089 s without). Sub-pixel shift estimation, which reuses its
buffers already, is unchanged (12 ms at 1080p either way).

:func:`keep_freed_memory` sets glibc's mmap threshold to 64 MiB (blocks up to
that size come from the heap: a 4K or a full-resolution Seneca float32 frame
is 33-39 MB; at full resolution the faults per pair drop from 890 to 300)
and the trim threshold to 64 MiB (the process keeps up to that much freed
heap on top for reuse instead of returning it; 32 MiB already gave the whole
gain, 512 MiB only raised the resident memory). Resident memory hardly
changes: in the 10-minute 30 Hz 1080p soak (``benchmarks/soak.py``) the RSS
peaked at 2.10-2.41 GB with it (3 runs) and 2.25 GB without (1 run); the
lowest RSS of each minute (measured in one run with it) came back to
1.44-1.50 GB from the first minute to the eighth (single minutes read up to
1.72 GB), so nothing accumulates. The same runs processed as many frames either way
(5335-5836 against 5585 shifts).

Every node's ``main``, the ``subpix`` command and the benchmarks call it.
It is a no-op where glibc's ``mallopt`` is missing (musl, macOS, Windows),
and an operator's own ``MALLOC_MMAP_THRESHOLD_`` / ``MALLOC_TRIM_THRESHOLD_``
or ``GLIBC_TUNABLES=glibc.malloc.*`` environment settings win, and
``SUBPIX_DEFAULT_MALLOC=1`` opts out: nothing is changed then.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import os
import sys

__all__ = ["keep_freed_memory", "allocator_line", "add_malloc_argument", "MMAP_THRESHOLD", "TRIM_THRESHOLD", "OPT_OUT"]

#: glibc's ``mallopt`` parameter numbers (malloc.h).
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3

#: Blocks up to this size come from the heap (more than a float32 4K frame).
MMAP_THRESHOLD = 64 * 1024 * 1024
#: Freed heap kept for reuse before the top of the heap is returned to the kernel.
TRIM_THRESHOLD = 64 * 1024 * 1024

_ENV = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_")

#: Set to 1 to leave glibc's allocator alone (inherited by child processes, e.g. the nodes a benchmark starts).
OPT_OUT = "SUBPIX_DEFAULT_MALLOC"


def _operator_set() -> bool:
    """True if the environment opts out or sets glibc's malloc thresholds (old variables or the tunables)."""
    return (os.environ.get(OPT_OUT, "") not in ("", "0") or any(os.environ.get(k) for k in _ENV)
            or "glibc.malloc." in os.environ.get("GLIBC_TUNABLES", ""))


def _mallopt():
    """glibc's ``mallopt`` or None."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        fn = libc.mallopt
    except (OSError, AttributeError):
        return None
    fn.argtypes = [ctypes.c_int, ctypes.c_int]
    fn.restype = ctypes.c_int
    return fn


def keep_freed_memory(mmap_threshold: int = MMAP_THRESHOLD, trim_threshold: int = TRIM_THRESHOLD) -> bool:
    """Keep freed frame buffers in the heap for reuse (glibc ``mallopt``); see the module docstring.

    ``mmap_threshold`` / ``trim_threshold`` in bytes. Returns True if both were
    applied, False if this is not glibc, if the operator set glibc's malloc
    tunables in the environment (theirs are kept), or if glibc refused a
    value. Process-wide and harmless to call twice.
    """
    if not (0 < int(mmap_threshold) <= 2**31 - 1 and 0 < int(trim_threshold) <= 2**31 - 1):
        raise ValueError("thresholds must be positive and fit a C int (bytes)")
    if _operator_set():
        return False
    fn = _mallopt()
    if fn is None:
        return False
    mmap_ok = fn(_M_MMAP_THRESHOLD, int(mmap_threshold)) == 1
    trim_ok = fn(_M_TRIM_THRESHOLD, int(trim_threshold)) == 1
    return mmap_ok and trim_ok


def add_malloc_argument(parser, where: str = "") -> None:
    """For benchmarks: the ``--default-malloc`` flag (``where``: which processes it reaches, for the help)."""
    parser.add_argument("--default-malloc", action="store_true",
                        help=f"glibc's default allocator thresholds{where} (subpix_ros.runtime)")


def allocator_line(default_malloc: bool = False) -> str:
    """For benchmarks: apply :func:`keep_freed_memory` (as the nodes and ``subpix`` do) unless
    ``default_malloc``, and return a one-line description of the allocator the timings ran with."""
    if default_malloc:
        os.environ[OPT_OUT] = "1"  # and in the processes this one starts
        return "allocator: glibc defaults (--default-malloc; the nodes and subpix keep freed frame buffers)"
    if keep_freed_memory():
        return (f"allocator: freed frame buffers kept for reuse, as in the nodes and subpix "
                f"(mmap threshold {MMAP_THRESHOLD >> 20} MiB, trim threshold {TRIM_THRESHOLD >> 20} MiB; "
                f"--default-malloc for glibc's defaults)")
    return "allocator: unchanged (not glibc, or SUBPIX_DEFAULT_MALLOC, MALLOC_* or GLIBC_TUNABLES set in the environment)"
