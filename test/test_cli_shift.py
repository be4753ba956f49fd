"""``subpix shift`` and ``subpix interval`` command lines."""

import json
import math
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from subpix_ros.cli import main
from subpix_ros.core.render import render_sequence


@pytest.fixture(scope="module")
def pair_files(crops, tmp_path_factory):
    d = tmp_path_factory.mktemp("shift")
    seq = render_sequence(
        crops["crop_rows"][:384, :384], 3, [(0, 0), (0.37, -0.62)], blur_sigma=0.4, snr_db=40
    )
    ref, mov = d / "ref.png", d / "mov.png"
    cv2.imwrite(str(ref), seq.frames[0])
    cv2.imwrite(str(mov), seq.frames[1])
    # the same pair as colour (BGR) files: grey replicated in 3 channels
    refc, movc = d / "ref_c.png", d / "mov_c.png"
    cv2.imwrite(str(refc), cv2.cvtColor(seq.frames[0], cv2.COLOR_GRAY2BGR))
    cv2.imwrite(str(movc), cv2.cvtColor(seq.frames[1], cv2.COLOR_GRAY2BGR))
    flat = d / "flat.png"
    cv2.imwrite(str(flat), np.full((64, 64), 90, np.uint8))
    return dict(
        ref=str(ref),
        mov=str(mov),
        refc=str(refc),
        movc=str(movc),
        flat=str(flat),
        truth=(0.37, -0.62),
    )


def test_shift_json(pair_files, capsys):
    assert main(["shift", pair_files["ref"], pair_files["mov"], "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    for key in ("u", "v", "u_std", "v_std", "converged"):
        assert key in out
    assert out["ok"] is True and out["converged"] is True
    assert out["u"] == pytest.approx(0.37, abs=0.01)
    assert out["v"] == pytest.approx(-0.62, abs=0.01)
    assert 0 < out["u_std"] < 0.01


def test_shift_text_and_colour_input(pair_files, capsys):
    assert main(["shift", pair_files["refc"], pair_files["movc"]]) == 0
    text = capsys.readouterr().out
    u = float(text.split("u =")[1].split("px")[0])
    v = float(text.split("v =")[1].split("px")[0])
    assert u == pytest.approx(0.37, abs=0.01) and v == pytest.approx(-0.62, abs=0.01)
    assert "converged: yes" in text


def test_shift_seed_method(pair_files, capsys):
    assert main(["shift", pair_files["ref"], pair_files["mov"], "--json", "--method", "seed"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["method"] == "seed" and out["u"] > 0 and out["v"] < 0


def test_shift_failure_is_one_line_and_nonzero(pair_files, capsys):
    rc = main(["shift", pair_files["flat"], pair_files["flat"]])
    err = capsys.readouterr().err
    assert rc != 0
    assert len(err.strip().splitlines()) == 1 and "textureless" in err
    rc = main(["shift", pair_files["flat"], pair_files["flat"], "--json"])
    cap = capsys.readouterr()
    assert rc != 0 and json.loads(cap.out)["ok"] is False and json.loads(cap.out)["u"] is None
    assert main(["shift", pair_files["ref"], "/nonexistent.png"]) != 0
    assert "not found" in capsys.readouterr().err
    folder = str(Path(pair_files["ref"]).parent)
    assert main(["shift", folder, pair_files["ref"]]) != 0
    assert f"reference {folder} is a folder: give an image file" in capsys.readouterr().err
    assert main(["shift", pair_files["ref"], pair_files["flat"]]) != 0
    assert "differ in size" in capsys.readouterr().err
    # an 8-bit frame against a 16-bit one: said, not a Gauss-Newton failure
    mov16 = str(Path(pair_files["mov"]).with_name("mov16.png"))
    cv2.imwrite(mov16, cv2.imread(pair_files["mov"], cv2.IMREAD_UNCHANGED).astype(np.uint16) * 257)
    assert main(["shift", pair_files["refc"], mov16]) != 0
    assert "differ in bit depth (uint8 vs uint16)" in capsys.readouterr().err


def test_shift_as_a_process(pair_files):
    p = subprocess.run(
        [
            sys.executable,
            "-m",
            "subpix_ros.cli",
            "shift",
            pair_files["ref"],
            pair_files["mov"],
            "--json",
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert p.returncode == 0, p.stderr
    assert json.loads(p.stdout)["u"] == pytest.approx(0.37, abs=0.01)


def _interval(*extra: str) -> int:
    """`subpix interval` at 60 m, 10 m/s, f 4.3 mm, 1.54 um pixels, plus ``extra``."""
    args = ["interval", "--height-m", "60", "--speed-mps", "10", "--focal-mm", "4.3"]
    return main([*args, "--pixel-um", "1.54", *extra])


def test_interval_hand_value(capsys):
    # t = 1.54e-6 * 60 / (2 * 4.3e-3 * 10) = 1.0744 ms
    assert _interval("--p", "2") == 0
    text = capsys.readouterr().out
    assert "t = 1.074 ms" in text and "phi = 0 deg" in text
    assert _interval("--p", "4", "--rotate", "--json") == 0
    out = json.loads(capsys.readouterr().out)
    assert out["phi_deg"] == pytest.approx(math.degrees(math.atan(1 / 3)))
    assert out["interval_s"] == pytest.approx(
        1.54e-6 * 60 * 3 / math.sqrt(10) / (4 * 4.3e-3 * 10), rel=1e-12
    )
    assert _interval("--p", "2", "--phi-deg", "30") == 0
    assert "phi = 30 deg" in capsys.readouterr().out


@pytest.mark.parametrize(
    "argv,word",
    [
        (["--speed-mps", "0"], "speed"),
        (["--speed-mps", "-3"], "speed"),
        (["--height-m", "0"], "height"),
        (["--p", "1"], "p must"),
    ],
)
def test_interval_bad_input(argv, word, capsys):
    base = {
        "--height-m": "60",
        "--speed-mps": "10",
        "--focal-mm": "4.3",
        "--pixel-um": "1.54",
        "--p": "2",
    }
    base.update(dict(zip(argv[::2], argv[1::2])))
    args = ["interval"] + [x for kv in base.items() for x in kv]
    assert main(args) != 0
    err = capsys.readouterr().err
    assert word in err and len(err.strip().splitlines()) == 1
