"""Per-frame metadata files (frames.csv with EXIF capture times) read into fixes and trajectories."""

import numpy as np
import pytest

from subpix_ros.data import data_root
from subpix_ros.io.frame_metadata import exif_utc, read_frames_csv, trajectory_from_frames_csv


def test_reads_the_bundled_frames_csv():
    fx = read_frames_csv(data_root() / "seneca" / "frames.csv")
    assert fx.names[0] == "IMG_0461.jpg" and len(fx.names) == 9
    assert fx.t[0] == 1370353145.0  # 2013-06-04 13:39:05 read as UTC
    assert (
        fx.lat_deg[0] == 41.0353080 and fx.lon_deg[0] == -83.3062512 and fx.alt_msl_m[0] == 288.40
    )
    assert np.all(np.diff(fx.t) > 0)


def test_exif_time_is_read_as_utc():
    assert exif_utc("1970:01:01 00:01:40") == 100.0
    with pytest.raises(ValueError, match="EXIF"):
        exif_utc("2013-06-04 13:39:05")


def test_frames_trajectory_rejects_bad_files(tmp_path):
    with pytest.raises(FileNotFoundError):
        trajectory_from_frames_csv(tmp_path / "missing.csv")
    bad = tmp_path / "frames.csv"
    bad.write_text(
        "file,datetime_original,latitude_deg,longitude_deg,gps_altitude_m\n"
        "a.jpg,2013:06:04 13:39:05,41,-83,280\nb.jpg,2013:06:04 13:39:05,41.1,-83,280\n"
    )
    with pytest.raises(ValueError, match="increase"):
        trajectory_from_frames_csv(bad)
    bad.write_text("file,when\na.jpg,x\n")
    with pytest.raises(ValueError, match="columns"):
        trajectory_from_frames_csv(bad)
    bad.write_text(
        "file,datetime_original,latitude_deg,longitude_deg,gps_altitude_m\n"
        "a.jpg,yesterday,41,-83,280\nb.jpg,2013:06:04 13:39:05,41.1,-83,280\n"
    )
    with pytest.raises(ValueError, match="frames.csv.*EXIF"):
        trajectory_from_frames_csv(bad)
