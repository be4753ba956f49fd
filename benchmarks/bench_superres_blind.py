"""Super-resolution when the camera's blur is not given (issue 17): gain over bicubic per cell.

Frames come from the independent degradation model
(``benchmarks/degrade_independent.py``, not the reconstruction's own
``core/render.py``): real full-resolution Seneca crops, Gaussian optics and a
pixel aperture of fill factor 0.8-1.0 integrated on an 8x finer grid,
Poisson-Gaussian noise at the cell's SNR, 8 bit. Cells: true blur x SNR x
factor x shift layout (``grid``: the p x p k/p grid; ``random``: max(8, p^2)
frames uniform in [-1, 1) px); shifts are estimated from the frames
(``core.shift.estimate_shift``) in every cell. Per cell two scenes: a real
crop as it is ("none": whatever edges nature gives) and another crop with a
sharp-edged roof in view ("edge"). Extra cells: JPEG quality 90 frames, and
0.1 px of unmodelled shift error (estimated shifts plus N(0, 0.1^2) px, used
as given: ``refine_shifts=False``, no covariance).

Columns per scene: PSNR gain over bicubic of frame 0 (dB; interior,
4 factor px cut) of CG (Tikhonov, scipy CG on the box-integration operator
with no optics model, gradient regulariser; weight tuned once per factor on
its first cell), ``told`` (ours told the true blur), ``told+w`` (told the true blur and the
true pixel fill factor, ``pixel_fill``), ``auto`` (ours with ``blur_sigma="auto"``, or the
default ``blur_sigma`` where the code has no ``auto``), and the blur and fill that ``auto``
used (``est``, ``w``) with its source. ``--snr``, ``--max-blur`` and ``--scene`` run a subset
of the cells (the same scenes, fills and seeds as in the whole table); ``--cg-lambda`` fixes
CG's weight (a subset's first cell is not the whole table's).

Motion blur (``--motion``, instead of the table above): frames exposed while the image moves
by ``d`` (1 and 2 px, along (0.8, 0.6) and along the columns), true optics 0.3 px, fill 1.0,
40 dB; columns ``ignore`` (told the optics blur, no motion blur), ``told`` (told both,
``motion_blur=d``), ``auto`` and ``auto+d`` (``blur_sigma="auto"`` without and with the
motion blur; ``est``, ``est+d``: the blur each used).

Image prior (``--prior P[,Q...]``, issue 17): ``told`` and ``auto`` use ``reconstruct(...,
prior=P)``; each further prior Q adds the columns ``told:Q`` and ``auto:Q`` (Q's first letter)
in the same run, on the same frames, and a summary of Q against P (cells where auto >= CG + 1
dB, min gain, change in told and auto). The timing then reconstructs with every prior given.

Over a flight (``--flight``, issue 17): a camera's blur does not change from set to set, and
``auto`` keeps an edge estimate for the sets after it (``BlurCalibration``). The column
``flight`` reconstructs each "none" scene with the blur the calibration holds after an earlier
set of the same flight showed the cell's roof: that set rendered with the same camera (blur,
fill factor, SNR, JPEG) and its own noise, measured, then this set given to the calibration
(which measures it too and keeps the roof's estimate when it shows no edge of its own).

Run: ``python benchmarks/bench_superres_blind.py [--quick] [--json out.json] [--flight]
[--only quality|timing] [--motion] [--snr DB] [--max-blur PX] [--scene none|edge]
[--cg-lambda L] [--scene-blur G] [--prior powerlaw,rolloff]``.
"""

from __future__ import annotations

import argparse
import inspect
import json
import os
import re
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from degrade_independent import degrade, scene_crop, shift_layout  # noqa: E402
from flight_eval import est_shifts, gain  # noqa: E402

from subpix_ros.core import superres  # noqa: E402
from subpix_ros.core.superres import reconstruct  # noqa: E402
from subpix_ros.data import CROP_NAMES, load_crop  # noqa: E402

LR = {2: 128, 3: 112, 4: 96}  # LR frame side per factor
MARGIN = 8
FILLS = (1.0, 0.9, 0.8)
_AUTO = getattr(superres, "BLUR_AUTO", None)  # None: code from before issue 17 (no "auto")
_FILL = "pixel_fill" in inspect.signature(reconstruct).parameters  # the model takes a fill


def tikhonov_cg(frames, shifts, p, lam, iters=60):
    """CG Tikhonov with box integration and no optics model (bench_superres's, blur 0)."""
    from bench_superres import tikhonov_cg as cg_reference

    return cg_reference(frames, shifts, p, lam, iters, blur_sigma=0.0)


def run_auto(frames, shifts, p, **kw):
    if _AUTO is None:
        return reconstruct(frames, shifts, p, **kw)
    return reconstruct(frames, shifts, p, blur_sigma=_AUTO, **kw)


def cells(quick: bool):
    blurs = (0.2, 0.5, 0.9) if quick else (0.2, 0.3, 0.5, 0.7, 0.9)
    snrs = (40,) if quick else (30, 40, 50)
    factors = (2, 4) if quick else (2, 3, 4)
    out = []
    for p in factors:
        for layout in ("grid", "random"):
            for snr in snrs:
                for b in blurs:
                    out.append(dict(p=p, layout=layout, snr=snr, blur=b, jpeg=None, err=0.0))
    for layout in ("grid", "random"):  # JPEG frames and unmodelled shift error: x2, 40 dB
        for b in (0.3, 0.7) if quick else (0.2, 0.5, 0.9):
            out.append(dict(p=2, layout=layout, snr=40, blur=b, jpeg=90, err=0.0))
            out.append(dict(p=2, layout=layout, snr=40, blur=b, jpeg=None, err=0.1))
    return out


def scenes_for(k: int):
    """(crop name, roof) of the two scenes of cell k: a crop as it is and another with a roof."""
    n = len(CROP_NAMES)
    return [(CROP_NAMES[k % n], False), (CROP_NAMES[(k + 1) % n], True)]


def render(
    hr, roof: bool, cell: dict, ff: float, layout_seed: int, noise_seed: int, scene_blur=0.0
):
    """Render one scene of a cell by the independent model: the cell's camera, fill ``ff``.

    ``hr``: the crop (its centre is used); ``scene_blur``: a Gaussian (HR px) applied to the
    scene first (a scene soft in itself); the shifts from ``layout_seed``, the noise from
    ``noise_seed``.
    """
    p = cell["p"]
    n_hr = (LR[p] + 2 * MARGIN) * p
    off = ((768 - n_hr) // 2,) * 2
    sc = scene_crop(hr, p, LR[p], MARGIN, off)
    if scene_blur > 0:
        sc = cv2.GaussianBlur(sc, (0, 0), scene_blur, borderType=cv2.BORDER_REFLECT)
    return degrade(
        sc,
        p,
        shift_layout(cell["layout"], p, seed=layout_seed),
        cell["blur"],
        fill_factor=ff,
        snr_db=cell["snr"],
        jpeg_quality=cell["jpeg"],
        roof=roof,
        seed=noise_seed,
        margin=MARGIN,
    )


def prior_kw(prior: str | None) -> dict:
    """``reconstruct``'s keyword for an image prior (none: the code's default, any version)."""
    return {} if prior is None else {"prior": prior}


def quality(
    quick: bool,
    json_out: str | None,
    only=None,
    cg_lambda=None,
    scene_blur: float = 0.0,
    priors: tuple = (None,),
    flight: bool = False,
) -> None:
    """Print the table; ``only``: (snr, max blur, scene) filters (None: all), same seeds.

    ``flight``: add the column ``flight`` to the "none" scenes (see the module's docstring).

    ``cg_lambda``: CG's weight for every factor (default: tuned on each factor's first cell).
    ``scene_blur``: a Gaussian of this std (HR px) applied to each crop before rendering: a
    scene soft in itself (the truth is the soft crop; a roof is still drawn sharp), which
    translated frames cannot tell from camera blur. ``priors``: the image prior of ``told`` and
    ``auto`` (None: the default), then those compared with it (extra columns).
    """
    snr_only, max_blur, scene_only = only or (None, None, None)
    crops = {c: load_crop(c) for c in CROP_NAMES}
    lam = {} if cg_lambda is None else {p: float(cg_lambda) for p in LR}
    rows = []
    label_auto = "auto" if _AUTO else "default"
    default = inspect.signature(reconstruct).parameters["blur_sigma"].default
    print(
        "\nGain over bicubic (dB) per cell; 'none' = crop as it is, 'edge' = another crop with a "
        f"roof in view; auto column = blur_sigma={_AUTO or f'default ({default})'}"
        + (
            f"; every crop blurred by {scene_blur:g} HR px first (soft scenes)"
            if scene_blur
            else ""
        )
    )
    hdr = (
        f"{'p':>1s} {'layout':6s} {'SNR':>3s} {'blur':>4s} {'extra':9s} | "
        + " | ".join(
            f"{t:4s} {'ff':>3s} {'CG':>6s} {'told':>6s} {'told+w':>6s} {label_auto:>7s} "
            f"{'est':>5s} {'w':>4s} {'src':5s}"
            for t in ("none", "edge")
        )
        + "".join(f" | told:{q[0]} auto:{q[0]}" for q in priors[1:])
        + (f" | {'flight':>6s} {'est':>5s}" if flight else "")
        + " | s"
    )
    print(hdr)
    for k, cell in enumerate(cells(quick)):
        if (snr_only is not None and cell["snr"] != snr_only) or (
            max_blur is not None and cell["blur"] > max_blur + 1e-9
        ):
            continue
        p = cell["p"]
        t0 = time.perf_counter()
        line = []
        tail = ""
        for j, (crop, roof) in enumerate(scenes_for(k)):
            if scene_only is not None and roof != (scene_only == "edge"):
                line.append(" " * 54)
                continue
            ff = FILLS[(k + j) % len(FILLS)]
            fl = render(crops[crop], roof, cell, ff, 100 + k, k * 7 + j, scene_blur)
            sh = est_shifts(fl.frames)
            kw = {}
            if cell["err"]:
                noise = np.random.default_rng(500 + k).normal(0, cell["err"], sh.shape)
                noise[0] = 0
                sh = sh + noise
                kw["refine_shifts"] = False
            keep = np.isfinite(sh).all(axis=1)
            frames = [f for f, ok in zip(fl.frames, keep) if ok]
            sh = sh[keep]
            if (
                p not in lam
            ):  # tune the reference's weight once per factor (first cell, first scene)
                lam[p] = max(
                    (gain(fl, tikhonov_cg(frames, sh, p, lm)), lm)
                    for lm in (0.003, 0.01, 0.03, 0.1)
                )[1]
            g_cg = gain(fl, tikhonov_cg(frames, sh, p, lam[p]))
            kw.update(prior_kw(priors[0]))
            told = reconstruct(frames, sh, p, blur_sigma=cell["blur"], **kw)
            told_fill = (
                reconstruct(frames, sh, p, blur_sigma=cell["blur"], pixel_fill=ff, **kw)
                if _FILL
                else told
            )
            auto = run_auto(frames, sh, p, **kw)
            est = float(getattr(auto, "blur_sigma", np.nan))
            src = str(getattr(auto, "blur_source", "-"))
            rec = dict(
                cell,
                k=k,
                crop=crop,
                roof=roof,
                fill=ff,
                cg=g_cg,
                told=gain(fl, told.image),
                told_fill=gain(fl, told_fill.image),
                auto=gain(fl, auto.image),
                est_fill=float(getattr(auto, "pixel_fill", 1.0)),
                est=est,
                source=src,
                auto_method=auto.method,
                auto_reason=auto.reason,
                blur_reason=str(getattr(auto, "blur_reason", "")),
                lam=lam[p],
                n_frames=len(frames),
            )
            if flight and not roof:
                est_f = flight_blur(crops, k, cell, ff, frames, sh)
                rec["flight"] = gain(fl, reconstruct(frames, sh, p, blur_sigma=est_f, **kw).image)
                rec["flight_est"] = est_f.sigma
                tail = f" | {rec['flight']:+6.2f} {est_f.sigma:5.2f}"
            for q in priors[1:]:  # the same frames with each further prior
                kq = dict(kw, prior=q)
                rec[f"told:{q}"] = gain(
                    fl, reconstruct(frames, sh, p, blur_sigma=cell["blur"], **kq).image
                )
                rec[f"auto:{q}"] = gain(fl, run_auto(frames, sh, p, **kq).image)
            rows.append(rec)
            line.append(
                f"{'':4s} {ff:3.1f} {rec['cg']:+6.2f} {rec['told']:+6.2f} {rec['told_fill']:+6.2f} "
                f"{rec['auto']:+7.2f} {est:5.2f} {rec['est_fill']:4.2f} {src[:5]:5s}"
                + "".join(f" {rec[f'told:{q}']:+6.2f} {rec[f'auto:{q}']:+6.2f}" for q in priors[1:])
            )
        extra = (
            f"jpeg{cell['jpeg']}"
            if cell["jpeg"]
            else (f"err{cell['err']:.1f}px" if cell["err"] else "")
        )
        print(
            f"{p:1d} {cell['layout']:6s} {cell['snr']:3d} {cell['blur']:4.1f} {extra:9s} | "
            + " | ".join(line)
            + tail
            + f" | {time.perf_counter() - t0:4.1f}",
            flush=True,
        )
    summarise(rows, label_auto)
    if flight:
        summarise_flight(rows)
    for q in priors[1:]:
        compare_priors(rows, priors[0] or "default", q)
    if json_out:
        Path(json_out).write_text(json.dumps(rows, indent=1))


def flight_blur(crops, k: int, cell: dict, ff: float, frames, sh):
    """Return the blur ``auto`` holds for this set after an earlier set with the roof.

    The earlier set: cell k's roof scene rendered by the same camera (blur, fill ``ff``, SNR,
    JPEG) with its own noise seed and shifts; both sets go through one ``BlurCalibration``.
    """
    from subpix_ros.core.blur import BlurCalibration

    crop, roof = scenes_for(k)[1]
    earlier = render(crops[crop], roof, cell, ff, 300 + k, k * 7 + 5)
    e_sh = est_shifts(earlier.frames)
    keep = np.isfinite(e_sh).all(axis=1)
    cal = BlurCalibration("auto")
    mono = [np.asarray(f, np.float32) for f, ok in zip(earlier.frames, keep) if ok]
    cal.update(mono, e_sh[keep])
    return cal.update([np.asarray(f, np.float32) for f in frames], sh)


def summarise_flight(rows) -> None:
    """Print the "none" scenes reconstructed with the blur held from an earlier roof set."""
    r = [x for x in rows if "flight" in x]
    if not r:
        return
    f = np.array([x["flight"] for x in r])
    cg = np.array([x["cg"] for x in r])
    told = np.array([x["told"] for x in r])
    auto = np.array([x["auto"] for x in r])
    err = np.array([x["flight_est"] - x["blur"] for x in r])
    print(
        f"\nOver a flight (--flight), {len(r)} scenes without an edge, the blur held from an "
        "earlier set with a roof:"
    )
    print(
        f"  flight: min gain over bicubic {f.min():+.2f} dB (below bicubic: {(f < 0).sum()}); "
        f"flight >= CG + 1 dB in {(f - cg >= 1.0).sum()} of {f.size} (the set alone, auto: "
        f"{(auto - cg >= 1.0).sum()}); told - flight median {np.median(told - f):+.2f}, max "
        f"{(told - f).max():+.2f} dB; flight - auto median {np.median(f - auto):+.2f} dB"
    )
    print(
        f"  blur held: error min {err.min():+.3f} max {err.max():+.3f} px; above the truth by "
        f"> 0.05 px: {(err > 0.05).sum()} of {err.size}"
    )


def compare_priors(rows, base: str, q: str) -> None:
    """Print prior ``q`` against the base prior on the same scene-cells."""
    cg = np.array([r["cg"] for r in rows])
    print(f"\nPrior {q} against {base} ({len(rows)} scene-cells):")
    for col in ("auto", "told"):
        a0 = np.array([r[col] for r in rows])
        a1 = np.array([r[f"{col}:{q}"] for r in rows])
        d = a1 - a0
        print(
            f"  {col:4s}: >= CG + 1 dB in {(a0 >= cg + 1.0).sum()} -> {(a1 >= cg + 1.0).sum()}; "
            f"min gain over bicubic {a0.min():+.2f} -> {a1.min():+.2f} dB; change median "
            f"{np.median(d):+.2f}, worst {d.min():+.2f}, best {d.max():+.2f} dB; "
            f"cells worse by > 0.3 dB: {(d < -0.3).sum()}"
        )


def motion_cells(quick: bool):
    out = []
    for p in (2,) if quick else (2, 4):
        for layout in ("grid", "random"):
            for length in (1.0, 2.0):
                for direction in ((0.8, 0.6), (0.0, 1.0)):
                    out.append(
                        dict(p=p, layout=layout, d=(length * direction[0], length * direction[1]))
                    )
    return out


def motion_quality(quick: bool, json_out: str | None) -> None:
    """Gain over bicubic with motion blur in the frames: ignoring it against told it."""
    crops = {c: load_crop(c) for c in CROP_NAMES}
    blur, snr = 0.3, 40
    print(
        f"\nMotion blur d (LR px) in every frame, optics {blur} px, fill 1.0, {snr} dB, estimated "
        "shifts; gain over bicubic (dB); 'none' = crop as it is, 'edge' = another with a roof"
    )
    print(
        f"{'p':>1s} {'layout':6s} {'d':>11s} | "
        + " | ".join(
            f"{t:4s} {'ignore':>6s} {'told':>6s} {'auto':>6s} {'est':>5s} {'auto+d':>6s} {'est+d':>5s}"
            for t in ("none", "edge")
        )
        + " | s"
    )
    rows = []
    for k, cell in enumerate(motion_cells(quick)):
        p, d = cell["p"], cell["d"]
        t0 = time.perf_counter()
        line = []
        tail = ""
        for j, (crop, roof) in enumerate(scenes_for(k)):
            n_hr = (LR[p] + 2 * MARGIN) * p
            sc = scene_crop(crops[crop], p, LR[p], MARGIN, ((768 - n_hr) // 2,) * 2)
            fl = degrade(
                sc,
                p,
                shift_layout(cell["layout"], p, seed=200 + k),
                blur,
                fill_factor=1.0,
                snr_db=snr,
                roof=roof,
                seed=k * 7 + j,
                margin=MARGIN,
                motion_blur=d,
            )
            sh = est_shifts(fl.frames)
            keep = np.isfinite(sh).all(axis=1)
            frames, sh = [f for f, ok in zip(fl.frames, keep) if ok], sh[keep]
            ignore = reconstruct(frames, sh, p, blur_sigma=blur)
            told = reconstruct(frames, sh, p, blur_sigma=blur, motion_blur=d)
            auto = reconstruct(frames, sh, p, blur_sigma="auto")
            auto_d = reconstruct(frames, sh, p, blur_sigma="auto", motion_blur=d)
            rec = dict(
                cell,
                k=k,
                crop=crop,
                roof=roof,
                ignore=gain(fl, ignore.image),
                told=gain(fl, told.image),
                auto=gain(fl, auto.image),
                auto_d=gain(fl, auto_d.image),
                est=float(auto.blur_sigma),
                source=auto.blur_source,
                est_d=float(auto_d.blur_sigma),
                source_d=auto_d.blur_source,
            )
            rows.append(rec)
            line.append(
                f"{'':4s} {rec['ignore']:+6.2f} {rec['told']:+6.2f} {rec['auto']:+6.2f} "
                f"{rec['est']:5.2f} {rec['auto_d']:+6.2f} {rec['est_d']:5.2f}"
            )
        print(
            f"{p:1d} {cell['layout']:6s} ({d[0]:4.2f},{d[1]:4.2f}) | "
            + " | ".join(line)
            + tail
            + f" | {time.perf_counter() - t0:4.1f}",
            flush=True,
        )
    for key in ("told", "auto_d"):
        base = "ignore" if key == "told" else "auto"
        diff = np.array([r[key] - r[base] for r in rows])
        for length in (1.0, 2.0):
            sel = np.array([abs(np.hypot(*r["d"]) - length) < 1e-9 for r in rows])
            print(
                f"  {key} - {base}, |d| = {length:.0f} px: min {diff[sel].min():+.2f} dB, median "
                f"{np.median(diff[sel]):+.2f}, max {diff[sel].max():+.2f} ({sel.sum()} scene-cells)"
            )
    print(
        f"  told: min gain over bicubic {min(r['told'] for r in rows):+.2f} dB; ignore: "
        f"{min(r['ignore'] for r in rows):+.2f}; auto+d: {min(r['auto_d'] for r in rows):+.2f}"
    )
    if json_out:
        Path(json_out).write_text(json.dumps(rows, indent=1))


def summarise(rows, label_auto):
    a = np.array([r["auto"] for r in rows])
    cg = np.array([r["cg"] for r in rows])
    told = np.array([r["told"] for r in rows])
    roof = np.array([r["roof"] for r in rows])
    est = np.array([r["est"] for r in rows])
    blur = np.array([r["blur"] for r in rows])
    snr = np.array([r["snr"] for r in rows])
    clean = np.array([r["jpeg"] is None and not r["err"] for r in rows])
    print(
        f"\nSummary over {len(rows)} scene-cells (lambda of CG per factor: "
        f"{ {r['p']: r['lam'] for r in rows} })"
    )
    print(
        f"  {label_auto}: min gain over bicubic {a.min():+.2f} dB "
        f"(cells below bicubic: {(a < 0).sum()}); "
        f"told the truth: min {told.min():+.2f} dB; CG: min {cg.min():+.2f} dB"
    )
    d = a - cg
    print(
        f"  {label_auto} - CG: min {d.min():+.2f} dB, median {np.median(d):+.2f}; "
        "cells short of +1.0 dB: "
        f"{(d < 1.0).sum()} of {d.size}"
    )
    e = told[roof] - a[roof]
    if e.size:
        print(
            f"  edge in view: told - {label_auto}: max {e.max():+.2f} dB, median "
            f"{np.median(e):+.2f}; cells beyond 1.0 dB: {(e > 1.0).sum()} of {e.size}"
        )
    if _FILL:
        tw = np.array([r["told_fill"] - r["told"] for r in rows])
        ff = np.array([r["fill"] for r in rows])
        for f in sorted(set(ff) - {1.0}):
            s = ff == f
            print(
                f"  told the fill {f:.1f} too (told+w - told): median {np.median(tw[s]):+.2f} dB, "
                f"{tw[s].min():+.2f} .. {tw[s].max():+.2f} ({s.sum()} scene-cells)"
            )
        ew = np.array([r["est_fill"] for r in rows])
        print(
            f"  {label_auto}: fill measured (< 1) in {(ew < 1).sum()} of {ew.size} scene-cells "
            f"(true fills there: {sorted(ff[ew < 1].tolist())})"
        )
    if np.isfinite(est).any():
        err = est - blur
        sel = roof & clean & (blur <= 0.7) & (snr == 40)
        if sel.any():
            print(
                "  blur estimate, edge scenes, blur <= 0.7, 40 dB: error min "
                f"{err[sel].min():+.3f} max {err[sel].max():+.3f} px; within 0.05 px: "
                f"{(np.abs(err[sel]) <= 0.05).sum()} of {sel.sum()}"
            )
        print(
            f"  blur estimate above the truth by > 0.05 px: {(err > 0.05).sum()} of {err.size} "
            "scene-cells "
            f"(max {err.max():+.3f} px)"
        )
        for src in sorted({r["source"] for r in rows}):
            s = np.array([r["source"] == src for r in rows])
            print(
                f"    source {src}: {s.sum()} scene-cells, error median {np.median(err[s]):+.3f} px"
            )
        stated_uncertainty(rows)


def stated_uncertainty(rows) -> None:
    """Print how often the edge estimate's stated ``+-`` covers its error (full-fill cells).

    The pooled value before its low bias and its uncertainty are read from ``blur_reason``
    (``(raw +- u px``); only cells rendered with the full pixel (fill 1.0) and measured with
    it, where the truth in the model's terms is the rendered blur itself.
    """
    z = []
    for r in rows:
        m = re.search(r"\(([0-9.]+) \+- ([0-9.]+) px", r.get("blur_reason", ""))
        if m and r["source"] == "edges" and r["fill"] == 1.0 and r["est_fill"] == 1.0:
            raw, unc = float(m.group(1)), float(m.group(2))
            z.append((raw - r["blur"]) / max(unc, 1e-9))
    if z:
        z = np.abs(np.array(z))
        print(
            f"  stated uncertainty, edge estimates of full-fill cells: |raw - truth| > 2 u in "
            f"{(z > 2).sum()} of {z.size}, > 3 u in {(z > 3).sum()} (median |z| "
            f"{np.median(z):.2f})"
        )


def timing(repeats: int, priors: tuple = (None,)) -> None:
    """Calibration on 8 frames of 512x512 and one set's reconstruction with a fixed blur vs auto."""
    hr = load_crop("crop_road")
    p = 2
    n_lr = 352  # the crop allows (352 + 16) * 2 = 736 HR px: frames for the reconstruction timing
    sc = scene_crop(hr, p, n_lr, MARGIN, (16, 16))
    fl = degrade(
        sc,
        p,
        shift_layout("random", p, 8, seed=3),
        0.5,
        fill_factor=0.9,
        snr_db=40,
        roof=True,
        margin=MARGIN,
    )
    frames512 = [cv2.resize(f, (512, 512), interpolation=cv2.INTER_CUBIC) for f in fl.frames]
    print(
        f"\nTiming (load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs), "
        f"best / median of {repeats}"
    )
    try:
        from subpix_ros.core.blur import estimate_blur
    except ImportError:
        estimate_blur = None
    if estimate_blur is not None:
        sh = est_shifts(frames512)
        ts = []
        for _ in range(repeats):
            t = time.perf_counter()
            est = estimate_blur(frames512, sh)
            ts.append(time.perf_counter() - t)
        print(
            f"  calibration estimate_blur, 8 frames 512x512: best {min(ts):.3f} s "
            f"median {np.median(ts):.3f} s "
            f"(sigma {est.sigma:.3f} px, source {est.source}, {est.n_edges} edges)"
        )
    sh = est_shifts(fl.frames)
    runs = [
        (f"{name}{'' if q is None else ', ' + q}", dict(kw, **prior_kw(q)))
        for q in priors
        for name, kw in (
            ("fixed blur 0.4", dict(blur_sigma=0.4)),
            ("fixed blur 0.4, shifts as given", dict(blur_sigma=0.4, refine_shifts=False)),
        )
    ]
    for name, kw in runs:
        ts = []
        for _ in range(repeats):
            t = time.perf_counter()
            reconstruct(fl.frames, sh, p, **kw)
            ts.append(time.perf_counter() - t)
        print(
            f"  reconstruct {len(fl.frames)} frames {n_lr}x{n_lr} x{p}, {name:32s}: "
            f"best {min(ts):.3f} s "
            f"median {np.median(ts):.3f} s"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="a smaller grid of cells")
    ap.add_argument(
        "--json", default=None, help="write every scene-cell's figures to this JSON file"
    )
    ap.add_argument("--only", choices=["quality", "timing"], default=None)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument(
        "--motion", action="store_true", help="the motion-blur table instead (ignoring vs told)"
    )
    ap.add_argument("--snr", type=int, default=None, help="only the cells of this SNR (dB)")
    ap.add_argument("--max-blur", type=float, default=None, help="only cells with blur <= this")
    ap.add_argument(
        "--scene", choices=["none", "edge"], default=None, help="only this scene of each cell"
    )
    ap.add_argument(
        "--cg-lambda", type=float, default=None, help="CG's weight (default: tuned per factor)"
    )
    ap.add_argument(
        "--scene-blur",
        type=float,
        default=0.0,
        help="blur every crop by a Gaussian of this std (HR px) before rendering: scenes soft "
        "in themselves, which a blind estimate reads as camera blur (default 0)",
    )
    ap.add_argument(
        "--prior",
        default=None,
        help="image prior(s), comma-separated (e.g. powerlaw,rolloff): the first for told and "
        "auto, the others compared with it on the same frames (default: the code's default)",
    )
    ap.add_argument(
        "--flight",
        action="store_true",
        help="add the 'flight' column: scenes without an edge reconstructed with the blur held "
        "from an earlier set of the same flight with a roof in view",
    )
    args = ap.parse_args()
    priors = (None,) if args.prior is None else tuple(args.prior.split(","))
    print(
        f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs; "
        f"OpenCV threads {cv2.getNumThreads()}"
    )
    if args.motion:
        motion_quality(args.quick, args.json)
        return
    if args.only in (None, "quality"):
        quality(
            args.quick,
            args.json,
            (args.snr, args.max_blur, args.scene),
            args.cg_lambda,
            args.scene_blur,
            priors,
            args.flight,
        )
    if args.only in (None, "timing"):
        timing(args.repeats, priors)


if __name__ == "__main__":
    main()
