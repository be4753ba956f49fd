"""``subpix superres`` and ``subpix mtf`` command lines."""

import argparse
import json

import cv2
import numpy as np
import pytest

from subpix_ros.cli import CliError
from subpix_ros.cli import mtf as mtf_cli
from subpix_ros.cli import superres as superres_cli
from subpix_ros.core.render import render_sequence
from subpix_ros.core.superres import bicubic_upscale, psnr


def run(module, argv):
    parser = argparse.ArgumentParser(prog="subpix")
    sub = parser.add_subparsers(dest="command")
    module.register(sub)
    args = parser.parse_args(argv)
    return args.func(args)


@pytest.fixture(scope="module")
def frames(tmp_path_factory, crops):
    d = tmp_path_factory.mktemp("sr")
    seq = render_sequence(
        crops["crop_road"][: 2 * 112, : 2 * 112],
        2,
        [(0, 0), (0, 0.5), (0.5, 0), (0.5, 0.5), (0.3, 0.8)],
        0.4,
        snr_db=40,
        seed=1,
    )
    paths = []
    for i, f in enumerate(seq.frames):
        p = d / f"f{i}.png"
        cv2.imwrite(str(p), f)
        paths.append(str(p))
    shifts = d / "shifts.json"
    shifts.write_text(json.dumps(seq.shifts.tolist()))
    return d, paths, str(shifts), seq


def gain(seq, img):
    return psnr(img, seq.truth, 8) - psnr(bicubic_upscale(seq.frames[0], 2), seq.truth, 8)


def test_superres_with_shift_file_npy(frames, capsys):
    d, paths, shifts, seq = frames
    out = d / "out.npy"
    # the frames' blur (0.4 px, as rendered) given as a lab calibration would be
    assert (
        run(
            superres_cli,
            [
                "superres",
                *paths,
                "--factor",
                "2",
                "--shifts",
                shifts,
                "--blur-sigma",
                "0.4",
                "-o",
                str(out),
            ],
        )
        == 0
    )
    img = np.load(out)
    assert img.shape == seq.truth.shape and img.dtype == np.float64
    assert gain(seq, img) > 4.0
    text = capsys.readouterr().out
    assert "method=map" in text and "blur_sigma=0.400 px (parameter" in text


def test_superres_prior_option(frames, tmp_path):
    """--prior rolloff reaches the solve: another image, still above bicubic."""
    d, paths, shifts, seq = frames
    out = {}
    for prior in ("powerlaw", "rolloff"):
        path = tmp_path / f"{prior}.npy"
        argv = ["superres", *paths, "--shifts", shifts, "--blur-sigma", "0.4"]
        assert run(superres_cli, argv + ["--prior", prior, "-o", str(path)]) == 0
        out[prior] = np.load(path)
    assert not np.array_equal(out["powerlaw"], out["rolloff"])
    assert gain(seq, out["rolloff"]) > 2.0
    with pytest.raises(SystemExit):
        run(superres_cli, ["superres", *paths, "--prior", "flat", "-o", str(tmp_path / "x.npy")])


def test_superres_blur_auto_reports_estimate_and_source(frames, tmp_path, capsys):
    # default --blur-sigma auto: these frames (a field crop) have no straight edge, so the low fallback is
    # used, said so, and the image is still better than bicubic
    d, paths, shifts, seq = frames
    out = tmp_path / "auto.npy"
    assert run(superres_cli, ["superres", *paths, "--shifts", shifts, "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "blur_sigma=0.200 px (fallback: no usable edge" in text
    assert gain(seq, np.load(out)) > 1.0


@pytest.mark.parametrize("bad", ["-0.1", "3.5", "nan", "sharp"])
def test_superres_bad_blur_sigma(frames, tmp_path, bad):
    _, paths, shifts, _ = frames
    with pytest.raises(CliError, match="--blur-sigma"):
        run(
            superres_cli,
            [
                "superres",
                *paths,
                "--shifts",
                shifts,
                "--blur-sigma",
                bad,
                "-o",
                str(tmp_path / "o.png"),
            ],
        )


def test_superres_auto_shifts_png_and_tiff(frames):
    d, paths, _, seq = frames
    png, tif = d / "auto.png", d / "auto.tiff"
    assert run(superres_cli, ["superres", *paths, "--blur-sigma", "0.4", "-o", str(png)]) == 0
    img = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
    assert img.dtype == np.uint8 and img.shape == seq.truth.shape
    assert gain(seq, img.astype(float)) > 4.0
    assert run(superres_cli, ["superres", *paths[:4], "--method", "windowed", "-o", str(tif)]) == 0
    t = cv2.imread(str(tif), cv2.IMREAD_UNCHANGED)
    assert t.dtype == np.float32 and t.shape == seq.truth.shape


def test_superres_colour_frames(frames, tmp_path):
    _, paths, shifts, seq = frames
    colour = []
    for i, p in enumerate(paths):
        g = cv2.imread(p, cv2.IMREAD_GRAYSCALE)
        c = tmp_path / f"c{i}.png"
        cv2.imwrite(str(c), np.dstack([g, g, g]))
        colour.append(str(c))
    out = tmp_path / "c.png"
    assert run(superres_cli, ["superres", *colour, "--shifts", shifts, "-o", str(out)]) == 0
    img = cv2.imread(str(out), cv2.IMREAD_UNCHANGED)
    assert img.shape == seq.truth.shape + (3,)


@pytest.mark.parametrize(
    "argv,match",
    [
        (["--factor", "5"], "factor"),
        (["--factor", "1"], "factor"),
        (["-o", "x.jpg"], "unsupported output"),
    ],
)
def test_superres_user_errors(frames, argv, match):
    d, paths, _, _ = frames
    full = ["superres", *paths, *argv]
    if "-o" not in argv:
        full += ["-o", str(d / "x.png")]
    with pytest.raises(CliError, match=match):
        run(superres_cli, full)


def test_superres_one_frame_mismatch_and_bad_shift_file(frames, tmp_path):
    d, paths, _, _ = frames
    with pytest.raises(CliError, match="at least 2"):
        run(superres_cli, ["superres", paths[0], "-o", str(tmp_path / "o.png")])
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), np.zeros((50, 60), np.uint8))
    with pytest.raises(CliError, match="differ in size"):
        run(superres_cli, ["superres", paths[0], str(small), "-o", str(tmp_path / "o.png")])
    bad = tmp_path / "bad.json"
    bad.write_text("[[0, 0], [0.5]]")
    with pytest.raises(CliError, match="shift file"):
        run(
            superres_cli,
            ["superres", *paths[:2], "--shifts", str(bad), "-o", str(tmp_path / "o.png")],
        )
    with pytest.raises(CliError, match="no such file"):
        run(
            superres_cli,
            ["superres", paths[0], str(tmp_path / "missing.png"), "-o", str(tmp_path / "o.png")],
        )


def test_superres_equal_shifts_reports_fallback(frames, tmp_path, capsys):
    _, paths, _, _ = frames
    same = tmp_path / "same.json"
    same.write_text(json.dumps([[0, 0], [0, 0]]))
    assert (
        run(
            superres_cli,
            ["superres", paths[0], paths[0], "--shifts", str(same), "-o", str(tmp_path / "o.png")],
        )
        == 1
    )
    said = capsys.readouterr()
    assert "fell back" in said.out and "not a super-resolved image" in said.err
    assert (tmp_path / "o.png").is_file()  # the bicubic upscale is still written


def test_mtf_cli(tmp_path, capsys):
    # a blurred straight edge tilted 5 degrees, drawn 8x larger and box-averaged down
    n, ss = 96, 8
    r, c = np.mgrid[0 : n * ss, 0 : n * ss] / ss
    big = np.where((c - n / 2) * np.cos(0.087) - (r - n / 2) * np.sin(0.087) > 0, 200.0, 50.0)
    big = cv2.GaussianBlur(big, (0, 0), 0.6 * ss)
    img = np.rint(big.reshape(n, ss, n, ss).mean(axis=(1, 3))).astype(np.uint8)
    path = tmp_path / "edge.png"
    cv2.imwrite(str(path), img)
    plot = tmp_path / "mtf.png"
    assert (
        run(
            mtf_cli,
            ["mtf", str(path), "--roi", "5,5,80,86", "--pixel-um", "4", "--plot", str(plot)],
        )
        == 0
    )
    out = capsys.readouterr().out
    assert "MTF50" in out and "MTF30" in out and "lp/mm" in out
    assert cv2.imread(str(plot)) is not None
    with pytest.raises(CliError, match="roi"):
        run(mtf_cli, ["mtf", str(path), "--roi", "1,2,3"])
    flat = tmp_path / "flat.png"
    cv2.imwrite(str(flat), np.full((64, 64), 90, np.uint8))
    with pytest.raises(CliError, match="contrast.*give --roi x,y,w,h around one straight edge"):
        run(mtf_cli, ["mtf", str(flat)])
    with pytest.raises(CliError, match="contrast") as err:  # a region was given: no hint
        run(mtf_cli, ["mtf", str(flat), "--roi", "0,0,60,60"])
    assert "--roi" not in str(err.value)


def test_registered_in_the_subpix_tool():
    from subpix_ros.cli import MODULES

    assert "superres" in MODULES and "mtf" in MODULES


def test_superres_motion_blur_reaches_the_model_and_bad_values_are_refused(
    frames, tmp_path, capsys
):
    _, paths, shifts, _ = frames
    base = ["superres", *paths, "--shifts", shifts, "--blur-sigma", "0.4"]
    a, b = tmp_path / "none.npy", tmp_path / "motion.npy"
    assert run(superres_cli, [*base, "-o", str(a)]) == 0
    assert "motion_blur=" not in capsys.readouterr().out
    assert run(superres_cli, [*base, "--motion-blur", "0,1.5", "-o", str(b)]) == 0
    assert "motion_blur=(0.00, 1.50) px" in capsys.readouterr().out
    diff = np.abs(np.load(a).astype(np.float64) - np.load(b).astype(np.float64))
    assert diff.max() > 1.0  # the model's PSF changed
    for bad in ("1", "a,b", "nan,0", "1,2,3"):
        with pytest.raises(CliError, match="--motion-blur"):
            run(superres_cli, [*base, "--motion-blur", bad, "-o", str(tmp_path / "x.npy")])


def test_superres_pixel_fill_reaches_the_model_and_bad_values_are_refused(frames, tmp_path, capsys):
    _, paths, shifts, _ = frames
    base = ["superres", *paths, "--shifts", shifts, "--blur-sigma", "0.3"]
    a, b = tmp_path / "full.npy", tmp_path / "fill.npy"
    assert run(superres_cli, [*base, "-o", str(a)]) == 0
    assert "pixel_fill=1.00" in capsys.readouterr().out
    assert run(superres_cli, [*base, "--pixel-fill", "0.8", "-o", str(b)]) == 0
    assert "pixel_fill=0.80" in capsys.readouterr().out
    diff = np.abs(np.load(a).astype(np.float64) - np.load(b).astype(np.float64))
    assert diff.max() > 0.5  # the model's pixel aperture changed
    for bad in ("0", "1.5", "-0.2"):
        with pytest.raises(CliError, match="--pixel-fill"):
            run(superres_cli, [*base, "--pixel-fill", bad, "-o", str(tmp_path / "x.npy")])


def test_a_given_blur_is_checked_against_the_frames_edges(frames, crops, tmp_path, capsys):
    """A lab value too high is checked against the frames' edges, and said where none is.

    ``--blur-sigma 0.7`` for frames of a 0.3 px camera with a roof in view (the independent
    model): the edges measure lower, their value is used and said; without an edge in view the
    given value stands and the line says nothing checked it.
    """
    from benchmarks.degrade_independent import degrade, scene_crop, shift_layout
    from benchmarks.flight_eval import gain as flight_gain

    sc = scene_crop(crops["crop_road"], 2, 128, 8, (240, 240))
    fl = degrade(sc, 2, shift_layout("random", 2, seed=3), 0.3, roof=True, seed=4, margin=8)
    paths = []
    for i, f in enumerate(fl.frames):
        paths.append(str(tmp_path / f"roof{i}.png"))
        cv2.imwrite(paths[-1], f)
    out = tmp_path / "roof.npy"
    assert run(superres_cli, ["superres", *paths, "--blur-sigma", "0.7", "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "(edges: blur_sigma 0.700 px given, but the edges measure" in text, text
    used = float(text.split("blur_sigma=")[1].split(" px")[0])
    assert used <= 0.35, text
    assert flight_gain(fl, np.load(out)) > 3.0  # 0.7 px as given: below bicubic
    d, plain, shifts, _ = frames  # a road crop without a straight edge
    assert run(superres_cli, ["superres", *plain, "--blur-sigma", "0.4", "-o", str(out)]) == 0
    assert "blur_sigma=0.400 px (parameter: given; not checked: no usable edge" in (
        capsys.readouterr().out
    )


def test_superres_16_bit_frames_give_a_16_bit_png(frames, tmp_path):
    """A 16-bit flight written as .png stays 16-bit (clipped to 8 bits it was all white)."""
    _, paths, shifts, seq = frames
    deep = []
    for i, p in enumerate(paths):
        q = tmp_path / f"d{i}.png"
        cv2.imwrite(str(q), cv2.imread(p, cv2.IMREAD_UNCHANGED).astype(np.uint16) * 257)
        deep.append(str(q))
    out = tmp_path / "deep.png"
    assert run(superres_cli, ["superres", *deep, "--shifts", shifts, "-o", str(out)]) == 0
    img = cv2.imread(str(out), cv2.IMREAD_UNCHANGED)
    assert img.dtype == np.uint16 and img.shape == seq.truth.shape
    assert gain(seq, img.astype(float) / 257.0) > 3.0


def test_superres_frames_of_other_channels_or_depth_are_refused(frames, tmp_path):
    """Grey beside colour and 8- beside 16-bit: said as such (not "differ in size" at one size)."""
    _, paths, _, _ = frames
    g = cv2.imread(paths[1], cv2.IMREAD_UNCHANGED)
    colour, deep = tmp_path / "colour.png", tmp_path / "deep.png"
    cv2.imwrite(str(colour), np.dstack([g, g, g]))
    cv2.imwrite(str(deep), g.astype(np.uint16) * 257)
    for other, said in ((colour, "colour 8-bit"), (deep, "grey 16-bit")):
        with pytest.raises(CliError, match="differ in channels or bit depth") as exc:
            run(superres_cli, ["superres", paths[0], str(other), "-o", str(tmp_path / "o.png")])
        assert said in str(exc.value) and "grey 8-bit" in str(exc.value)
