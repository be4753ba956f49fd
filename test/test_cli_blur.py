"""`subpix blur`: the camera's blur from straight edges in images or a bag, as a blur_sigma."""

import subprocess

import cv2
import numpy as np
import pytest
import yaml
from conftest import degraded_flight, subpix_cmd

from subpix_ros.core.blur import parse_blur_sigma
from subpix_ros.io.bags import BagWriter
from subpix_ros.nodes.payloads import image_cdr
from subpix_ros.stages import ReconstructionStage

TRUE_BLUR = 0.5  # input px


def _run(*args):
    return subprocess.run(subpix_cmd("blur", *args), capture_output=True, text=True, timeout=120)


def _frames(crop, roof, seed):
    """Frames of the independent degradation model, true blur ``TRUE_BLUR``, 40 dB."""
    return degraded_flight(crop, roof, TRUE_BLUR, shift_seed=seed, noise_seed=seed).frames


@pytest.fixture(scope="module")
def images(tmp_path_factory):
    d = tmp_path_factory.mktemp("blur_images")
    paths = []
    for k, (crop, roof) in enumerate(
        [("crop_road", True), ("crop_trees", True), ("crop_rows", False)]
    ):
        p = d / f"{k}_{crop}.png"
        cv2.imwrite(str(p), _frames(crop, roof, seed=k + 1)[0])
        paths.append(p)
    return paths


def test_images_give_a_low_biased_blur_and_a_parameter_file(images, tmp_path):
    out = tmp_path / "blur.yaml"
    r = _run(*map(str, images), "--yaml", str(out))
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert [ln.split(":")[0] for ln in lines[:3]] == [p.name for p in images]  # one per image
    assert "no usable edge" in lines[2]  # the crop without a roof
    assert "camera blur: blur_sigma" in r.stdout and "2 of 3 frames" in r.stdout
    assert (
        " px of 128x128 frames " in r.stdout and "# subpix blur, 128x128 frames" in out.read_text()
    )
    value = yaml.safe_load(out.read_text())["/**/reconstruction_node"]["ros__parameters"][
        "blur_sigma"
    ]
    sigma = parse_blur_sigma(value)
    assert TRUE_BLUR - 0.15 <= sigma <= TRUE_BLUR + 0.02, sigma  # never much above the truth
    assert ReconstructionStage(blur_sigma=value).blur.setting == sigma  # the node takes it


def test_a_bag_is_sampled_across_its_frames(tmp_path):
    bag = tmp_path / "roof_flight"
    with BagWriter(bag) as w:
        for k, f in enumerate(_frames("crop_road", True, seed=5)):
            t = 1_000_000_000 + k * 100_000_000
            w.write("/camera/image_raw", "sensor_msgs/msg/Image", t, image_cdr(f, t, "cam"))
    r = _run(str(bag), "--max-frames", "3")
    assert r.returncode == 0, r.stderr
    measured = [ln for ln in r.stdout.splitlines() if ln.startswith("roof_flight @ ")]
    assert len(measured) == 3  # 8 frames: every third
    sigma = float(r.stdout.split("camera blur: blur_sigma ")[1].split()[0])
    assert TRUE_BLUR - 0.15 <= sigma <= TRUE_BLUR + 0.02, sigma


def test_no_edge_anywhere_is_a_one_line_error_that_says_what_to_photograph(
    sample_bags, images, tmp_path
):
    r = _run(str(sample_bags / "subpixel"))  # a field crop without a straight edge
    assert r.returncode != 0
    err = r.stderr.strip().splitlines()
    assert len(err) == 1 and "no usable straight edge in 12 frames" in err[0]
    assert "slanted" not in err[0] and "tilted 5-10 deg" in err[0]
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), np.zeros((64, 80), np.uint8))
    r = _run(str(images[0]), str(small))  # pixels of another size: another blur in px
    assert r.returncode != 0 and "small.png is 80x64, the frames before it 128x128" in r.stderr
    junk = tmp_path / "junk_frames"
    with BagWriter(junk) as w:  # image messages that do not decode
        for k in range(3):
            w.write(
                "/camera/image_raw",
                "sensor_msgs/msg/Image",
                k + 1,
                b"\x00\x01\x00\x00" + b"\x07" * 20,
            )
    r = _run(str(junk))
    assert r.returncode != 0 and "no frame could be decoded" in r.stderr, r.stderr
    text = tmp_path / "notes.txt"
    text.write_text("not an image")
    for args, msg in (
        ([str(tmp_path / "missing.png")], "no such file"),
        ([str(text)], "not an image"),
        ([str(text), "--max-frames", "0"], "--max-frames"),
    ):
        r = _run(*args)
        assert r.returncode != 0 and msg in r.stderr and len(r.stderr.strip().splitlines()) == 1
