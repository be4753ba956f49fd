"""The sections of the flight report: shifts, registration, super-resolution, mosaic, timing."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from subpix_ros.process.products import read_csv
from subpix_ros.process.report_html import (
    _esc,
    _f,
    _fig_svg,
    _img,
    _num,
    _pixels,
    _plt,
    _plural,
    _sig,
    _svg_img,
    _table,
)

CROP_LR_PX = 96  # side of the super-resolution crops, in input pixels


def missing_note(names: list[str], what: str) -> str:
    """Say which products are missing from the flight's folder and what is not shown for it.

    Parameters
    ----------
    names : list of str
        The missing files, relative to the folder.
    what : str
        What the section cannot show without them.

    Returns
    -------
    str
        One HTML paragraph (class ``problem``), or "" when nothing is missing.
    """
    if not names:
        return ""
    return (
        f"<p class='problem'>Missing from the flight's folder (after the run): "
        f"{_esc(', '.join(names))}: {_esc(what)}.</p>"
    )


def _legend_outside(fig, axes) -> None:
    """Put one legend of all the axes' labelled series at the figure's right, outside them.

    It can hide no point, and every panel keeps the same width (constrained layout makes room
    for it at the figure's edge).
    """
    handles, labels = [], []
    for ax in axes:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            if lab not in labels:
                handles.append(h)
                labels.append(lab)
    if handles:
        fig.legend(handles, labels, loc="outside right upper", fontsize=7)


def _empty_panel(ax, why: str) -> None:
    """Say in an axes without data why it has none (no meaningless value ticks)."""
    import textwrap

    ax.text(
        0.5,
        0.5,
        textwrap.fill(why, 80),
        ha="center",
        va="center",
        transform=ax.transAxes,
        fontsize=9,
        in_layout=False,  # the sentence is inside the axes: no room to make for it
    )
    ax.set_yticks([])


def telemetry_cover(
    telemetry: list[dict], stamps_ns: list[float], clock: tuple[float, float] = (0.0, 1.0)
) -> tuple[int, str]:
    """Return how many frame times fall within the telemetry's time span, and the spans.

    Parameters
    ----------
    telemetry : list of dict
        ``telemetry.csv``'s rows (``t_s``: the sample's time, s).
    stamps_ns : list of float
        The frames' stamps (ns).
    clock : (float, float), optional
        ``telemetry_time_offset_s`` and ``telemetry_timeout_s`` of the run (the registration
        stage's defaults if not given): the rule of :func:`~subpix_ros.process.summary.
        frames_covered`, as the flight's problem line applies it.

    Returns
    -------
    tuple of (int, str)
        The frames within the span and, for a sentence, both spans in seconds from the first
        frame ("" without samples or frames).
    """
    from subpix_ros.process.summary import frames_covered  # (summary -> collector -> here)

    t = np.array([_f(r, "t_s") for r in telemetry], dtype=float)
    t = t[np.isfinite(t)]
    f = np.array(stamps_ns, dtype=float) * 1e-9
    f = f[np.isfinite(f)]
    if not t.size or not f.size:
        return 0, ""
    inside = int(frames_covered(t, f, *clock).sum())
    f = f + clock[0]  # on the telemetry's clock
    t0 = f.min()
    spans = (
        f"telemetry from {t.min() - t0:+.1f} to {t.max() - t0:+.1f} s, frames from 0 to "
        f"{f.max() - t0:.1f} s, both from the first frame"
    )
    return inside, spans


def _no_residual_why(has_tel: bool, has_exp: bool, has_meas: bool, cover: tuple[int, str]) -> str:
    """Say why the residual (measured - expected) panel has no point."""
    if not has_tel:
        return "no telemetry: no expected shift, no residual"
    if not has_exp:
        if cover[1] and cover[0] == 0:
            return f"telemetry does not cover the frames' times ({cover[1]}): no expected shift"
        return (
            "no expected shift at these frames (telemetry stale, below min_speed_mps or "
            "without height above ground)"
        )
    if not has_meas:
        return "no converged shift: no sub-pixel shift to compare with the expected shift"
    return "no frame has both a converged and an expected shift"


def _section_shifts(
    shifts: list[dict],
    t0: float | None,
    has_tel: bool,
    cover: tuple[int, str] = (0, ""),
) -> str:
    """Draw the shift trajectory: measured total shift, the expected one, their residual.

    Frames without a converged shift are drawn at the registration's displacement of the
    reference's centre (hollow markers: no sub-pixel part, no residual) where they have one;
    frames with neither are ticks on the time axis (red), never points at 0 px. A series
    without a point has no legend entry; a panel without data says why. ``cover`` is
    :func:`telemetry_cover` of the shifts' frames (the reason of a missing expected shift).
    """
    plt = _plt()
    if not shifts:
        return "<p>No aligned frame: no shift to show.</p>"
    t = np.array([_f(r, "stamp_ns") for r in shifts]) * 1e-9 - (t0 or 0.0)
    conv = np.array([r.get("converged") == "1" for r in shifts])
    refs = [r.get("reference_stamp_ns") for r in shifts]
    new_ref = np.array([k == 0 or refs[k] != refs[k - 1] for k in range(len(refs))])
    reg_only = ~conv & _registered(shifts)
    fig, axes = plt.subplots(2, 1, figsize=(11, 5.6), sharex=True, layout="constrained")
    has_meas = has_exp = has_res = False
    for key, colour, ax_label in (
        ("u", "tab:blue", "u (rows)"),
        ("v", "tab:orange", "v (columns)"),
    ):
        tot = np.array([_f(r, f"{key}_total_px") for r in shifts])
        std = np.array([_f(r, f"{key}_std_px") for r in shifts])
        exp = np.array([_f(r, f"{key}_expected_px") for r in shifts])
        res = np.array([_f(r, f"{key}_residual_px") for r in shifts])

        def points(ax, values, label: str, colour=colour, std=std) -> bool:
            ok = conv & np.isfinite(values)
            if ok.any():
                ax.errorbar(
                    t[ok],
                    values[ok],
                    yerr=std[ok],
                    fmt="o",
                    ms=3,
                    color=colour,
                    capsize=2,
                    label=label,
                )
            return bool(ok.any())

        has_meas |= points(axes[0], tot, f"{ax_label} measured (+-1 s.e.)")
        if reg_only.any():  # whole-frame motion the registration measured: hollow, no s.e.
            axes[0].plot(
                t[reg_only],
                np.array([_f(r, f"{key}_registration_px") for r in shifts])[reg_only],
                "o",
                ms=5,
                mfc="none",
                mec=colour,
                mew=1.2,
                linestyle="none",
                label=f"{ax_label} registration only (no sub-pixel shift)",
            )
        if has_tel and np.isfinite(exp).any():  # without telemetry, no expectation to show
            has_exp = True
            axes[0].plot(
                *_broken_line(t, exp, new_ref),
                ".-",
                ms=4,
                color=colour,
                alpha=0.6,
                label=f"{ax_label} expected from telemetry (eq. 1)",
            )
        if has_tel:
            has_res |= points(axes[1], res, f"{ax_label} measured - expected")
    bare = ~conv & ~reg_only
    if bare.any():
        # no value: ticks on the time axis, not a point at 0 px that would read as measured
        axes[0].plot(
            t[bare],
            np.full(bare.sum(), 0.0),
            "|",
            ms=14,
            mew=2,
            color="red",
            transform=axes[0].get_xaxis_transform(),
            clip_on=False,
            label="frame without a converged shift or registration (time only)",
        )
    axes[0].set_ylabel("shift against\nreference (px)")
    axes[0].grid(alpha=0.3)
    if not has_meas and not has_exp and not reg_only.any():
        _empty_panel(axes[0], "no converged shift and no expected shift: no value to draw")
    elif not has_meas:
        axes[0].set_title(_no_measured_title(bool(reg_only.any()), bool(bare.any())), fontsize=8)
    axes[1].set_ylabel("residual (px)")
    axes[1].set_xlabel("time since the first frame (s)")
    axes[1].grid(alpha=0.3)
    _legend_outside(fig, axes)
    if not has_res:
        _empty_panel(axes[1], _no_residual_why(has_tel, has_exp, has_meas, cover))
    res_u = np.array([_f(r, "u_residual_px") for r in shifts])
    res_v = np.array([_f(r, "v_residual_px") for r in shifts])
    ok = np.isfinite(res_u) & np.isfinite(res_v) & has_tel
    text = (
        f"<p>{int(conv.sum())} of {len(shifts)} aligned frames have a converged shift. "
        f"Shift = where the reference's content appears in the frame (rows u, columns v)."
    )
    if reg_only.any():
        text += (
            f" {_plural(int(reg_only.sum()), 'frame')} without a converged shift "
            f"{'is' if reg_only.sum() == 1 else 'are'} drawn at the registration's "
            "displacement of the reference's centre (hollow markers: whole-frame motion, no "
            "sub-pixel shift, no residual)."
        )
    if ok.any():
        text += (
            f" Residual against telemetry: RMS u {_sig(np.sqrt(np.mean(res_u[ok] ** 2)))} px, "
            f"v {_sig(np.sqrt(np.mean(res_v[ok] ** 2)))} px over "
            f"{_plural(int(ok.sum()), 'frame')}."
        )
    return text + "</p>" + _img(fig, "shift trajectory")


def _registered(shifts: list[dict]) -> np.ndarray:
    """Return, per ``shifts.csv`` row, True where it has the registration's displacement."""
    u = np.array([_f(r, "u_registration_px") for r in shifts], dtype=float)
    v = np.array([_f(r, "v_registration_px") for r in shifts], dtype=float)
    return np.isfinite(u) & np.isfinite(v)


def _no_measured_title(registered: bool, ticks: bool) -> str:
    """Title the shift panel of a flight where no sub-pixel shift converged."""
    if not registered:
        return "no converged shift: no measured value (red ticks: the frames' times)"
    drawn = "hollow markers: the registration's displacement"
    if ticks:
        drawn += "; red ticks: frames without it either"
    return f"no converged shift: no sub-pixel value ({drawn})"


def _segments(frames: list[dict], aligned: list[dict]) -> np.ndarray:
    """Return, per aligned row, True where its line starts anew (no line drawn to it).

    A line joins two aligned frames only when they share the reference and no frame was
    dropped between them (in ``frames.csv``'s order).
    """
    start = np.ones(len(aligned), dtype=bool)
    pos = {id(r): i for i, r in enumerate(aligned)}
    prev = None
    broken = True
    for r in frames:
        status = r.get("status")
        if status == "aligned":
            i = pos[id(r)]
            start[i] = (
                broken
                or prev is None
                or (prev.get("reference_stamp_ns") != r.get("reference_stamp_ns"))
            )
            prev, broken = r, False
        elif status in ("dropped", "reference"):
            broken = True
    return start


def _broken_line(t: np.ndarray, y: np.ndarray, start: np.ndarray) -> tuple:
    """Insert NaN before each new segment's first point (matplotlib breaks the line there)."""
    xs, ys = [], []
    for i in range(len(t)):
        if start[i] and i:
            xs.append(np.nan)
            ys.append(np.nan)
        xs.append(t[i])
        ys.append(y[i])
    return np.array(xs, dtype=float), np.array(ys, dtype=float)


def _section_registration(
    frames: list[dict], refs: list[dict], stages: dict, t0: float | None
) -> str:
    """Draw the registration: inliers and residuals per aligned frame, references, fallbacks.

    Lines join only frames of one reference with no frame dropped between them; every point
    has a marker (a frame alone is seen). The tracking fallbacks are the registration stage's
    count; those on frames that were then aligned are drawn, the others (a frame that
    started a new reference) are said.
    """
    plt = _plt()
    aligned = [r for r in frames if r.get("status") == "aligned"]
    reg = stages.get("registration_node") or stages.get("registration") or {}
    fb = [r for r in aligned if r.get("tracked") == "0"]
    out = []
    if aligned:
        t = np.array([_f(r, "stamp_ns") for r in aligned]) * 1e-9 - (t0 or 0.0)
        start = _segments(frames, aligned)
        fig, axes = plt.subplots(2, 1, figsize=(11, 4.8), sharex=True, layout="constrained")
        axes[0].plot(
            *_broken_line(t, np.array([_f(r, "inliers") for r in aligned]), start), "o-", ms=3
        )
        axes[0].set_ylabel("inlier tie points")
        for key, style, label in (
            ("rms_along_px", "o-", "along the baseline"),
            ("rms_cross_px", "s-", "across the baseline"),
        ):
            y = np.array([_f(r, key) for r in aligned])
            if np.isfinite(y).any():
                axes[1].plot(*_broken_line(t, y, start), style, ms=3, label=label)
        axes[1].plot(
            *_broken_line(t, np.array([_f(r, "rms_px") for r in aligned]), start),
            ".:",
            ms=4,
            color="grey",
            label="inlier RMS",
        )
        axes[1].set_ylabel("residual (px)")
        axes[1].set_xlabel("time since the first frame (s)")
        for ax in axes:
            ax.grid(alpha=0.3)
            for k, r in enumerate(refs):
                ax.axvline(
                    r["stamp_ns"] * 1e-9 - (t0 or 0.0),
                    color="green",
                    alpha=0.35,
                    lw=1,
                    label="new reference" if k == 0 and ax is axes[1] else None,
                )
            for k, r in enumerate(fb):
                ax.axvline(
                    _f(r, "stamp_ns") * 1e-9 - (t0 or 0.0),
                    color="red",
                    alpha=0.5,
                    ls="--",
                    lw=1,
                    label="tracking fell back to the full search"
                    if k == 0 and ax is axes[1]
                    else None,
                )
        _legend_outside(fig, axes)
        out.append(_img(fig, "registration quality"))
        out.append(
            "<p>The residual along and across the baseline (the frame's motion against its "
            "reference) is computed only where the baseline is at least 1 px (below it has no "
            "direction): those frames show the inlier RMS alone. Lines join only frames of one "
            "reference with no frame dropped between them.</p>"
        )
    else:
        out.append("<p>No frame was registered to a reference.</p>")
    fallbacks = reg.get("fallbacks", reg.get("tracking_fallbacks"))
    n_fb = len(fb)
    total = int(fallbacks) if fallbacks is not None else n_fb
    text = f"Tracking fallbacks: {total}."
    if total:
        text += f" {n_fb} drawn (red dashed: frames then aligned)"
        if total > n_fb:
            rest = total - n_fb
            text += (
                f"; {rest} on {'a frame' if rest == 1 else 'frames'} that then failed to "
                "register or started a new reference (not drawn)"
            )
        text += "."
    if total and reg.get("last_tracking_fallback"):
        text += f" Last reason: {_esc(reg['last_tracking_fallback'])}."
    out.append(f"<p>{text}</p>")
    rows = []
    for r in refs:
        ts = r["stamp_ns"] * 1e-9 - (t0 or 0.0)
        rows.append([f"{ts:.3f}", r["stamp_ns"], r.get("reason") or "?"])
    out.append(
        f"<p>{_plural(len(refs), 'reference')} started:</p>"
        + _table(["t (s)", "stamp (ns)", "why"], rows)
    )
    return "".join(out)


def _read_image(path: Path):
    """Return the image at ``path`` as stored (bit depth, channels), or None.

    None when the file is not there or cannot be decoded, without OpenCV's own warning on
    stderr (``imread`` logs one for a missing file): the report says what is missing.
    """
    if not path.is_file():
        return None
    try:
        data = np.fromfile(path, dtype=np.uint8)
    except OSError:
        return None
    return cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None


def _display(img: np.ndarray) -> np.ndarray:
    """RGB float 0..1 for matplotlib from a BGR/mono uint8/uint16 image."""
    a = img.astype(np.float64) / (65535.0 if img.dtype == np.uint16 else 255.0)
    if a.ndim == 3:
        a = a[..., ::-1]
    return np.clip(a, 0, 1)


def _crop_box(img: np.ndarray, factor: int) -> tuple[int, int, int]:
    """Find the crop (row, col, side; output px) with the most detail (gradient energy).

    The search runs on the luminance of the image reduced by ``factor`` (the input's scale,
    where the crop's detail is already visible): cheap on 4K images.
    """
    side = min(CROP_LR_PX * factor, img.shape[0], img.shape[1])
    h, w = img.shape[0] // factor, img.shape[1] // factor
    small = cv2.resize(img, (max(w, 1), max(h, 1)), interpolation=cv2.INTER_AREA)
    if small.ndim == 3:
        small = cv2.cvtColor(small, cv2.COLOR_BGR2GRAY)
    gy, gx = np.gradient(small.astype(np.float32))
    energy = cv2.magnitude(gx, gy)
    ii = cv2.integral(cv2.multiply(energy, energy), sdepth=cv2.CV_64F)
    side_s, step_s = side // factor, max(1, max(factor, side // 2) // factor)
    rows = np.arange(0, max(h - side_s, 0) + 1, step_s)
    cols = np.arange(0, max(w - side_s, 0) + 1, step_s)
    r, c = np.meshgrid(rows, cols, indexing="ij")
    r1, c1 = np.minimum(r + side_s, h), np.minimum(c + side_s, w)
    sums = ii[r1, c1] - ii[r, c1] - ii[r1, c] + ii[r, c]
    k = int(np.argmax(sums))  # the first maximum in row-major order
    return int(r.flat[k]) * factor, int(c.flat[k]) * factor, side


@dataclass(frozen=True)
class SetCrop:
    """The report's crop of one set: where (output px) and the two images' pixels there."""

    row: int
    col: int
    side: int
    bicubic: np.ndarray
    super_resolved: np.ndarray


def set_crop(bicubic: np.ndarray, super_resolved: np.ndarray, factor: int) -> SetCrop:
    """Cut the report's crop (:func:`_crop_box` on the bicubic image) out of both images."""
    r, c, side = _crop_box(bicubic, factor)
    win = (slice(r, r + side), slice(c, c + side))
    return SetCrop(r, c, side, bicubic[win].copy(), super_resolved[win].copy())


def edge_crop(
    bicubic: np.ndarray, super_resolved: np.ndarray, factor: int, roi: list[int]
) -> SetCrop:
    """Cut the crop (same side as :func:`set_crop`'s) centred on an edge's ROI from both images.

    ``roi`` is ``(x, y, w, h)`` in input px (``summary.json``'s ``edges[i].roi``). The side is
    every set's (the same scale on screen); a longer edge runs beyond it.
    """
    h, w = bicubic.shape[:2]
    x, y, rw, rh = (int(v) * factor for v in roi)
    side = min(CROP_LR_PX * factor, h, w)
    r = int(np.clip(y + rh // 2 - side // 2, 0, h - side))
    c = int(np.clip(x + rw // 2 - side // 2, 0, w - side))
    win = (slice(r, r + side), slice(c, c + side))
    return SetCrop(r, c, side, bicubic[win].copy(), super_resolved[win].copy())


def _contains(crop: SetCrop, roi: list[int], factor: int) -> bool:
    """Return True if the ROI ``(x, y, w, h)`` (input px) lies within the crop (output px)."""
    x, y, rw, rh = (int(v) * factor for v in roi)
    return (
        crop.col <= x
        and x + rw <= crop.col + crop.side
        and crop.row <= y
        and y + rh <= crop.row + crop.side
    )


def _edge_outline(
    crop: SetCrop, edges: list[dict], factor: int, scale: int
) -> tuple[tuple[int, int, int, int] | None, str]:
    """Return where the first edge's ROI is on the shown crop (screen px) and a caption part.

    ``(top, left, height, width)`` of the ROI's part within the crop, None when the set has no
    edge or it lies outside the crop (the caption then says where it is).
    """
    if not edges or len(edges[0].get("roi") or []) != 4:
        return None, ""
    roi = edges[0]["roi"]
    x, y, rw, rh = (int(v) * factor for v in roi)
    where = f"rows {y}..{y + rh}, columns {x}..{x + rw}"
    top, left = max(y, crop.row), max(x, crop.col)
    bottom, right = min(y + rh, crop.row + crop.side), min(x + rw, crop.col + crop.side)
    if bottom <= top or right <= left:
        return None, f"; the edge measured for the MTF is elsewhere ({where})"
    box = (
        (top - crop.row) * scale,
        (left - crop.col) * scale,
        (bottom - top) * scale,
        (right - left) * scale,
    )
    part = "" if _contains(crop, roi, factor) else ", in part beyond the crop"
    return box, f"; outlined: the edge measured for the MTF ({where}{part})"


def _edges_text(edges: list[dict], has_truth: bool) -> str:
    """Say what the slanted-edge MTF at the reference's straight edges shows (or that none)."""
    if not edges:
        what = "no straight edge in the reference" + ("" if has_truth else " and no ground truth")
        return f"<p>MTF: {what}: no MTF figure for this set.</p>"
    b50 = float(np.median([e["mtf50_bicubic"] for e in edges]))
    s50 = float(np.median([e["mtf50_sr"] for e in edges]))
    b30 = float(np.median([e["mtf30_bicubic"] for e in edges]))
    s30 = float(np.median([e["mtf30_sr"] for e in edges]))
    return (
        f"<p>MTF at {_plural(len(edges), 'straight edge')} of the scene (slanted-edge method, "
        f"{'median; ' if len(edges) > 1 else ''}"
        f"cycles per input px, the input's Nyquist is 0.5): MTF50 bicubic {b50:.3f}, "
        f"super-resolved {s50:.3f} ({s50 / b50:.2f}x); MTF30 bicubic {b30:.3f}, "
        f"super-resolved {s30:.3f}.</p>"
    )


def _set_crop(folder: Path, entry: dict, factor: int, crops: dict | None) -> SetCrop | None:
    """Return the set's crop: kept by the run that made it, else cut from the PNGs on disk.

    A set whose MTF comes from an edge is shown around its first edge (the crop kept by the
    run, chosen for its detail before the edges were measured, is used only if it holds it).
    """
    edges = entry.get("edges") or []
    roi = edges[0].get("roi") if edges else None
    kept = (crops or {}).get(entry["superres"])
    if kept is not None and (roi is None or _contains(kept, roi, factor)):
        return kept
    sr = _read_image(folder / entry["superres"])
    bic = _read_image(folder / entry["bicubic"])
    if sr is None or bic is None or sr.shape != bic.shape:
        return kept
    if roi is not None and len(roi) == 4:
        return edge_crop(bic, sr, factor, roi)
    return set_crop(bic, sr, factor)


def _section_sets(
    folder: Path,
    sets: list[dict],
    factor: int,
    t0: float | None,
    crops: dict | None = None,
    offsets: dict[str, str] | None = None,
) -> str:
    if not sets:
        return "<p>No super-resolved image (no set of frames reached min_frames).</p>"
    out = []
    for k, s in enumerate(sets):
        ts = s["reference_stamp_ns"] * 1e-9 - (t0 or 0.0)
        head = (
            f"<h3>Set {k + 1}: reference at {ts:.3f} s, {s['frames']} frames, "
            f"method {_esc(s.get('method'))}"
            + (f", fell back: {_esc(s.get('reason'))}" if s.get("fell_back") else "")
            + "</h3>"
        )
        out.append(head)
        if s.get("blur_sigma") is not None:
            out.append(
                f"<p>Optics blur {s['blur_sigma']:.3f} px ({_esc(s.get('blur_source'))}"
                + (f": {_esc(s.get('blur_reason'))}" if s.get("blur_reason") else "")
                + ").</p>"
            )
        if "psnr_sr_db" in s:
            out.append(
                f"<p>Against the rendered truth: PSNR super-resolved {s['psnr_sr_db']:.2f} dB, "
                "bicubic "
                f"{s['psnr_bicubic_db']:.2f} dB (gain {s['gain_db']:+.2f} dB).</p>"
            )
        out.append(_edges_text(s.get("edges") or [], "psnr_sr_db" in s))
        crop = _set_crop(folder, s, factor, crops)
        if crop is None:
            gone = [s[k] for k in ("superres", "bicubic") if not (folder / s[k]).is_file()]
            out.append(
                missing_note(gone, "the set's images are not shown")
                or "<p>Images unreadable (or of different sizes).</p>"
            )
            continue
        r, c, side = crop.row, crop.col, crop.side
        scale = max(1, round(320 / max(side, 1)))  # about 320 screen px wide
        where = (
            f"output px rows {r}..{r + side}, columns {c}..{c + side} "
            f"(same crop, same scale, x{scale} on screen)"
        )
        box, said = _edge_outline(crop, s.get("edges") or [], factor, scale)
        where += said
        out.append('<div class="sets">')
        out.append(
            _pixels(
                crop.bicubic,
                f"set {k + 1}: bicubic",
                f"bicubic x{factor} of the reference; {where}",
                scale,
                box,
            )
        )
        label, caption = (
            (f"set {k + 1}: bicubic fallback", f"bicubic fallback, not super-resolved; {where}")
            if s.get("fell_back")
            else (
                f"set {k + 1}: super-resolved",
                f"super-resolved x{factor} ({s.get('method')}); {where}",
            )
        )
        out.append(_pixels(crop.super_resolved, label, caption, scale, box))
        members = s.get("members", [])
        svg = (offsets or {}).get(offsets_key(members, factor)) or offsets_svg(members, factor)
        out.append(_svg_img(svg, f"set {k + 1}: sub-pixel offsets"))
        out.append("</div>")
    return "".join(out)


def offsets_key(members: list[dict], factor: int) -> str:
    """Return what a set's offsets figure shows, as a key: the factor and the members' shifts."""
    return json.dumps([int(factor), [[m["u_px"], m["v_px"]] for m in members]])


def offsets_svg(members: list[dict], factor: int) -> str:
    """Draw a set's sub-pixel offsets figure (members as in ``summary.json``) as base64 SVG."""
    uv = np.array([[0.0, 0.0]] + [[m["u_px"], m["v_px"]] for m in members])
    frac = uv - np.floor(uv)
    return _fig_svg(_offsets_figure(_plt(), frac, factor))


def _offsets_figure(plt, frac: np.ndarray, factor: int):
    """Scatter of a set's fractional offsets (row 0: the reference) on the 1/factor grid.

    The ticks are the grid lines themselves (fixed: no tick search, no legend box, which
    were most of a figure's cost); the caption names the markers.
    """
    fig, ax = plt.subplots(figsize=(3.0, 3.0))
    ax.scatter(frac[1:, 1], frac[1:, 0], s=30)
    ax.scatter([0], [0], marker="*", s=120, color="red")
    grid = np.linspace(0.0, 1.0, factor + 1)
    labels = [f"{g:.2g}" for g in grid]
    ax.set_xticks(grid, labels, fontsize=7)
    ax.set_yticks(grid, labels, fontsize=7)
    ax.grid(True, color="grey", lw=0.6)
    ax.set_xlim(-0.05, 1.05)
    ax.set_ylim(1.05, -0.05)
    ax.set_aspect("equal")
    ax.set_xlabel("fractional v (columns, px)", fontsize=8)
    ax.set_ylabel("fractional u (rows, px)", fontsize=8)
    ax.set_title(
        f"sub-pixel offsets (grid 1/{factor} px)\nred star: reference; dots: frames", fontsize=8
    )
    fig.subplots_adjust(left=0.2, right=0.96, bottom=0.15, top=0.87)
    return fig


def _section_mosaic(
    folder: Path,
    mosaic: dict,
    telemetry: list[dict],
    frames: list[dict] | None = None,
    clock: tuple[float, float] = (0.0, 1.0),
) -> str:
    """Draw the mosaic with the frame footprints and the GPS track with the frames on it.

    The part of the track flown while frames were taken (first to last frame) is drawn thick
    and each frame's position (interpolated at its stamp) is a dot; when no frame falls within
    the track's time span, the panel and a sentence say so.
    """
    plt = _plt()
    gone = [
        name
        for name, needed in (("mosaic.png", mosaic.get("written")), ("telemetry.csv", True))
        if needed and not (folder / name).is_file()
    ]
    note = missing_note(gone, "not shown")
    parts = []
    img = _read_image(folder / "mosaic.png") if mosaic.get("written") else None
    lat = np.array([_f(r, "lat_deg") for r in telemetry])
    lon = np.array([_f(r, "lon_deg") for r in telemetry])
    has_gps = (
        telemetry
        and np.isfinite(lat).any()
        and (np.ptp(lat[np.isfinite(lat)]) > 0 or np.ptp(lon[np.isfinite(lon)]) > 0)
    )
    n = (img is not None) + bool(has_gps)
    if n == 0:
        return note or "<p>No mosaic and no GPS track.</p>"
    fig, axes = plt.subplots(
        1, n, figsize=(5.5 * n + 1.5, 4.6), squeeze=False, layout="constrained"
    )
    axes = list(axes[0])
    if img is not None:
        ax = axes.pop(0)
        ax.imshow(_display(img), cmap="gray" if img.ndim == 2 else None)
        for i, fp in enumerate(mosaic.get("footprints", [])):
            p = np.array(fp + [fp[0]])
            ax.plot(p[:, 0], p[:, 1], "-", lw=0.8, color="yellow", alpha=0.8)
        ax.set_title(
            f"mosaic with {_plural(len(mosaic.get('footprints', [])), 'frame footprint')}",
            fontsize=9,
        )
        ax.set_xticks([])
        ax.set_yticks([])
    if has_gps:
        from subpix_ros.core.telemetry import enu_offset_m
        from subpix_ros.process.summary import frames_covered

        ok = np.isfinite(lat) & np.isfinite(lon)
        e, nn = enu_offset_m(float(lat[ok][0]), float(lon[ok][0]), lat[ok], lon[ok])
        ts = np.array([_f(r, "t_s") for r in telemetry])[ok]
        stamps = np.array([_f(r, "stamp_ns") for r in frames or []], dtype=float) * 1e-9
        stamps = stamps[np.isfinite(stamps)] + clock[0]  # on the telemetry's clock
        ax = axes.pop(0)
        ax.plot(e, nn, "-", color="tab:blue", lw=1, alpha=0.6, label="track")
        inside = np.zeros(0, dtype=bool)
        if stamps.size and np.isfinite(ts).all() and np.all(np.diff(ts) >= 0):
            # the flight's rule (summary.frames_covered), the offset already added
            inside = frames_covered(ts, stamps, 0.0, clock[1])
        if inside.any():
            # the stretch flown while frames were taken: the track at the frames' times
            t_in = np.sort(stamps[inside])
            fe, fn = np.interp(t_in, ts, e), np.interp(t_in, ts, nn)
            ax.plot(fe, fn, "-", color="tab:orange", lw=4, label="while frames were taken")
            ax.plot(fe, fn, "o", ms=2, color="black", label="frame positions")
            if not inside.all():
                parts.append(
                    f"<p>{int((~inside).sum())} of {_plural(stamps.size, 'frame')} taken outside "
                    "the GPS track's time span: not on the track.</p>"
                )
        elif stamps.size:
            _, spans = telemetry_cover(telemetry, list((stamps - clock[0]) * 1e9), clock)
            why = "no frame was taken within the GPS track's time"
            ax.set_title(why + " (no frame on the track)", fontsize=8, loc="left")
            parts.append(f"<p>GPS track: {why} ({_esc(spans)}).</p>")
        ax.plot(e[:1], nn[:1], "go", label="start")
        ax.plot(e[-1:], nn[-1:], "rs", label="end")
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("east (m)")
        ax.set_ylabel("north (m)")
        if not ax.get_title(loc="left"):
            ax.set_title(f"GPS track ({_plural(int(ok.sum()), 'sample')})", fontsize=9)
        ax.grid(alpha=0.3)
        _legend_outside(fig, [ax])
    elif "telemetry.csv" not in gone:
        parts.append("<p>No GPS track (no telemetry position).</p>")
    return note + _img(fig, "mosaic and GPS track") + "".join(parts)


#: Fewest calls for a p99 worth showing (below, the p99 is the largest value or two).
MIN_CALLS_P99 = 20


def _p99(calls, p99) -> str:
    """Return a stage's p99 (ms), or why not: too few calls to tell it from the maximum."""
    try:
        n = int(calls)
    except (TypeError, ValueError):
        n = 0
    if n < MIN_CALLS_P99:
        return f"n too small (< {MIN_CALLS_P99})"
    return _num(p99, "{:.1f}")


def _section_timing(timing: dict) -> str:
    """Tabulate the stages' times (calls, median, p99, max, total) and the memory."""
    rows = []
    for name, st in sorted((timing.get("stages") or {}).items()):
        rows.append(
            [
                name,
                st.get("calls"),
                _num(st.get("median_ms"), "{:.1f}"),
                _p99(st.get("calls"), st.get("p99_ms")),
                _num(st.get("max_ms"), "{:.1f}"),
                _num(st.get("total_s"), "{:.2f}"),
            ]
        )
    # the mosaic runs on its own thread: only its stage statistics (no p99, no total)
    mos = ((timing.get("stage_stats_ms") or {}).get("mosaic_node") or {}).get("times") or {}
    if mos.get("n"):
        rows.append(
            [
                "mosaic (own thread)",
                mos.get("n"),
                _num(mos.get("p50"), "{:.1f}"),
                _p99(mos.get("n"), None) if int(mos["n"]) < MIN_CALLS_P99 else "not recorded",
                _num(mos.get("max"), "{:.1f}"),
                "not recorded",
            ]
        )
    fm = timing.get("frame_ms") or {}
    rows.append(
        [
            "whole frame (pipeline add)",
            timing.get("frames"),
            _num(fm.get("median"), "{:.1f}"),
            _p99(timing.get("frames"), fm.get("p99")),
            _num(fm.get("max"), "{:.1f}"),
            "",
        ]
    )
    t = _table(["stage", "calls", "median (ms)", "p99 (ms)", "max (ms)", "total (s)"], rows)
    return t + (
        f"<p>p99 only from {MIN_CALLS_P99} calls on (with fewer it is the maximum). "
        "Peak resident memory of the processing process: "
        f"{_num(timing.get('peak_rss_mb'), '{:.0f}')} MB; "
        f"CPU time {_num(timing.get('cpu_s'), '{:.1f}')} s.</p>"
    )


def _read_table(folder: Path, name: str) -> list[dict[str, str]]:
    """Read a CSV product of ``folder`` (an empty list when the flight has none)."""
    path = folder / name
    return read_csv(path) if path.is_file() else []


def per_frame_sections(
    folder: str | Path,
    references: list,
    stages: dict,
    t0: float | None,
    has_telemetry: bool,
    clock: tuple[float, float] = (0.0, 1.0),
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
    clock : (float, float), optional
        The run's ``telemetry_time_offset_s`` and ``telemetry_timeout_s``
        (:func:`telemetry_cover`).

    Returns
    -------
    dict
        ``{"shifts": html, "registration": html}``.
    """
    folder = Path(folder)
    shifts = _read_table(folder, "shifts.csv")
    cover = (0, "")
    if has_telemetry and shifts:
        cover = telemetry_cover(
            _read_table(folder, "telemetry.csv"), [_f(r, "stamp_ns") for r in shifts], clock
        )
    gone = [name for name in ("shifts.csv", "frames.csv") if not (folder / name).is_file()]
    return {
        # a table deleted after the run is said, not shown as a flight without aligned frames
        "shifts": missing_note(["shifts.csv"], "no shift to show")
        if "shifts.csv" in gone
        else _section_shifts(shifts, t0, has_telemetry, cover),
        "registration": missing_note([n for n in gone if n == "frames.csv"], "no frame to show")
        + _section_registration(_read_table(folder, "frames.csv"), references, stages, t0),
    }


def mosaic_section(
    folder: str | Path, mosaic: dict, clock: tuple[float, float] = (0.0, 1.0)
) -> dict[str, str]:
    """Draw the mosaic and track section from ``mosaic.png`` and ``telemetry.csv``.

    ``mosaic`` is ``summary.json``'s ``mosaic`` and ``clock`` the run's
    ``telemetry_time_offset_s`` and ``telemetry_timeout_s`` (:func:`telemetry_cover`);
    returns ``{"mosaic": html}``.
    """
    folder = Path(folder)
    return {
        "mosaic": _section_mosaic(
            folder,
            mosaic,
            _read_table(folder, "telemetry.csv"),
            _read_table(folder, "frames.csv"),
            clock,
        )
    }
