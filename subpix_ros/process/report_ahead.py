"""The flight report's per-frame figures, drawn in a helper process while the last set is solved.

When the last frame of a flight has been registered, ``subpix process`` (one job) still waits
for the last set's reconstruction and the queued products, with a core mostly idle, and then
draws the report on one thread. The shift trajectory and the registration sections depend only
on tables that are final once every frame is registered and drawn into the mosaic
(``shifts.csv``, ``frames.csv``) and on the references and registration statistics, so a helper
process started with the flight (its matplotlib imported while the frames are read) draws them
from those files in the meantime. The HTML is the one :func:`subpix_ros.process.report.build_report`
draws itself from the same files (the same functions); when the helper is not there or fails,
the report draws them in-process.

The helper is ``python -m subpix_ros.process.report_ahead`` reading requests from a pipe (not
a ``multiprocessing`` child, which would run the caller's main script again in a script without
the ``if __name__ == "__main__"`` guard; no fork of a process that holds OpenCV's thread pool).
It ignores SIGINT (the command stops it), ends with its parent or when the pipe closes, and
writes nothing to the terminal.
"""

from __future__ import annotations

import pickle
import select
import subprocess
import sys
from pathlib import Path

__all__ = ["SectionsAhead", "per_frame_sections"]

#: Longest wait for the helper's sections before the report draws them itself (s).
WAIT_S = 60.0


def per_frame_sections(
    folder: str | Path, references: list, stages: dict, t0: float | None, has_telemetry: bool
) -> dict[str, str]:
    """Draw the shift trajectory and registration sections from a flight's tables.

    Parameters
    ----------
    folder : str or Path
        The flight's product folder (``shifts.csv`` and ``frames.csv`` written).
    references : list of dict
        ``summary.json``'s ``references``.
    stages : dict
        ``summary.json``'s ``stages`` (the registration's entry is read).
    t0 : float or None
        The first frame's stamp (s): the figures' time origin.
    has_telemetry : bool
        Whether the flight has telemetry samples (the expected shift is drawn).

    Returns
    -------
    dict
        ``{"shifts": html, "registration": html}``.
    """
    from subpix_ros.process.products import read_csv
    from subpix_ros.process.report_sections import _section_registration, _section_shifts

    folder = Path(folder)
    shifts = read_csv(folder / "shifts.csv") if (folder / "shifts.csv").is_file() else []
    frames = read_csv(folder / "frames.csv") if (folder / "frames.csv").is_file() else []
    return {
        "shifts": _section_shifts(shifts, t0, has_telemetry),
        "registration": _section_registration(frames, references, stages, t0),
    }


def _start() -> None:
    """Start the helper: end with the parent, leave SIGINT to it, import the plotting now."""
    import signal

    from subpix_ros.runtime import die_with_parent

    die_with_parent()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    from subpix_ros.process.report_html import _plt

    _plt()
    import subpix_ros.process.products  # noqa: F401
    import subpix_ros.process.report_sections  # noqa: F401


def _serve() -> None:
    """Answer ``(id, args)`` requests on stdin with ``(id, sections or None)`` on stdout."""
    requests, answers = sys.stdin.buffer, sys.stdout.buffer
    sys.stdout = sys.stderr  # whatever a library prints must not go into the pipe
    _start()
    while True:
        try:
            rid, args = pickle.load(requests)
        except EOFError:  # the command closed the pipe: done
            return
        try:
            sections = per_frame_sections(*args)
        except Exception:  # noqa: BLE001 - the command draws them itself
            sections = None
        pickle.dump((rid, sections), answers)
        answers.flush()


class SectionsAhead:
    """One helper process for the per-frame report sections of the flights of one command."""

    def __init__(self) -> None:
        self._next = 0
        try:  # started now: its imports run while the first flight is read
            self._proc: subprocess.Popen | None = subprocess.Popen(
                [sys.executable, "-m", "subpix_ros.process.report_ahead"],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=subprocess.DEVNULL,
            )
        except OSError:
            self._proc = None

    def submit(
        self, folder: Path, references: list, stages: dict, t0: float | None, has_telemetry: bool
    ) -> int | None:
        """Ask for :func:`per_frame_sections`; return the request's id (None: no helper)."""
        if self._proc is None:
            return None
        self._next += 1
        try:
            pickle.dump(
                (self._next, (str(folder), references, stages, t0, has_telemetry)),
                self._proc.stdin,
            )
            self._proc.stdin.flush()
        except (OSError, ValueError, pickle.PicklingError):  # the helper is gone
            self.close()
            return None
        return self._next

    def result(self, rid: int | None) -> dict[str, str] | None:
        """Return the sections of request ``rid``, or None (the report then draws them itself)."""
        if rid is None or self._proc is None:
            return None
        try:
            while True:  # answers to earlier requests (a flight that failed after asking) skipped
                ready, _, _ = select.select([self._proc.stdout], [], [], WAIT_S)
                if not ready:
                    raise TimeoutError
                got, sections = pickle.load(self._proc.stdout)
                if got == rid:
                    return sections
        except Exception:  # noqa: BLE001 - a helper that died, hangs or answers garbage: stop it
            self.close()
            return None

    def close(self) -> None:
        """Stop the helper (at once: nothing it still does is needed)."""
        proc, self._proc = self._proc, None
        if proc is None:
            return
        for pipe in (proc.stdin, proc.stdout):
            try:
                pipe.close()
            except OSError:
                pass
        proc.terminate()
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


if __name__ == "__main__":
    _serve()
