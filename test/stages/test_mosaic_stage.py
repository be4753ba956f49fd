"""MosaicStage: the preview's registration settings reach the core mosaic."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from subpix_ros.data import seneca_frame_paths
from subpix_ros.stages.mosaic import MosaicStage
from subpix_ros.stages.types import Frame


@pytest.fixture(scope="module")
def strip():
    return [cv2.imread(str(p)) for p in seneca_frame_paths()[:4]]


def _tie_points(stage: MosaicStage) -> list[int]:
    return [u.inliers for u in stage.mosaic.updates[1:]]


def test_n_points_sets_the_preview_registration_and_the_seams_hold(strip):
    """Fewer tie points per pair (150, the default, against the core's 700) for the same seams.

    The stage's ``n_points`` is what the registration gets (two thirds of it as the inliers
    wanted before stopping): the inliers found follow it, and the sample strip's seams stay
    within the mosaic's 1 px target either way.
    """
    runs = {}
    for n in (150, 700):
        st = MosaicStage(n_points=n, frame_max_px=1280)
        assert st.mosaic.register_kwargs == {"n_points": n, "want_inliers": 2 * n // 3}
        for k, img in enumerate(strip):
            assert st.add(Frame(k * 1_000_000_000, img)), st.stats.last_warning
        runs[n] = st
    few, many = _tie_points(runs[150]), _tie_points(runs[700])
    assert max(few) < min(many), (few, many)
    for st in runs.values():
        seams = [u.seam_residual_px for u in st.mosaic.updates[1:]]
        assert max(seams) <= 1.0, seams
    assert np.asarray(runs[150].canvas()).shape == np.asarray(runs[700].canvas()).shape
