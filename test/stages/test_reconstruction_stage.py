"""ReconstructionStage policy without ROS: set assembly, stamp matching, flushes, time jumps."""

import dataclasses
import gc
import itertools
import weakref

import numpy as np
import pytest
from conftest import SET_SHIFTS, degraded_flight, rendered_set

from subpix_ros.core.evaluate import gain_over_bicubic
from subpix_ros.core.superres import estimate_peak_mb
from subpix_ros.data import load_crop
from subpix_ros.runtime import release_freed_memory
from subpix_ros.stages import Aligned, Frame, ReconstructionStage, Shift

T0 = 5_000_000_000
DT = 100_000_000


@pytest.fixture(scope="module")
def seq():
    """Eight frames of a real crop rendered at known sub-pixel shifts (factor 2, 40 dB)."""
    return rendered_set(load_crop("crop_trees"))


def _set(seq, ref_k=0, t0=T0, n=None, jitter_ns=0):
    """Return (reference Frame, [(Shift, Aligned)]) of the rendered frames, reference at ``t0``."""
    n = len(SET_SHIFTS) if n is None else n
    ref = Frame(t0, seq.frames[ref_k])
    pairs = []
    for k in range(1, n):
        stamp = t0 + k * DT
        a = Aligned(stamp, seq.frames[k], np.ones(seq.frames[k].shape, bool), ref, np.eye(3))
        u, v = seq.shifts[k] - seq.shifts[ref_k]
        pairs.append((Shift(stamp + jitter_ns, -1, float(u), float(v), 0.0, 0.01, 0.01), a))
    return ref, pairs


class Clock:
    """A settable clock for the stage's wall-time idle flush."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_a_complete_set_gives_an_image_better_than_bicubic(seq):
    stage = ReconstructionStage(n_frames=8)
    ref, pairs = _set(seq)
    out = [stage.add(s, a) for s, a in pairs]
    assert [len(o) for o in out] == [0] * 6 + [1]
    sr = out[-1][0]
    assert sr.complete and sr.n_frames == 8 and sr.stamp_ns == T0 and sr.method.startswith("map")
    assert (
        sr.image.shape == (2 * ref.image.shape[0], 2 * ref.image.shape[1])
        and sr.image.dtype == np.uint8
    )
    assert sr.bicubic.shape == sr.image.shape
    p_sr, p_bic = gain_over_bicubic(sr.image, ref.image, seq.truth, 2, border=16)
    assert p_sr - p_bic > 1.0, (p_sr, p_bic)
    assert stage.stats.sets_complete == 1 and stage.stats.kept == 1 and not stage.sets


def test_the_next_reference_closes_an_incomplete_set_or_drops_it_below_min_frames(seq):
    problems = []
    stage = ReconstructionStage(n_frames=8, min_frames=4, method="bicubic")
    stage.on_problem = lambda level, msg: problems.append(msg)
    _, pairs = _set(seq, n=5)  # 4 aligned frames: 5 with the reference
    assert all(stage.add(s, a) == [] for s, a in pairs)
    _, later = _set(seq, t0=T0 + 10 * DT, n=3)
    out = stage.add(*later[0])
    assert len(out) == 1 and not out[0].complete and out[0].n_frames == 5 and out[0].stamp_ns == T0
    stage.add(*later[1])  # a set of 3 frames (< min_frames): the next reference drops it, said so
    _, third = _set(seq, t0=T0 + 20 * DT, n=2)
    assert stage.add(*third[0]) == []
    assert stage.stats.sets_dropped == 1 and any(
        "dropped: 3 frames < min_frames 4" in m for m in problems
    )
    assert stage.stats.sets_incomplete == 1


def test_end_of_stream_flush(seq):
    stage = ReconstructionStage(n_frames=8, min_frames=4, method="bicubic")
    _, pairs = _set(seq, n=7)  # the 8-frame flight with one frame lost
    assert all(stage.add(s, a) == [] for s, a in pairs)
    out = stage.flush()
    assert len(out) == 1 and out[0].n_frames == 7 and not out[0].complete
    assert stage.stats.sets_flushed == 1 and stage.flush() == []
    # a set below min_frames is not flushed: dropped with a reason
    _, few = _set(seq, t0=T0 + 50 * DT, n=3)
    for s, a in few:
        stage.add(s, a)
    assert stage.flush() == [] and stage.stats.sets_dropped == 1


def test_idle_flush_after_flush_after_s_of_wall_time(seq):
    clock = Clock()
    stage = ReconstructionStage(
        n_frames=8, min_frames=4, method="bicubic", flush_after_s=2.0, clock=clock
    )
    _, pairs = _set(seq, n=7)
    for s, a in pairs:
        stage.add(s, a)
        clock.now += 0.1
    clock.now += 1.5  # 1.6 s since the last frame
    assert stage.tick() == []
    clock.now += 0.5
    out = stage.tick()
    assert len(out) == 1 and out[0].n_frames == 7 and not out[0].complete
    assert stage.tick() == [] and stage.stats.sets_flushed == 1
    # a frame of that reference arriving after the flush makes no second image of the rest
    late = Aligned(
        T0 + 9 * DT,
        seq.frames[1],
        np.ones(seq.frames[1].shape, bool),
        pairs[0][1].reference,
        np.eye(3),
    )
    assert stage.add(Shift(late.stamp_ns, -1, 0.5, 0.0, 0.0, 0.01, 0.01), late) == []
    assert stage.stats.skipped_by_reason == {"late": 1} and not stage.sets


def test_idle_flush_on_stream_time_and_a_small_set_waits(seq):
    stage = ReconstructionStage(n_frames=8, min_frames=4, method="bicubic", flush_after_s=2.0)
    _, pairs = _set(seq, n=3)  # 3 frames < min_frames: stays open, may still grow
    for s, a in pairs:
        stage.add(s, a)
    last = pairs[-1][0].stamp_ns
    assert stage.tick(stamp_ns=last + 3_000_000_000) == [] and stage.sets
    _, more = _set(seq, n=6)
    for s, a in more[2:]:
        stage.add(s, a)
    last = more[-1][0].stamp_ns
    assert stage.tick(stamp_ns=last + 1_900_000_000) == []
    out = stage.tick(stamp_ns=last + 2_000_000_000)
    assert len(out) == 1 and out[0].n_frames == 6


def test_time_jumping_back_forgets_the_open_sets(seq):
    problems = []
    stage = ReconstructionStage(n_frames=8, min_frames=4, method="bicubic")
    stage.on_problem = lambda level, msg: problems.append(msg)
    _, pairs = _set(seq, t0=T0 + 100 * DT, n=6)
    for s, a in pairs:
        stage.add(s, a)
    _, again = _set(seq, n=8)  # the bag from its start: earlier stamps
    out = [o for s, a in again for o in stage.add(s, a)]
    assert (
        len(out) == 1 and out[0].stamp_ns == T0 and out[0].n_frames == 8
    )  # the old set is not mixed in
    assert stage.stats.resets == 1 and any("time jumped back" in m for m in problems)
    assert stage.flush() == []


def test_shifts_and_frames_pair_by_stamp_in_any_arrival_order(seq):
    """Shifts and aligned frames interleaved every way give the same set and image.

    Shifts are stamped within time_tolerance_s of their frame; each stream keeps its own order
    (one topic each).
    """
    _, pairs = _set(seq, n=5, jitter_ns=300_000)  # 0.3 ms off: within the 1 ms tolerance
    images = []
    # every interleaving of the 4 shifts and the 4 frames: where the shifts go among 8 arrivals
    orders = list(itertools.combinations(range(8), 4))
    assert len(orders) == 70
    for shift_slots in orders:
        stage = ReconstructionStage(n_frames=5, method="map")
        shifts, frames = iter(s for s, _ in pairs), iter(a for _, a in pairs)
        out = []
        for slot in range(8):
            out += (
                stage.add_shift(next(shifts))
                if slot in shift_slots
                else stage.add_aligned(next(frames))
            )
        assert len(out) == 1, shift_slots
        assert sorted(s.stamp_ns for s in out[0].shifts) == [s.stamp_ns for s, _ in pairs]
        assert all(s.reference_stamp_ns == T0 for s in out[0].shifts)
        images.append(out[0].image)
    assert all(np.array_equal(images[0], im) for im in images[1:])


def test_stamps_beyond_the_tolerance_do_not_pair_and_non_finite_shifts_are_rejected(seq):
    stage = ReconstructionStage(n_frames=3, min_frames=3, method="bicubic")
    _, pairs = _set(seq, n=3, jitter_ns=2_000_000)  # 2 ms: beyond 1 ms
    for s, a in pairs:
        assert stage.add_aligned(a) == [] and stage.add_shift(s) == []
    assert stage.stats.frames_in == 0
    bad = Shift(pairs[0][1].stamp_ns, -1, float("nan"), 0.0, 0.0, 0.0, 0.0)
    assert stage.add_shift(bad) == [] and stage.stats.errors == 1


def test_aligned_frames_no_shift_comes_for_are_counted_and_said(seq):
    """Frames whose shifts never come (the shift stage stopped) are not dropped silently."""
    stage = ReconstructionStage(n_frames=3, method="bicubic")
    said = []
    stage.on_problem = lambda level, text: said.append(text)
    ref = Frame(T0, seq.frames[0])
    keep = 64  # the matcher holds this many frames waiting for their shifts
    for k in range(1, keep + 4):
        img = seq.frames[1]
        stage.add_aligned(Aligned(T0 + k * DT, img, np.ones(img.shape, bool), ref, np.eye(3)))
    assert stage.stats.frames_without_shift == 3 and stage.stats.frames_in == 0
    assert said and said[-1].startswith("3 aligned frame(s) left without a shift so far")


def test_solver_options_go_to_the_reconstruction_and_other_keys_are_ignored(seq):
    stage = ReconstructionStage(n_frames=4, method="map", queue_size=5, reg=8.0, other=1)
    assert stage.solver_options == {"reg": 8.0} and stage.ignored == {"other": 1}
    plain = ReconstructionStage(n_frames=4, method="map")  # reg 1.0, the core's default
    _, pairs = _set(seq, n=4)
    a = [sr for s, al in pairs for sr in stage.add(s, al)]
    b = [sr for s, al in pairs for sr in plain.add(s, al)]
    assert len(a) == len(b) == 1 and not np.array_equal(a[0].image, b[0].image)
    assert stage.stats.last_warning == "parameters not used by the reconstruction: other"


def test_the_prior_is_a_checked_parameter_and_reaches_the_solve(seq, monkeypatch):
    from subpix_ros.stages import reconstruction as stage_mod

    with pytest.raises(ValueError, match="prior"):
        ReconstructionStage(prior="gaussian")
    seen = []
    real = stage_mod.reconstruct_within_budget

    def spy(*a, **kw):
        seen.append(kw.get("prior"))
        return real(*a, **kw)

    monkeypatch.setattr(stage_mod, "reconstruct_within_budget", spy)
    images = []
    for prior in ("rolloff", "powerlaw"):
        stage = ReconstructionStage(n_frames=4, prior=prior)
        _, pairs = _set(seq, n=4)
        (sr,) = [sr for s, al in pairs for sr in stage.add(s, al)]
        assert sr.method.startswith("map") and not sr.fell_back
        images.append(sr.image)
    assert seen == ["rolloff", "powerlaw"] and not np.array_equal(*images)


def test_blur_sigma_is_a_checked_parameter_and_reaches_the_result(seq):
    with pytest.raises(ValueError, match="blur_sigma"):
        ReconstructionStage(blur_sigma="blurry")
    stage = ReconstructionStage(n_frames=4, method="map", blur_sigma="0.3")
    _, pairs = _set(seq, n=4)
    (sr,) = [sr for s, al in pairs for sr in stage.add(s, al)]
    assert sr.blur_sigma == 0.3 and sr.blur_source == "parameter"
    stage.configure(blur_sigma="auto")
    _, pairs = _set(seq, t0=T0 + 10 * DT, n=4)
    (sr,) = [sr for s, al in pairs for sr in stage.add(s, al)]
    assert sr.blur_source in ("edges", "fallback") and sr.blur_sigma <= 0.45
    assert sr.result.pixel_fill == stage.blur.current.fill_factor  # the calibration's fill


def test_a_given_pixel_fill_is_a_solver_option(seq):
    stage = ReconstructionStage(n_frames=4, method="map", pixel_fill=0.85)
    assert stage.solver_options == {"pixel_fill": 0.85}
    _, pairs = _set(seq, n=4)
    (sr,) = [sr for s, al in pairs for sr in stage.add(s, al)]
    assert sr.result.pixel_fill == 0.85


def test_uint16_frames_give_a_uint16_image(seq):
    stage = ReconstructionStage(n_frames=4, method="bicubic")
    ref = Frame(T0, seq.frames[0].astype(np.uint16) * 200)
    out = []
    for k in range(1, 4):
        a = Aligned(
            T0 + k * DT,
            seq.frames[k].astype(np.uint16) * 200,
            np.ones(seq.frames[k].shape, bool),
            ref,
            np.eye(3),
        )
        out += stage.add(Shift(a.stamp_ns, -1, *map(float, seq.shifts[k]), 0.0, 0.01, 0.01), a)
    assert out[0].image.dtype == np.uint16 and out[0].image.max() > 255


def test_max_memory_mb_tiles_or_drops_frames_and_says_so(seq):
    """A small max_memory_mb still gives an image, with what was reduced in the stats."""
    ref, pairs = _set(seq)
    whole = ReconstructionStage(n_frames=8)
    (full,) = [o for s, a in pairs for o in whole.add(s, a)]
    assert whole.stats.memory_reduction == "" and whole.stats.memory_reduced == 0
    # 256x256 frames (less than two 128 px tiles): the budget is met with fewer frames
    budget = estimate_peak_mb(5, seq.frames[0].shape, 2, colour=False)
    assert budget < whole.stats.memory_estimate_mb
    stage = ReconstructionStage(n_frames=8, min_frames=4, max_memory_mb=budget)
    (sr,) = [o for s, a in pairs for o in stage.add(s, a)]
    st = stage.stats
    assert sr.image.shape == full.image.shape and sr.image.dtype == np.uint8
    assert st.frames == 5 and st.memory_reduction == "5 of 8 frames" and st.memory_reduced == 1
    assert st.memory_estimate_mb <= budget + 0.05  # (rounded to 0.1 MB in the stats)
    assert not sr.fell_back
    p_sr, p_bic = gain_over_bicubic(sr.image, seq.frames[0], seq.truth, 2, 8)
    assert p_sr - p_bic > 1.0  # fewer frames, still super-resolved
    # nothing fits: the bicubic reference, reported as a fallback with the reason
    tiny = ReconstructionStage(n_frames=8, max_memory_mb=1.0)
    (sb,) = [o for s, a in pairs for o in tiny.add(s, a)]
    assert sb.fell_back and "bicubic" in sb.reason and tiny.stats.fallbacks == 1
    with pytest.raises(ValueError):
        ReconstructionStage(max_memory_mb=-1.0)


def test_a_wrong_shift_is_disputed_replaced_and_reported(seq):
    """One shift off by 0.15 px: the image matches the right shifts', the stage warns."""
    images, stats = [], []
    for wrong in (False, True):
        stage = ReconstructionStage(n_frames=8)
        problems = []
        stage.on_problem = lambda level, msg, problems=problems: problems.append((level, msg))
        ref, pairs = _set(seq)
        if wrong:
            s, a = pairs[3]
            pairs[3] = (dataclasses.replace(s, u=s.u + 0.15), a)
        out = [o for s, a in pairs for o in stage.add(s, a)]
        images.append(out[0].image.astype(np.float64))
        stats.append((stage.stats.shifts_disputed, problems))
    assert stats[0] == (0, [])
    assert stats[1][0] == 1
    assert any(lvl == "warn" and "disputed" in m and "frames 4 " in m for lvl, m in stats[1][1])
    p_right, _ = gain_over_bicubic(images[0], ref.image, seq.truth, 2, border=16)
    p_fixed, _ = gain_over_bicubic(images[1], ref.image, seq.truth, 2, border=16)
    assert abs(p_fixed - p_right) < 0.3, (p_fixed, p_right)


# ------------------------------------------------------------------ motion blur (issue 17)


def _moving_set(exposure_s, velocity=(13.0, 9.0), dt_ns=DT):
    """Render 8 frames of a scene moving at ``velocity`` (LR px/s), each exposed ``exposure_s``.

    Frames from the independent degradation model (optics 0.3 px, motion blur = exposure x
    velocity), the shifts the true displacements (up to 9 px: the frames are not warped, the
    homographies are the identity); returns (stage inputs, flight).
    """
    from benchmarks.degrade_independent import degrade, scene_crop

    t = np.arange(8) * dt_ns * 1e-9
    disp = np.outer(t, velocity)
    blur = (exposure_s * velocity[0], exposure_s * velocity[1])
    sc = scene_crop(load_crop("crop_road"), 2, 96, 14, (240, 240))
    fl = degrade(sc, 2, disp, 0.3, snr_db=40, seed=0, margin=14, motion_blur=blur)
    ref = Frame(T0, fl.frames[0])
    pairs = []
    for k in range(1, 8):
        stamp = T0 + k * dt_ns
        a = Aligned(stamp, fl.frames[k], np.ones(fl.frames[k].shape, bool), ref, np.eye(3))
        pairs.append((Shift(stamp, -1, *map(float, disp[k]), 0.0, 0.01, 0.01), a))
    return pairs, fl


def test_exposure_gives_the_motion_blur_from_the_sets_own_velocity():
    """13 x 9 px/s and 0.1 s: motion blur (1.3, 0.9) px, modelled, reported, and it pays."""
    pairs, fl = _moving_set(0.1)
    gains, stats = [], []
    for exposure in (0.0, 0.1):
        stage = ReconstructionStage(n_frames=8, blur_sigma="0.3", exposure_s=exposure)
        (sr,) = [o for s, a in pairs for o in stage.add(s, a)]
        p_sr, p_bic = gain_over_bicubic(sr.image, fl.frames[0], fl.truth, 2, border=8)
        gains.append(p_sr - p_bic)
        stats.append((stage.stats.motion_blur_px, sr.result.motion_blur))
    assert stats[0] == (None, (0.0, 0.0))
    np.testing.assert_allclose(stats[1][0], (1.3, 0.9), atol=1e-3)
    np.testing.assert_allclose(stats[1][1], (1.3, 0.9), atol=1e-9)
    assert gains[1] > gains[0] + 1.0 and gains[1] > 0.0, gains  # measured +2.76 -> +5.17 dB


def test_motion_blur_fit_uses_stamps_and_the_alignment():
    """The velocity is a least-squares line through the displacements against the stamps.

    A member's displacement is its shift carried through the inverse of its alignment
    homography (an integer translation here), so the fit sees the whole motion, not only
    the sub-pixel residual.
    """
    from subpix_ros.stages.reconstruction import FrameSet, image_velocity, set_motion_blur

    img = np.zeros((64, 64), np.uint8)
    ref = Frame(T0, img)
    rng = np.random.default_rng(3)
    members = []
    for k in range(1, 6):
        stamp = T0 + k * 40_000_000 + int(rng.integers(-2_000_000, 2_000_000))
        t = (stamp - T0) * 1e-9
        d = np.array([-20.0 * t, 35.0 * t]) + rng.normal(0, 0.01, 2)  # px/s, rows and cols
        whole = np.rint(d)
        h = np.array([[1.0, 0.0, -whole[1]], [0.0, 1.0, -whole[0]], [0.0, 0.0, 1.0]])
        a = Aligned(stamp, img, np.ones_like(img, bool), ref, h)
        members.append((Shift(stamp, T0, *map(float, d - whole), 0.0, 0.01, 0.01), a))
    fs = FrameSet(ref, members, True, "complete")
    du, dv = set_motion_blur(fs, 0.02)
    assert abs(du + 0.4) < 0.01 and abs(dv - 0.7) < 0.01, (du, dv)
    assert set_motion_blur(fs, 0.0) is None
    assert image_velocity(np.array([1.0, 1.0]), np.zeros((2, 2))) is None  # one stamp: no fit
    with pytest.raises(ValueError):
        ReconstructionStage(exposure_s=0.5)  # beyond 0.1 s


def _degraded_set(crop, roof, t0, blur=0.5):
    """Return a flight of 8 independent-model frames from ``t0`` and its (Shift, Aligned)."""
    fl = degraded_flight(crop, roof, blur, shift_seed=3, noise_seed=4)
    ref = Frame(t0, fl.frames[0])
    pairs = []
    for k in range(1, 8):
        a = Aligned(t0 + k * DT, fl.frames[k], np.ones((128, 128), bool), ref, np.eye(3))
        pairs.append((Shift(t0 + k * DT, -1, *map(float, fl.shifts[k]), 0.0, 0.01, 0.01), a))
    return fl, pairs


def test_a_given_blur_the_edges_contradict_is_replaced_with_a_warning():
    """blur_sigma "0.7" on frames of a true 0.3 px with a roof in view: measured, warned, used."""
    fl, pairs = _degraded_set("crop_road", True, T0, blur=0.3)
    problems = []
    stage = ReconstructionStage(n_frames=8, blur_sigma="0.7")
    stage.on_problem = lambda level, msg: problems.append((level, msg))
    (sr,) = [o for s, a in pairs for o in stage.add(s, a)]
    assert sr.blur_source == "edges" and sr.blur_sigma <= 0.35
    assert any(lvl == "warn" and "over-deconvolve" in m for lvl, m in problems), problems
    p_sr, p_bic = gain_over_bicubic(sr.image, fl.frames[0], fl.truth, 2, border=8)
    assert p_sr - p_bic > 3.0


@pytest.mark.parametrize("search_sets", [1, 10])
def test_auto_blur_picks_up_the_first_edge_the_flight_reaches(search_sets):
    """A set without edges, then one with a roof: measured at once (default), or 10 sets on."""
    stage = ReconstructionStage(n_frames=8, blur_sigma="auto", blur_search_sets=search_sets)
    flight = [("crop_rows", False), ("crop_road", True)]
    got = []
    for k, (crop, roof) in enumerate(flight):
        for s, a in _degraded_set(crop, roof, T0 + 10 * k * DT)[1]:
            got += [(sr.blur_source, sr.blur_sigma) for sr in stage.add(s, a)]
    assert [src for src, _ in got] == ["fallback", "edges" if search_sets == 1 else "fallback"]
    if search_sets == 1:
        assert 0.4 <= got[1][1] <= 0.55, got  # true 0.5 px, biased low
    stage.configure(blur_search_sets=1)  # the schedule follows a run-time change
    assert stage.blur.search_sets == 1 and stage.blur.due == (search_sets == 10)


def test_release_memory_trims_the_heap_after_each_set_and_leaves_the_image_alone(seq):
    ref, pairs = _set(seq)
    plain = ReconstructionStage(n_frames=8)
    (a,) = [o for s, al in pairs for o in plain.add(s, al)]
    assert plain.stats.released_mb is None  # not asked
    assert plain.stats.workspace_mb > 0  # the solve's buffers kept for the next set
    stage = ReconstructionStage(n_frames=8, release_memory=True)
    # 64 KiB blocks (below glibc's mmap threshold: from the heap), every other one freed:
    # 160 MB of holes the heap keeps resident
    ballast = [np.ones(8192) for _ in range(5000)]
    del ballast[::2]
    (b,) = [o for s, al in pairs for o in stage.add(s, al)]
    assert np.array_equal(a.image, b.image)
    assert stage.stats.workspace_mb == 0  # nothing kept with release_memory
    released = stage.stats.released_mb
    if release_freed_memory() is None:
        pytest.skip("no glibc malloc_trim on this platform")
    assert released is not None and released > 50, released  # the holes went back to the kernel


def test_turning_release_memory_on_drops_the_buffers_kept_so_far(seq):
    stage = ReconstructionStage(n_frames=8)
    ref, pairs = _set(seq)
    (a,) = [o for s, al in pairs for o in stage.add(s, al)]
    assert stage.stats.workspace_mb > 0
    stage.configure(release_memory=True)
    ref, pairs = _set(seq, t0=T0 + 10 * DT)
    (b,) = [o for s, al in pairs for o in stage.add(s, al)]
    assert stage.stats.workspace_mb == 0 and stage.workspace.nbytes == 0
    assert np.array_equal(a.image, b.image)


def test_non_finite_pixels_are_an_error_and_no_image(seq, monkeypatch):
    import subpix_ros.stages.reconstruction as stage_mod
    from subpix_ros.core.superres.result import NonFiniteImageError

    def broken(*a, **k):
        assert k["out_dtype"] == np.uint8  # rounded by the core, tile by tile
        raise NonFiniteImageError("reconstruction produced non-finite pixels")

    monkeypatch.setattr(stage_mod, "reconstruct_within_budget", broken)
    stage = ReconstructionStage(n_frames=8)
    ref, pairs = _set(seq)
    out = [o for s, a in pairs for o in stage.add(s, a)]
    assert out == [] and stage.stats.kept == 0
    assert stage.stats.errors == 1 and "non-finite" in stage.stats.last_error


def test_the_result_holds_the_published_image_not_a_float_copy(seq):
    stage = ReconstructionStage(n_frames=8)
    ref, pairs = _set(seq)
    (sr,) = [o for s, a in pairs for o in stage.add(s, a)]
    assert sr.image.dtype == np.uint8 and sr.result.image is sr.image


def test_release_memory_without_malloc_trim_says_so_once(seq, monkeypatch):
    import subpix_ros.stages.reconstruction as stage_mod

    monkeypatch.setattr(stage_mod, "release_freed_memory", lambda: None)  # no glibc
    stage = ReconstructionStage(n_frames=8, release_memory=True)
    for t0 in (T0, T0 + 10**10):
        ref, pairs = _set(seq, t0=t0)
        [o for s, a in pairs for o in stage.add(s, a)]
    assert stage.stats.kept == 2 and stage.stats.released_mb is None
    warned = [stage.stats.last_warning] if "malloc_trim" in stage.stats.last_warning else []
    assert warned and stage.stats.warnings == 1, stage.stats


def test_members_given_as_rectangles_give_the_image_their_masks_give(seq):
    """Integer crops' rectangles (no mask made) and the same as masks: the same image."""
    from subpix_ros.core.validity import box_mask

    ref, pairs = _set(seq)
    h, w = ref.image.shape[:2]
    boxes = [(k % 3, h, 0, w - (k % 4)) for k in range(1, len(pairs) + 1)]
    out = {}
    for kind in ("box", "mask"):
        stage = ReconstructionStage(n_frames=8, blur_sigma="auto")
        got = []
        for (s, a), box in zip(pairs, boxes):
            img = a.image.copy()
            img[~box_mask((h, w), box)] = 0
            if kind == "box":
                member = dataclasses.replace(a, image=img, mask=None, box=box)
            else:
                member = dataclasses.replace(a, image=img, mask=box_mask((h, w), box))
            got += stage.add(s, member)
        (out[kind],) = got
    assert out["box"].blur_source == out["mask"].blur_source
    assert out["box"].blur_sigma == out["mask"].blur_sigma
    assert np.array_equal(out["box"].image, out["mask"].image)


def _colour_pairs(frames, shifts):
    """Return (reference Frame, [(Shift, Aligned)]) of BGR frames at ``shifts`` (LR px)."""
    ref = Frame(T0, frames[0])
    pairs = []
    for k in range(1, len(frames)):
        stamp = T0 + k * DT
        a = Aligned(stamp, frames[k], None, ref, np.eye(3), box=(0, 240, 0, 320))
        u, v = shifts[k]
        pairs.append((Shift(stamp, -1, float(u), float(v), 0.0, 0.01, 0.01), a))
    return ref, pairs


def test_colour_members_are_held_packed_and_give_the_same_image_within_a_level():
    """A waiting colour member is held as its luminance in 2 bytes per pixel, not 3."""
    import cv2

    from subpix_ros.data import seneca_frame_paths

    scene = cv2.imread(str(seneca_frame_paths()[4]), cv2.IMREAD_COLOR)
    shifts = [(0.23 * k, 0.37 * k) for k in range(8)]
    frames = []
    for u, v in shifts:
        m = np.float32([[1, 0, -300 + v], [0, 1, -300 + u]])
        frames.append(cv2.warpAffine(scene, m, (320, 240), flags=cv2.INTER_CUBIC))
    images, held = {}, {}
    for pack in (True, False):
        stage = ReconstructionStage(n_frames=8, pack_members=pack, blur_sigma="0.3")
        ref, pairs = _colour_pairs(frames, shifts)
        out = [sr for s, a in pairs[:-1] for sr in stage.add(s, a)]
        (members,) = stage.sets.values()
        held[pack] = sum(a.image.nbytes for _, a in members)
        assert all(a.packed == pack for _, a in members)
        out += stage.add(*pairs[-1])
        assert len(out) == 1 and out[0].method.startswith("map") and not out[0].fell_back
        images[pack] = out[0].image
    assert held[True] * 3 == held[False] * 2
    d = np.abs(images[True].astype(int) - images[False])
    assert d.max() <= 1 and (d > 0).mean() < 0.01


def test_a_member_of_another_type_drops_its_set_loudly():
    """A mono member in a colour set is not packed nor read as a packed luminance: error."""
    rng = np.random.default_rng(3)
    frames = [rng.integers(0, 255, (240, 320, 3), dtype=np.uint8) for _ in range(4)]
    frames[2] = frames[2][..., 0].copy()  # the camera switched to mono8 mid-set
    stage = ReconstructionStage(n_frames=4, min_frames=2)
    ref, pairs = _colour_pairs(frames, [(0.0, 0.0), (0.5, 0.0), (0.0, 0.5), (0.5, 0.5)])
    out = [sr for s, a in pairs for sr in stage.add(s, a)]
    assert out == [] and stage.stats.errors == 1
    assert "differ in size or type" in stage.stats.last_error


class CpuClock:
    """A CPU clock on which every reconstruction takes ``per_set`` seconds."""

    def __init__(self, per_set: float) -> None:
        self.per_set, self.t, self.calls = per_set, 0.0, 0

    def __call__(self) -> float:
        self.calls += 1
        if self.calls % 2 == 0:  # read before and after each set
            self.t += self.per_set
        return self.t


def test_max_cpu_cores_skips_sets_until_the_last_sets_cpu_is_paid_for(seq):
    problems = []
    # each set "takes" 0.5 s of CPU; 0.5 cores: a set per 1.0 s of flight at most
    stage = ReconstructionStage(
        n_frames=4, method="bicubic", max_cpu_cores=0.5, cpu_clock=CpuClock(0.5)
    )
    stage.on_problem = lambda level, msg: problems.append(msg)
    images = []
    for k in range(8):  # a reference every 0.4 s (sets of 4 at 10 Hz), 3.2 s of flight
        _, pairs = _set(seq, t0=T0 + 4 * k * DT, n=4)
        images += stage.add(*pairs[0])
        assert (T0 + 4 * k * DT in stage.sets) == (k in (0, 3, 6))  # a skipped set holds nothing
        images += [sr for s, a in pairs[1:] for sr in stage.add(s, a)]
    # references at 0, 0.4, ..., 2.8 s: 0 taken (nothing measured yet), then one per 1.0 s
    assert [sr.stamp_ns - T0 for sr in images] == [0, 12 * DT, 24 * DT]
    st = stage.stats
    assert st.sets_skipped_budget == 5 and st.skipped_by_reason == {"cpu_budget": 15}
    assert st.set_cpu_time_s == pytest.approx(0.5) and st.kept == 3
    assert sum("max_cpu_cores 0.5: sets skipped" in m for m in problems) == 1  # said once
    assert "one set per 1.0 s of flight" in problems[0]


def test_without_a_cpu_budget_every_set_is_reconstructed(seq):
    stage = ReconstructionStage(n_frames=4, method="bicubic", cpu_clock=CpuClock(5.0))
    images = []
    for k in range(4):
        _, pairs = _set(seq, t0=T0 + 4 * k * DT, n=4)
        images += [sr for s, a in pairs for sr in stage.add(s, a)]
    assert len(images) == 4 and stage.stats.sets_skipped_budget == 0 and not stage.stats.skipped
    assert stage.stats.set_cpu_time_s == pytest.approx(5.0)


def test_a_solved_sets_frames_are_released_before_its_image_is_published(seq):
    """A node holds the FrameSet while it publishes: the members' frames must be gone by then."""
    stage = ReconstructionStage(n_frames=4, method="bicubic")
    alive, sets = [], []
    for s, a in _set(seq, n=4)[1]:
        alive.append(weakref.ref(a))
        sets += stage.assemble(s, a)
    del s, a
    (fs,) = sets
    sr = stage.reconstruct(fs)  # fs still held here, as in the node's worker
    gc.collect()
    assert [r() for r in alive] == [None, None, None] and fs.members == []
    assert sr.n_frames == 4 and [s.stamp_ns for s in sr.shifts] == [T0 + k * DT for k in (1, 2, 3)]


def test_min_frames_above_n_frames_is_refused_naming_both():
    with pytest.raises(ValueError, match="min_frames: 10 is above n_frames 4"):
        ReconstructionStage(n_frames=4, min_frames=10)
    stage = ReconstructionStage(n_frames=3, min_frames=3)
    with pytest.raises(ValueError, match="min_frames: 64 is above n_frames 3"):
        stage.configure(min_frames=64)
    with pytest.raises(ValueError, match="n_frames"):
        stage.configure(n_frames=2)
    assert stage.param("min_frames") == 3 and stage.param("n_frames") == 3  # unchanged
    stage.configure(n_frames=6, min_frames=5)  # together: checked as a whole
    assert (stage.param("n_frames"), stage.param("min_frames")) == (6, 5)
    # n_frames alone below the default min_frames (4): a set of 3, the default follows it
    stage = ReconstructionStage(n_frames=3)
    assert (stage.param("n_frames"), stage.param("min_frames")) == (3, 3)


def test_numbers_are_taken_for_a_float_and_for_blur_sigma():
    # -p exposure_s:=0 is an integer; blur_sigma: 0.4 in a params file is a double
    stage = ReconstructionStage(exposure_s=0, blur_sigma=0.4, n_frames=4)
    assert stage.param("exposure_s") == 0.0 and isinstance(stage.param("exposure_s"), float)
    assert stage.param("blur_sigma") == "0.4" and stage.blur.setting == 0.4
    with pytest.raises(ValueError, match="expected int"):
        ReconstructionStage(n_frames=2.5)  # not the other way round
