"""ReconstructionStage: sets of shifted, aligned frames to super-resolved images.

A set is the reference frame plus the next ``n_frames - 1`` aligned frames of
that reference that have a shift. An incomplete set (frames dropped or
without a shift) is still used if it has ``min_frames`` or more frames when
the next reference starts, when no input has come for ``flush_after_s``
(:meth:`ReconstructionStage.tick`, wall time, or stream time from a later
stamp), or at the end of the stream (:meth:`ReconstructionStage.flush`).
"""

from __future__ import annotations

import collections
import inspect
import threading
import time
from dataclasses import dataclass, replace

import numpy as np

from subpix_ros.core.blur import BLUR_SIGMA_MAX, BlurCalibration, parse_blur_sigma
from subpix_ros.core.motion import displacement_through_homography, image_velocity
from subpix_ros.core.superres import colour_luminance, reconstruct_within_budget
from subpix_ros.core.superres.luma import lazy_member_luminance, pack_luminance, packed_dtype
from subpix_ros.core.superres.result import NonFiniteImageError
from subpix_ros.core.superres.workspace import Workspace
from subpix_ros.runtime import release_freed_memory
from subpix_ros.stages.base import Stage
from subpix_ros.stages.params import Spec
from subpix_ros.stages.stats import ReconstructionStats
from subpix_ros.stages.types import Aligned, Shift, SuperResolved


def _blur_setting_error(value) -> str | None:
    try:
        parse_blur_sigma(value)
    except ValueError as exc:
        return str(exc)
    return None


PARAMS = (
    Spec("factor", 2, "resolution factor", 2, 4),
    Spec("n_frames", 8, "frames per super-resolved image (the reference included)", 2, 64),
    Spec(
        "min_frames",
        4,
        "an incomplete set (frames dropped or without a shift) is still used if it has "
        "this many frames when the next reference starts",
        2,
        64,
        at_most="n_frames",
    ),
    Spec("method", "map", "reconstruction method", choices=("map", "windowed", "pinv", "bicubic")),
    Spec(
        "prior",
        "powerlaw",
        "image prior of the map method: powerlaw (default) or rolloff (times a Gaussian "
        "roll-off fitted to the frames: up to +7.7 dB on scenes soft in themselves, e.g. haze, "
        "but up to 0.5 dB below powerlaw on sharp ones; never below bicubic in the bench)",
        choices=("powerlaw", "rolloff"),
    ),
    Spec(
        "check_geometry",
        False,
        "re-check inside the reconstruction whether frames differ by more "
        "than a translation (the registration node already warps out rotation and perspective "
        "beyond its threshold)",
    ),
    Spec(
        "refine_shifts",
        False,
        "re-estimate the shifts inside the reconstruction (off: the shift "
        "node's estimates, already at the accuracy limit and screened by its max_std_px, are used "
        "as they are)",
    ),
    Spec(
        "max_memory_mb",
        0.0,
        "working-memory budget of one reconstruction (MB; 0: unbounded): a set that would need "
        "more is reconstructed in tiles, then with fewer frames (not below min_frames), "
        "then as the bicubic reference",
        0.0,
        1.0e6,
    ),
    Spec(
        "pack_members",
        False,
        "hold each waiting member of a colour set as its luminance in 2 bytes per pixel "
        "(uint8 BGR: 3; uint16 BGR: 6), all the reconstruction reads from it: less memory "
        "(config/onboard.yaml) for about 2 ms of CPU per 1080p frame; images within 1 DN",
    ),
    Spec(
        "max_cpu_cores",
        0.0,
        "CPU budget of the reconstruction in cores (0: none): after a set that took c seconds "
        "of CPU, sets whose reference comes less than c / max_cpu_cores seconds of flight "
        "after its reference are skipped (their frames not held), counted in "
        "sets_skipped_budget; fewer images, each as good (live only: subpix process "
        "reconstructs every set)",
        0.0,
        64.0,
    ),
    Spec(
        "release_memory",
        False,
        "after each set, drop the solve's reused buffers and hand the heap's free pages back "
        "to the kernel (glibc malloc_trim): lower resident memory between sets for an onboard "
        "computer, at the cost of page faults in the next set",
    ),
    Spec(
        "blur_sigma",
        "auto",
        "optics blur std of the model, input px: 'auto' (measured on straight edges in the "
        "frames, looked for every blur_search_sets sets until one is found, then refreshed "
        "every 10 sets, biased low; a low fallback until an edge is seen) or a "
        f"number in 0..{BLUR_SIGMA_MAX:g} (a calibration, e.g. from subpix blur; replaced, "
        "with a warning, by the edges' measurement where that is lower by more than "
        "max(0.1 px, 3 standard errors))",
        validate=_blur_setting_error,
        numeric_text=True,
    ),
    Spec(
        "blur_search_sets",
        1,
        "while no straight edge has been measured in the flight (the fallback blur in use), "
        "look for edges in every this many sets (1: every set; each look costs about an eighth "
        "of a set's reconstruction at 1080p, config/onboard.yaml looks every 10th); once one "
        "is found, every 10 sets",
        1,
        1000,
    ),
    Spec(
        "exposure_s",
        0.0,
        "exposure time (s) for the motion blur of the model: the image velocity is fitted to "
        "the set's shifts against their stamps and the blur is exposure x velocity (a box along "
        "the motion); 0: unknown, no motion blur modelled",
        0.0,
        0.1,
    ),
    Spec("time_tolerance_s", 0.001, "shift and frame stamps closer than this match", 0.0, 1.0),
    Spec(
        "flush_after_s",
        2.0,
        "an incomplete set of min_frames or more is reconstructed when no new "
        "frame has come for this long (stream time, or wall time once the stream stops)",
        0.1,
        600.0,
    ),
)


def _fits(ref: np.ndarray, member: Aligned) -> bool:
    """Return True if ``member`` belongs in a set with reference image ``ref`` (same size)."""
    if member.packed:
        return (
            ref.ndim == 3
            and member.image.shape == ref.shape[:2]
            and (member.image.dtype == packed_dtype(ref))
        )
    return member.image.shape == ref.shape and member.image.dtype == ref.dtype


def _packed(member: Aligned) -> Aligned:
    """Return a colour member as its packed luminance, all the reconstruction reads of it.

    The chroma of a super-resolved image is the reference's, so a member is only read as
    luminance: held in 2 bytes per pixel instead of 3 (uint8 BGR; values within 1/512 DN)
    or 6 (uint16 BGR, as float32: the same values). Other members are returned as they are.
    """
    img = member.image
    if img.ndim != 3 or img.dtype not in (np.uint8, np.uint16):
        return member
    return replace(member, image=pack_luminance(img), packed=True)


@dataclass
class FrameSet:
    """A set ready to reconstruct: the reference, its (shift, aligned) members, why it closed.

    :meth:`ReconstructionStage.reconstruct` consumes it: the members are released once solved.
    """

    reference: object  # Frame
    members: list[tuple[Shift, Aligned]]
    complete: bool
    why: str  # "complete", "next reference", "idle", "end of stream"

    @property
    def n_frames(self) -> int:
        """Frames in the set, the reference included."""
        return 1 + len(self.members)


class ShiftFrameMatcher:
    """Pair shifts with aligned frames by stamp (within a tolerance), in any arrival order."""

    KEEP = 64  # unmatched shifts and frames kept, each

    def __init__(self, tolerance_ns: int) -> None:
        self.tolerance_ns = tolerance_ns
        self.frames: dict[int, Aligned] = {}
        self.shifts: list[Shift] = []
        self.frames_dropped = 0  # frames let go after KEEP newer ones, no shift having come

    def add_frame(self, aligned: Aligned) -> list[tuple[Shift, Aligned]]:
        """Take an aligned frame; return the (shift, frame) pairs now matched."""
        self.frames[aligned.stamp_ns] = aligned
        return self._match()

    def add_shift(self, shift: Shift) -> list[tuple[Shift, Aligned]]:
        """Take a shift; return the (shift, frame) pairs now matched."""
        self.shifts.append(shift)
        return self._match()

    def _match(self) -> list[tuple[Shift, Aligned]]:
        """Pair each shift with the nearest frame within tolerance; keep the rest (bounded)."""
        pairs, still = [], []
        for shift in self.shifts:
            stamp = min(self.frames, key=lambda t: abs(t - shift.stamp_ns), default=None)
            if stamp is not None and abs(stamp - shift.stamp_ns) <= self.tolerance_ns:
                aligned = self.frames.pop(stamp)
                shift.reference_stamp_ns = aligned.reference.stamp_ns
                pairs.append((shift, aligned))
            else:
                still.append(shift)
        self.shifts = still[-self.KEEP :]
        if len(self.frames) > self.KEEP:
            for t in sorted(self.frames)[: -self.KEEP]:
                del self.frames[t]
                self.frames_dropped += 1
        return pairs

    def clear(self) -> None:
        """Forget every unmatched shift and frame."""
        self.frames.clear()
        self.shifts.clear()


class ReconstructionStage(Stage):
    """Set assembly, stamp matching and super-resolution, without ROS.

    ``add(shift, aligned)`` returns the images of the sets it completed (or
    cut short: the next reference started); ``add_shift`` / ``add_aligned``
    take the two halves separately and pair them by stamp; ``tick(now_s)``
    reconstructs sets idle for ``flush_after_s``; ``flush()`` every set with
    ``min_frames`` or more at the end of the stream. Parameters not known
    here that the core's ``reconstruct`` takes as keywords (e.g. ``blur_sigma``)
    are passed to it; any other (a node's own) is ignored (``ignored``).

    For a worker thread, :meth:`assemble` (cheap) and :meth:`reconstruct`
    (the solve) can be called separately.
    """

    PARAMS = PARAMS
    STATS = ReconstructionStats
    CLOSED_KEEP = 64  # references whose set was flushed: late members do not start a new set

    def __init__(self, clock=time.monotonic, cpu_clock=time.thread_time, **params) -> None:
        super().__init__(**params)
        self.clock = clock
        self.cpu_clock = cpu_clock  # CPU seconds of the solving thread (max_cpu_cores)
        self._budget_from: tuple[int, int] | None = None  # (last set's reference, next allowed)
        self._budget_skipped: collections.OrderedDict[int, None] = collections.OrderedDict()
        self._told_budget = False
        self.solver_options, self.ignored = _solver_options(self.extra)
        self._told_ignored = False
        self._told_no_trim = False  # release_memory without malloc_trim: said once
        self.blur = self._blur_calibration()
        self._blur_warned = None  # the overriding estimate last warned about
        self.sets: dict[int, list[tuple[Shift, Aligned]]] = {}
        self.matcher = ShiftFrameMatcher(self._tolerance_ns())
        self._closed: collections.OrderedDict[int, None] = collections.OrderedDict()
        self._last_input_wall: float | None = None
        # the solve's large arrays, reused from set to set (none with release_memory)
        self.workspace = Workspace()
        self._workspace_lock = threading.Lock()
        self._last_stamp_in: dict[int, int] = {}  # reference -> its newest member's stamp

    def _blur_calibration(self) -> BlurCalibration:
        """Return a new flight blur calibration for ``blur_sigma`` (a number checked on edges)."""
        return BlurCalibration(
            self.param("blur_sigma"),
            check_given=True,
            search_sets=self.param("blur_search_sets"),
        )

    def _tolerance_ns(self) -> int:
        """Return ``time_tolerance_s`` in ns."""
        return int(self.param("time_tolerance_s") * 1e9)

    def configure(self, **changes) -> None:
        """Change parameters at run time (matching tolerance, blur, solver options follow)."""
        super().configure(**changes)
        if "max_cpu_cores" in changes:
            self._told_budget = False  # a new budget is said again at its first skip
        self.matcher.tolerance_ns = self._tolerance_ns()
        if parse_blur_sigma(self.param("blur_sigma")) != self.blur.setting:
            self.blur = self._blur_calibration()
        self.blur.search_sets = self.param("blur_search_sets")
        self.solver_options, self.ignored = _solver_options(self.extra)

    def reset(self) -> None:
        """Forget every open set and unmatched input."""
        super().reset()
        self.sets.clear()
        self.matcher.clear()
        self._closed.clear()
        self._last_stamp_in.clear()
        self._budget_from = None
        self._budget_skipped.clear()
        self.stats.pending_sets = 0

    # ---------------------------------------------------------------- assembly
    def add_aligned(self, aligned: Aligned) -> list[SuperResolved]:
        """Take an aligned frame whose shift may come before or after it; return the images made."""
        return self._run(self.offer_aligned(aligned))

    def add_shift(self, shift: Shift) -> list[SuperResolved]:
        """Take a shift whose aligned frame may come before or after it (non-finite: rejected)."""
        return self._run(self.offer_shift(shift))

    def add(self, shift: Shift, aligned: Aligned) -> list[SuperResolved]:
        """Take one (shift, aligned frame) pair; return the images of the sets this closes."""
        return self._run(self.assemble(shift, aligned))

    def offer_aligned(self, aligned: Aligned) -> list[FrameSet]:
        """Match and assemble an aligned frame; return the sets it closes (not solved)."""
        return [fs for pair in self.match_aligned(aligned) for fs in self.assemble(*pair)]

    def offer_shift(self, shift: Shift) -> list[FrameSet]:
        """Match and assemble a shift; return the sets it closes (not solved)."""
        return [fs for pair in self.match_shift(shift) for fs in self.assemble(*pair)]

    def match_aligned(self, aligned: Aligned) -> list[tuple[Shift, Aligned]]:
        """Return the (shift, frame) pairs an aligned frame completes (``time_tolerance_s``)."""
        self._last_input_wall = self.clock()
        before = self.matcher.frames_dropped
        pairs = self.matcher.add_frame(aligned)
        lost = self.matcher.frames_dropped - before
        if lost:
            self.stats.frames_without_shift += lost
            self.warn(
                f"{self.stats.frames_without_shift} aligned frame(s) left without a shift so far "
                f"(each let go after {self.matcher.KEEP} newer ones): is the shift stage running "
                "and its shifts arriving? (it also leaves out shifts above max_std_px)"
            )
        return pairs

    def match_shift(self, shift: Shift) -> list[tuple[Shift, Aligned]]:
        """Return the (shift, frame) pairs a shift completes; a non-finite one is an error."""
        self._last_input_wall = self.clock()
        if not (np.isfinite(shift.u) and np.isfinite(shift.v)):
            self.error("shift message with non-finite u/v ignored")
            return []
        return self.matcher.add_shift(shift)

    def assemble(self, shift: Shift, aligned: Aligned) -> list[FrameSet]:
        """Add a pair to its reference's set: the sets this closes (the solve not done yet)."""
        self.stats.frames_in += 1
        self._last_input_wall = self.clock()
        self.check_time(shift.stamp_ns)
        key = aligned.reference.stamp_ns
        if key in self._closed:  # its set was flushed incomplete: no second image of the rest
            self.stats.skip("late")
            self.warn(
                f"frame {shift.stamp_ns / 1e9:.3f} s came after the incomplete set of reference "
                f"{key / 1e9:.3f} s was flushed: skipped"
            )
            return []
        ready = []
        # a newer reference started: older sets can no longer grow (frames were dropped or had no
        # shift); reconstruct one that still has min_frames, else say why it is dropped
        for old in sorted(k for k in self.sets if k < key):
            ready += self._close(old, "next reference")
        if key not in self.sets and self._over_budget(key):
            self.stats.skip("cpu_budget")  # by design (max_cpu_cores), not a drop
            return ready
        members = self.sets.setdefault(key, [])
        if self.param("pack_members") and _fits(aligned.reference.image, aligned):
            aligned = _packed(aligned)
        members.append((shift, aligned))
        self._last_stamp_in[key] = max(shift.stamp_ns, self._last_stamp_in.get(key, shift.stamp_ns))
        if len(members) + 1 >= self.param("n_frames"):
            ready += self._close(key, "complete")
        self.stats.pending_sets = len(self.sets)
        return ready

    def _over_budget(self, key: int) -> bool:
        """Return True if the set of reference ``key`` is skipped for ``max_cpu_cores``.

        The decision is taken at the set's first member and kept for its later ones.
        """
        if key in self._budget_skipped:
            return True
        cores = self.param("max_cpu_cores")
        if not cores > 0.0 or self._budget_from is None or key >= self._budget_from[1]:
            return False
        self._budget_skipped[key] = None
        while len(self._budget_skipped) > self.CLOSED_KEEP:
            self._budget_skipped.popitem(last=False)
        self.stats.sets_skipped_budget += 1
        if not self._told_budget:  # said once; then counted in sets_skipped_budget
            self._told_budget = True
            last = self.stats.set_cpu_time_s or 0.0
            self.warn(
                f"max_cpu_cores {cores:g}: sets skipped to keep the reconstruction within its "
                f"CPU budget (the last set took {last:.2f} s of CPU: one set "
                f"per {last / cores:.1f} s of flight)"
            )
        return True

    def _budget_after(self, key: int) -> None:
        """Start the ``max_cpu_cores`` pause after the set of reference ``key`` (the last CPU)."""
        cores = self.param("max_cpu_cores")
        last = self.stats.set_cpu_time_s
        if cores > 0.0 and last is not None:
            if self._budget_from is None or key >= self._budget_from[0]:
                self._budget_from = (key, key + int(last / cores * 1e9))

    def _close(self, key: int, why: str) -> list[FrameSet]:
        members = self.sets.pop(key)
        self._last_stamp_in.pop(key, None)
        if why in ("idle", "end of stream"):
            self._closed[key] = None
            while len(self._closed) > self.CLOSED_KEEP:
                self._closed.popitem(last=False)
        self.stats.pending_sets = len(self.sets)
        n = len(members) + 1
        complete = n >= self.param("n_frames")
        if not complete and n < self.param("min_frames"):
            self.stats.sets_dropped += 1
            self.stats.dropped += len(members)
            self.warn(
                f"set of reference {key / 1e9:.3f} s dropped: {n} frames "
                f"< min_frames {self.param('min_frames')}"
            )
            return []
        self._budget_after(key)  # with the last set's CPU until this one's is measured
        if complete:
            self.stats.sets_complete += 1
        else:
            self.stats.sets_incomplete += 1
            if why in ("idle", "end of stream"):
                self.stats.sets_flushed += 1
        return [FrameSet(members[0][1].reference, members, complete, why)]

    def idle_sets(
        self, now_s: float | None = None, *, stamp_ns: int | None = None
    ) -> list[FrameSet]:
        """Close the sets no input has come to for ``flush_after_s``.

        Wall time: ``now_s`` (the stage's ``clock``, default ``time.monotonic``,
        read when neither argument is given) against the last input's
        arrival; stream time: ``stamp_ns`` (a later frame's stamp) against
        each set's newest member. A set below ``min_frames`` stays open (it
        may still grow, or the next reference drops it).
        """
        wait = self.param("flush_after_s")
        if now_s is None and stamp_ns is None:
            now_s = self.clock()
        wall_idle = (
            now_s is not None
            and self._last_input_wall is not None
            and now_s - self._last_input_wall >= wait
        )
        ready = []
        for key in sorted(self.sets):
            stream_idle = stamp_ns is not None and stamp_ns - self._last_stamp_in[key] >= wait * 1e9
            if (wall_idle or stream_idle) and len(self.sets[key]) + 1 >= self.param("min_frames"):
                ready += self._close(key, "idle")
        return ready

    def tick(
        self, now_s: float | None = None, *, stamp_ns: int | None = None
    ) -> list[SuperResolved]:
        """Reconstruct the sets idle for ``flush_after_s`` (:meth:`idle_sets`); return images."""
        return self._run(self.idle_sets(now_s, stamp_ns=stamp_ns))

    def flush_sets(self) -> list[FrameSet]:
        """End of stream: close every open set (below ``min_frames``: dropped, with a warning)."""
        ready = []
        for key in sorted(self.sets):
            ready += self._close(key, "end of stream")
        return ready

    def flush(self) -> list[SuperResolved]:
        """End of stream: reconstruct every open set with ``min_frames`` or more."""
        return self._run(self.flush_sets())

    def _run(self, sets: list[FrameSet]) -> list[SuperResolved]:
        """Reconstruct sets; return the images made."""
        return [sr for sr in map(self.reconstruct, sets) if sr is not None]

    # ---------------------------------------------------------------- solve
    def reconstruct(self, fs: FrameSet) -> SuperResolved | None:
        """Super-resolve one set (None, with an error, when it cannot be); consumes ``fs``.

        ``fs.members`` is emptied: the frames are released before the image is published (the
        image carries the members' shifts). The solve's largest arrays (frame spectra,
        luminance, HR spectrum) stay in ``self.workspace`` for the next set: no fresh pages to
        map in and zero each time (``stats.workspace_mb`` says how much is held). With
        ``release_memory`` nothing is kept and the heap's free pages go back to the kernel
        afterwards (:func:`subpix_ros.runtime.release_freed_memory`; ``stats.released_mb``).
        The CPU of the call (``cpu_clock``) is ``stats.set_cpu_time_s``, what ``max_cpu_cores``
        pays for.
        """
        release = bool(self.param("release_memory"))
        # one set at a time uses the workspace (a concurrent call, if any, allocates its own)
        owned = not release and self._workspace_lock.acquire(blocking=False)
        cpu0 = self.cpu_clock()
        try:
            return self._reconstruct_set(fs, self.workspace if owned else None)
        finally:
            # the set is consumed: its members' frames go now, not after the image is published
            # (a set of 8 at 4K holds 133 MB packed; the caller's FrameSet outlives the solve)
            fs.members = []
            self.stats.set_cpu_time_s = self.cpu_clock() - cpu0
            self._budget_after(fs.reference.stamp_ns)
            if owned:
                self._workspace_lock.release()
            if release:
                self.workspace.clear()  # buffers of sets before release_memory was turned on
            self.stats.workspace_mb = round(self.workspace.nbytes / 2**20, 1)
            if release:
                self.stats.released_mb = release_freed_memory()
                if self.stats.released_mb is None and not self._told_no_trim:
                    self._told_no_trim = True
                    self.warn("release_memory: no glibc malloc_trim here, nothing is released")

    def _reconstruct_set(self, fs: FrameSet, ws: Workspace | None) -> SuperResolved | None:
        """Super-resolve one set: the body of :meth:`reconstruct` (``ws``: buffers to reuse)."""
        ref, members = fs.reference, fs.members
        if self.ignored and not self._told_ignored:
            self._told_ignored = True
            self.warn(
                f"parameters not used by the reconstruction: {', '.join(sorted(self.ignored))}"
            )
        t0 = time.monotonic()
        frames = [ref.image] + [a.image for _, a in members]
        shape = ref.image.shape[:2]
        masks, boxes = None, None
        if all(a.mask is None for _, a in members):  # rectangles (integer crops): no masks made
            boxes = [(0, shape[0], 0, shape[1])] + [a.box for _, a in members]
        else:
            masks = [np.ones(shape, bool)] + [a.valid_mask() for _, a in members]
        shifts = np.array([[0.0, 0.0]] + [[s.u, s.v] for s, _ in members])
        if any(not _fits(ref.image, a) for _, a in members):
            self.error("frames of one set differ in size or type: set dropped")
            return None
        # luminance only for a set the calibration measures (BlurCalibration.due)
        mono = []
        if self.blur.due:  # frame 0 whole (the edge search); the others where the edges are
            mono = [colour_luminance(frames[0])] + [
                lazy_member_luminance(a.image, a.packed) for _, a in members
            ]
        motion = set_motion_blur(fs, self.param("exposure_s"))
        if motion is None and self.param("exposure_s") > 0.0:
            self.warn(
                "exposure_s is set but the set's image velocity could not be fitted (fewer "
                "than 2 distinct stamps): no motion blur modelled for this set"
            )
        blur = self.blur.update(mono, shifts, masks, motion, boxes=boxes)
        if self.blur.setting != "auto" and blur.source == "edges" and blur is not self._blur_warned:
            self._blur_warned = blur
            self.warn(blur.reason)
        dtype = np.uint16 if ref.image.dtype == np.uint16 else np.uint8
        try:  # rounded into the output type tile by tile: the float image never whole
            res, plan = reconstruct_within_budget(
                frames,
                shifts,
                self.param("factor"),
                masks=masks,
                boxes=boxes,
                max_memory_mb=self.param("max_memory_mb") or None,
                min_frames=min(self.param("min_frames"), len(frames)),
                method=self.param("method"),
                prior=self.param("prior"),
                geometry="auto" if self.param("check_geometry") else "translation",
                refine_shifts=self.param("refine_shifts"),
                blur_sigma=blur,
                motion_blur=motion,
                out_dtype=dtype,
                workspace=ws,
                **self.solver_options,
            )
        except NonFiniteImageError:
            self.error("reconstruction produced non-finite pixels: not published")
            return None
        out = res.image  # the result holds the published image, not a float copy of it
        dt = time.monotonic() - t0
        st = self.stats
        st.kept += 1
        st.times.add(1000 * dt)
        st.method, st.fell_back, st.fallback_reason = res.method, res.fell_back, res.reason
        st.noise_sigma, st.frames = float(res.noise_sigma), plan.n_frames
        st.memory_estimate_mb = round(plan.estimate_mb, 1)
        st.motion_blur_px = (
            None if motion is None else tuple(round(float(x), 4) for x in res.motion_blur)
        )
        st.memory_reduction = ", ".join(plan.reductions)
        if plan.reduced:
            st.memory_reduced += 1
        if res.shifts_disputed:
            st.shifts_disputed += res.shifts_disputed
            self.warn(f"shift estimates disputed by the frames: {res.reason}")
        if res.fell_back:
            st.fallbacks += 1
            self.warn(f"super-resolution fell back to {res.method}: {res.reason}")
        blur = getattr(res, "blur_sigma", None)
        return SuperResolved(
            out,
            ref,
            [sh for sh, _ in members],
            res.method,
            res.fell_back,
            res.reason,
            self.param("factor"),
            None if blur is None else float(blur),
            getattr(res, "blur_source", None),
            dt,
            fs.complete,
            float(res.noise_sigma),
            res,
        )


_SET_HERE = {
    "method",
    "prior",
    "masks",
    "geometry",
    "refine_shifts",
    "blur_sigma",
    "motion_blur",
    "out_dtype",
    "workspace",
}  # given by the stage itself


def member_displacement(shift: Shift, aligned: Aligned) -> tuple[float, float]:
    """Return a member's displacement against its reference in its original frame (LR px).

    :func:`~subpix_ros.core.motion.displacement_through_homography` of the aligned frame's
    homography and its shift.
    """
    return displacement_through_homography(
        aligned.homography, aligned.image.shape[:2], shift.u, shift.v
    )


def set_motion_blur(fs: FrameSet, exposure_s: float) -> tuple[float, float] | None:
    """Return the motion blur of a set, exposure x fitted image velocity (LR px), or None.

    Parameters
    ----------
    fs : FrameSet
        The set: the reference (displacement 0 at its stamp) and its members, whose
        displacements (:func:`member_displacement`) are fitted against their stamps
        (:func:`~subpix_ros.core.motion.image_velocity`).
    exposure_s : float
        Exposure time (s); 0 = unknown.

    Returns
    -------
    (float, float) or None
        ``(du, dv) = exposure_s (vu, vv)`` (LR px, rows and cols; the sign does not matter:
        the box is centred); None when the exposure is 0 or the velocity cannot be fitted.
    """
    if exposure_s <= 0.0:
        return None
    stamps = [fs.reference.stamp_ns] + [s.stamp_ns for s, _ in fs.members]
    pos = [(0.0, 0.0)] + [member_displacement(s, a) for s, a in fs.members]
    vel = image_velocity(np.array(stamps, dtype=np.float64) * 1e-9, np.array(pos))
    if vel is None:
        return None
    return (exposure_s * vel[0], exposure_s * vel[1])


def solver_option_names() -> frozenset[str]:
    """Return the names of the core solver's options a ``reconstruction_node`` parameter sets.

    Returns
    -------
    frozenset of str
        The keyword-only arguments of the core's solver
        (:func:`~subpix_ros.core.superres.reconstruct` and the ones it passes on, e.g. ``reg``,
        ``noise_sigma``, ``pixel_fill``), without those the stage sets itself.

    Notes
    -----
    The stage passes such a parameter, not one of its own, to the solver; ``subpix process``
    accepts them in a params file's ``reconstruction_node`` section for that reason.
    """
    from subpix_ros.core import superres

    taken: set[str] = set()
    for fn in (superres.reconstruct, superres._reconstruct):
        taken |= {
            k
            for k, arg in inspect.signature(fn).parameters.items()
            if arg.kind is inspect.Parameter.KEYWORD_ONLY
        }
    return frozenset(taken - _SET_HERE)


def _solver_options(extra: dict) -> tuple[dict, dict]:
    """``(options, ignored)``: the parameters not known here that the solver takes, and the rest.

    Options the core's solver accepts (:func:`solver_option_names`) go to it; any other key
    (a node's own parameter) is ignored.
    """
    taken = solver_option_names()
    return (
        {k: v for k, v in extra.items() if k in taken},
        {k: v for k, v in extra.items() if k not in taken},
    )
