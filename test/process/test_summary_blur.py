"""``summary.json``'s optics blur: where each set's came from, said in one sentence."""

from subpix_ros.process.flight import _blur_words
from subpix_ros.process.summary import blur_summary


def _set(sigma, source, reason=""):
    return {"blur_sigma": sigma, "blur_source": source, "blur_reason": reason}


def test_a_flight_that_reached_an_edge_gives_its_measurement_as_the_camera_setting():
    sets = [_set(0.2, "fallback"), _set(0.2, "fallback"), _set(0.431, "edges"), _set(0.4, "edges")]
    b = blur_summary(sets)
    assert b["sets_by_source"] == {"edges": 2, "fallback": 2}
    assert b["edges_px"] == 0.4 and b["used_px"] == [0.2, 0.431]  # the last measurement
    assert "2 of 4 sets" in b["note"] and "blur_sigma: 0.400" in b["note"]
    assert _blur_words(b) == " (optics blur 0.400 px from edges)"


def test_a_flight_without_edges_says_it_used_the_fallback_and_what_to_do():
    b = blur_summary([_set(0.2, "fallback", "no usable edge"), _set(0.2, "fallback")])
    assert b["edges_px"] is None and b["sets_by_source"] == {"fallback": 2}
    assert b["note"].startswith("no usable straight edge in this flight: 2 of 2 sets")
    assert "subpix blur" in b["note"]
    assert _blur_words(b) == " (optics blur: fallback 0.20 px, no straight edge)"


def test_a_given_blur_and_no_sets():
    b = blur_summary([_set(0.35, "parameter", "given (edges measure 0.341 +- 0.010 px)")])
    assert b["note"] == "given as blur_sigma: 0.350 px (given (edges measure 0.341 +- 0.010 px))"
    assert _blur_words(b) == " (optics blur 0.350 px given)"
    bicubic_only = [{"blur_sigma": None, "blur_source": None}]  # e.g. method bicubic
    for sets in ([], bicubic_only):
        b = blur_summary(sets)
        assert b["used_px"] is None and b["edges_px"] is None and _blur_words(b) == ""
        assert b["note"] == "no set was reconstructed with an optics model"
