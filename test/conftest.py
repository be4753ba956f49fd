import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from subpix_ros.data import CROP_NAMES, load_crop  # noqa: E402


@pytest.fixture(scope="session")
def crops():
    """The four real full-resolution Seneca luminance crops (uint8, 768x768)."""
    return {name: load_crop(name) for name in CROP_NAMES}
