"""The flight report's figures, drawn in a helper process while the flight is still processed.

When the last frame of a flight has been registered, ``subpix process`` (one job) still waits
for the last set's reconstruction and the queued products, with a core mostly idle, and then
draws the report on one thread. The shift trajectory and the registration sections depend only
on tables that are final once every frame is registered and drawn into the mosaic
(``shifts.csv``, ``frames.csv``) and on the references and registration statistics, so a helper
process started with the flight (its matplotlib imported while the frames are read) draws them
from those files in the meantime. The HTML is the one :func:`subpix_ros.process.report.build_report`
draws itself from the same files (the same functions); when the helper is not there or fails,
the report draws them in-process. Each set's sub-pixel offsets figure (its members' shifts,
final when the set is emitted) is drawn there as the set arrives, keyed by what it shows, and
the mosaic section once ``mosaic.png`` is written: the command itself then does not import
matplotlib at all (measured figures: docs/design-notes.md, "The report drawn beside the run").

The helper is ``python -m subpix_ros.process.report_ahead`` reading requests from a pipe (not
a ``multiprocessing`` child, which would run the caller's main script again in a script without
the ``if __name__ == "__main__"`` guard; no fork of a process that holds OpenCV's thread pool).
It ignores SIGINT (the command stops it), ends with its parent or when the pipe closes, and
writes nothing to the terminal.
"""

from __future__ import annotations

import pickle
import subprocess
import sys
import threading
import time
from typing import Any

from subpix_ros.process.report_sections import mosaic_section, offsets_svg, per_frame_sections

__all__ = ["SectionsAhead"]

#: Longest wait for the helper's sections before the report draws them itself (s).
WAIT_S = 60.0


#: What the helper may be asked to draw, by name.
_CALLS = {
    "per_frame_sections": per_frame_sections,
    "offsets_svg": offsets_svg,
    "mosaic_section": mosaic_section,
}


def _start() -> None:
    """Start the helper: end with the parent, leave SIGINT to it, import the plotting now."""
    import signal

    from subpix_ros.runtime import die_with_parent

    die_with_parent()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    from subpix_ros.process.report_html import _plt

    _plt()  # the sections' module (and the products') are imported with this one


def _serve() -> None:
    """Answer ``(id, name, args)`` requests on stdin with ``(id, result or None)`` on stdout."""
    requests, answers = sys.stdin.buffer, sys.stdout.buffer
    sys.stdout = sys.stderr  # whatever a library prints must not go into the pipe
    _start()
    while True:
        try:
            rid, name, args = pickle.load(requests)
        except EOFError:  # the command closed the pipe: done
            return
        try:
            result = _CALLS[name](*args)
        except Exception:  # noqa: BLE001 - the command draws it itself
            result = None
        pickle.dump((rid, result), answers)
        answers.flush()


class SectionsAhead:
    """One helper process for the report figures of the flights of one command.

    :meth:`submit` queues a drawing and returns its id; :meth:`result` waits for it. The
    answers are read as they come (a thread), so the helper never blocks on a full pipe.
    """

    def __init__(self) -> None:
        self._next = 0
        self._answers: dict[int, Any] = {}
        self._cond = threading.Condition()
        try:  # started now: its imports run while the first flight is read
            self._proc: subprocess.Popen | None = subprocess.Popen(
                [sys.executable, "-m", "subpix_ros.process.report_ahead"],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=subprocess.DEVNULL,
            )
        except OSError:
            self._proc = None
            return
        threading.Thread(
            target=self._read, args=(self._proc,), name="subpix-report-ahead", daemon=True
        ).start()

    def _read(self, proc: subprocess.Popen) -> None:
        """Collect the helper's answers until its pipe ends (then mark it gone)."""
        try:
            while True:
                rid, result = pickle.load(proc.stdout)
                with self._cond:
                    self._answers[rid] = result
                    self._cond.notify_all()
        except Exception:  # noqa: BLE001 - EOF, a helper that died or answered garbage
            pass
        with self._cond:
            if self._proc is proc:
                self._proc = None
            self._cond.notify_all()

    def submit(self, name: str, *args) -> int | None:
        """Ask the helper to draw ``name(*args)``; return the request's id (None: no helper)."""
        with self._cond:
            proc = self._proc
            if proc is None:
                return None
            self._next += 1
            rid = self._next
        try:
            pickle.dump((rid, name, args), proc.stdin)
            proc.stdin.flush()
        except (OSError, ValueError, pickle.PicklingError):  # the helper is gone
            self.close()
            return None
        return rid

    def result(self, rid: int | None) -> Any:
        """Return the answer to request ``rid``, or None (the report then draws it itself)."""
        if rid is None:
            return None
        deadline = time.monotonic() + WAIT_S
        with self._cond:
            while rid not in self._answers:
                left = deadline - time.monotonic()
                if self._proc is None or left <= 0:
                    break
                self._cond.wait(left)
            if rid in self._answers:
                return self._answers.pop(rid)
        self.close()  # gone, or hung for WAIT_S
        return None

    def close(self) -> None:
        """Stop the helper (at once: nothing it still does is needed)."""
        with self._cond:
            proc, self._proc = self._proc, None
            self._answers.clear()
            self._cond.notify_all()
        if proc is None:
            return
        try:
            proc.stdin.close()
        except OSError:
            pass
        proc.terminate()
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        proc.stdout.close()  # after the end: the reader thread has met the pipe's end


if __name__ == "__main__":
    _serve()
