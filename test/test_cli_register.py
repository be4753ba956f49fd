"""`subpix register` and `subpix mosaic` command lines."""

from __future__ import annotations

import json

import cv2
import numpy as np

from subpix_ros.cli import main
from subpix_ros.data import seneca_frame_paths


def test_register_json_and_aligned_output(tmp_path, capsys):
    a, b = (str(p) for p in seneca_frame_paths()[3:5])
    out = tmp_path / "aligned.png"
    rc = main(["register", a, b, "--json", "-o", str(out)])
    assert rc == 0
    d = json.loads(capsys.readouterr().out)
    h = np.asarray(d["homography"])
    assert h.shape == (3, 3) and d["inliers"] >= 16 and d["rms_px"] < 1.0
    ref = cv2.imread(a)
    assert cv2.imread(str(out)).shape == ref.shape
    # the homography maps MOVING pixels to REF pixels: a tie point pair agrees with it
    from subpix_ros.core.registration import register

    res = register(ref, cv2.imread(b))
    np.testing.assert_allclose(h, res.homography, rtol=1e-6, atol=1e-6)


def test_register_failure_is_one_line_nonzero(tmp_path, capsys):
    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), np.full((200, 300), 100, np.uint8))
    rc = main(["register", str(blank), str(seneca_frame_paths()[0])])
    assert rc != 0
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "blank" in err


def test_register_missing_file(capsys):
    assert main(["register", "/nonexistent/a.png", "/nonexistent/b.png"]) != 0
    assert "cannot read" in capsys.readouterr().err


def test_mosaic_writes_image_and_residuals(tmp_path, capsys):
    out = tmp_path / "m.png"
    frames = [str(p) for p in seneca_frame_paths()[:3]]
    assert main(["mosaic", *frames, "-o", str(out), "--max-size", "600"]) == 0
    text = capsys.readouterr().out
    assert "3/3 frames" in text
    img = cv2.imread(str(out))
    assert img is not None and max(img.shape[:2]) <= 600


def _frames_1200(tmp_path, n=7):
    """``n`` real Seneca frames reduced to 1200x900 (the issue's case)."""
    paths = []
    for i, p in enumerate(seneca_frame_paths()[:n]):
        q = tmp_path / f"f{i}.png"
        cv2.imwrite(
            str(q), cv2.resize(cv2.imread(str(p)), (1200, 900), interpolation=cv2.INTER_AREA)
        )
        paths.append(str(q))
    return paths


def test_mosaic_keeps_input_resolution_by_default(tmp_path, capsys):
    """Seven 1200x900 frames.

    The offline mosaic is drawn at 1 canvas px per frame px (it was 0.43, 594x1128, with the live
    preview's 2048 px bound as the default).
    """
    out = tmp_path / "m.png"
    assert main(["mosaic", *_frames_1200(tmp_path), "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "7/7 frames" in text and "scale 1.000 canvas px per frame px" in text
    assert "scaled" not in text
    img = cv2.imread(str(out))
    # a whole frame fits across the strip, and the strip is longer than 2 frames (was 586x1313)
    assert min(img.shape[:2]) >= 1200 and max(img.shape[:2]) >= 2 * 1200


def test_mosaic_says_when_it_scales(tmp_path, capsys):
    out = tmp_path / "m.png"
    assert main(["mosaic", *_frames_1200(tmp_path, 4), "-o", str(out), "--max-size", "1500"]) == 0
    text = capsys.readouterr().out
    line = next(ln for ln in text.splitlines() if "scaled" in ln)
    assert "--max-size 1500" in line
    img = cv2.imread(str(out))
    assert max(img.shape[:2]) <= 1500


def test_mosaic_help_states_the_bound(capsys):
    import pytest

    with pytest.raises(SystemExit):
        main(["mosaic", "--help"])
    assert "16384" in " ".join(capsys.readouterr().out.split())
