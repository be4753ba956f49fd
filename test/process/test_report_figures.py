"""The report's figures: per-frame plots as PNG (size bounded), each set's offsets as SVG."""

import numpy as np

from subpix_ros.process.report_html import _plt
from subpix_ros.process.report_sections import _img, _offsets_figure, _section_shifts


def _rows(n: int) -> list[dict]:
    """shifts.csv rows of ``n`` converged frames drifting at 0.4 px per frame (strings)."""
    rng = np.random.default_rng(0)
    out = []
    for k in range(n):
        u, v = 0.41 * k + rng.normal(0, 0.002), 0.27 * k + rng.normal(0, 0.002)
        out.append(
            {
                "stamp_ns": str(1_000_000_000 + 100_000_000 * k),
                "converged": "1",
                "u_total_px": f"{u:.4f}",
                "v_total_px": f"{v:.4f}",
                "u_std_px": "0.002",
                "v_std_px": "0.002",
                "u_expected_px": f"{0.41 * k:.4f}",
                "v_expected_px": f"{0.27 * k:.4f}",
                "u_residual_px": f"{u - 0.41 * k:.4f}",
                "v_residual_px": f"{v - 0.27 * k:.4f}",
            }
        )
    return out


def test_a_long_flight_s_shift_trajectory_stays_small():
    """PNG: 2000 frames in ~0.2 MB (as SVG, 2.6 KB per frame: 5 MB)."""
    html = _section_shifts(_rows(2000), 1.0, True)
    assert "data:image/png;base64," in html and "data:image/svg" not in html
    assert len(html) < 400_000, len(html)


def test_a_set_s_offsets_are_a_small_deterministic_svg():
    frac = np.random.default_rng(1).random((16, 2))
    a = _img(_offsets_figure(_plt(), frac, 2), "offsets", vector=True)
    b = _img(_offsets_figure(_plt(), frac, 2), "offsets", vector=True)
    assert a.startswith('<img alt="offsets" src="data:image/svg+xml;base64,')
    assert a == b and len(a) < 40_000  # no date, fixed ids: the same bytes every time


def test_a_set_that_fell_back_is_not_shown_as_super_resolved(tmp_path):
    """The report labels a bicubic fallback as one, beside the set's reason."""
    from subpix_ros.process.report_sections import _section_sets, set_crop

    img = np.random.default_rng(2).integers(0, 256, (64, 64, 3), dtype=np.uint8)
    sets = []
    for k, fell in enumerate((False, True)):
        sets.append(
            {
                "reference_stamp_ns": 10**9 * (k + 1),
                "frames": 16,
                "method": "bicubic" if fell else "map",
                "fell_back": fell,
                "reason": "no plan fits 250 MB" if fell else "",
                "superres": f"superres/{k}.png",
                "bicubic": f"bicubic/{k}.png",
                "members": [],
            }
        )
    crops = {s["superres"]: set_crop(img, img, 2) for s in sets}
    html = _section_sets(tmp_path, sets, 2, 0.0, crops)
    first, second = html.split("<h3>Set 2")
    assert 'alt="set 1: super-resolved"' in first and "fallback" not in first
    assert "fell back: no plan fits 250 MB" in second
    assert 'alt="set 2: bicubic fallback"' in second
    assert "bicubic fallback, not super-resolved" in second and "super-resolved x2" not in second
