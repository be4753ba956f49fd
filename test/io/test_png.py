"""PNG products: whichever encoder writes them, they decode to the exact pixels given."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from subpix_ros.io.images import png


def _images():
    rng = np.random.default_rng(3)
    yield "bgr8", rng.integers(0, 256, (37, 53, 3), dtype=np.uint8)
    yield "bgra8", rng.integers(0, 256, (20, 31, 4), dtype=np.uint8)
    yield "mono8", rng.integers(0, 256, (19, 23), dtype=np.uint8)
    yield "bgr16", rng.integers(0, 65536, (17, 29, 3), dtype=np.uint16)
    yield "mono16", rng.integers(0, 65536, (11, 13), dtype=np.uint16)
    # a smooth image (what products look like: the filters and compression do real work)
    y, x = np.mgrid[0:120, 0:160]
    smooth = np.stack([x, y, (x + y) // 2], axis=-1).astype(np.uint8)
    yield "smooth bgr8", np.ascontiguousarray(smooth)
    yield "non-contiguous bgr8", smooth[::2, ::3]


@pytest.mark.parametrize("fast", [True, False], ids=["fpng if installed", "opencv"])
@pytest.mark.parametrize("name,image", list(_images()), ids=[n for n, _ in _images()])
def test_png_round_trip_is_exact(tmp_path, monkeypatch, fast, name, image):
    if not fast:
        monkeypatch.setattr(png, "_fpng", lambda: None)
    path = tmp_path / "x.png"
    png.write_png(path, image)
    back = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert back is not None and back.dtype == image.dtype
    assert np.array_equal(back, image), name


def test_8bit_colour_goes_through_fpng_when_installed():
    pytest.importorskip("fpng")  # optional dependency; requirements.txt installs it
    img = np.zeros((64, 64, 3), np.uint8)
    img[:, 32:] = (10, 200, 90)
    data = png.encode_png(img)
    # OpenCV (libpng) writes with zlib's compression; fpng's stream is its own: tell them apart
    assert data != cv2.imencode(".png", img)[1].tobytes()
    assert png.fast_png_available()


def test_a_failing_fast_encoder_falls_back_to_opencv(monkeypatch):
    class Broken:
        @staticmethod
        def encode_ndarray(a):
            return b""  # what the binding returns on failure (no exception)

    monkeypatch.setattr(png, "_fpng", lambda: Broken)
    img = np.full((8, 9, 3), 7, np.uint8)
    assert png.encode_png(img) == cv2.imencode(".png", img)[1].tobytes()


def test_an_image_no_encoder_takes_is_a_clear_error():
    with pytest.raises(ValueError, match="cannot encode"):
        png.encode_png(np.zeros((4, 4, 2), np.float64))
