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
