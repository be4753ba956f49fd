"""HTML and figure helpers of the flight report: escaping, tables, embedded PNG figures."""

from __future__ import annotations

import base64
import html
import io
import math
from typing import Any


def _esc(x: Any) -> str:
    return html.escape(str(x))


def _fig_png(fig) -> str:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, metadata={"Software": None})
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _fig_svg(fig) -> str:
    """Return a figure as base64 SVG: vector lines and points, text as text, no date.

    For small plots (a set's offsets: half the cost of its PNG); an SVG grows with its points,
    so per-frame plots stay PNG. The same bytes every run (fixed hash salt for the element
    ids, no date in the metadata).
    """
    import matplotlib
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    with matplotlib.rc_context({"svg.fonttype": "none", "svg.hashsalt": "subpix_ros"}):
        fig.savefig(buf, format="svg", dpi=90, metadata={"Date": None, "Creator": None})
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _svg_img(svg_b64: str, alt: str) -> str:
    """Return an inline base64 SVG figure (:func:`_fig_svg`'s output)."""
    return f'<img alt="{_esc(alt)}" src="data:image/svg+xml;base64,{svg_b64}">'


def _img(fig, alt: str, vector: bool = False) -> str:
    """Return an inline figure: PNG, or SVG with ``vector`` (small plots, no raster image)."""
    if vector:
        return _svg_img(_fig_svg(fig), alt)
    return f'<img alt="{_esc(alt)}" src="data:image/png;base64,{_fig_png(fig)}">'


def _pixels(
    image, alt: str, caption: str, scale: int = 1, box: tuple[int, int, int, int] | None = None
) -> str:
    """Return an image's own pixels as an inline PNG, shown ``scale`` x with square pixels.

    No resampling on the way (the browser enlarges without smoothing): what the product's
    pixels are, at a fraction of a plotted figure's cost. ``box`` ``(top, left, height,
    width)`` in screen px outlines a region above the image (the pixels stay untouched).
    """
    from subpix_ros.io.images.png import encode_png

    data = base64.b64encode(encode_png(image)).decode("ascii")
    w = int(image.shape[1]) * int(scale)
    outline = (
        ""
        if box is None
        else '<span class="roi" style="top:{}px;left:{}px;height:{}px;width:{}px"></span>'.format(
            *(int(v) for v in box)
        )
    )
    return (
        f'<figure class="px"><div class="pxwrap"><img alt="{_esc(alt)}" width="{w}" '
        f'src="data:image/png;base64,{data}">{outline}</div>'
        f"<figcaption>{_esc(caption)}</figcaption></figure>"
    )


def _f(row: dict, key: str) -> float:
    v = row.get(key, "")
    try:
        return float(v) if v not in ("", None) else math.nan
    except ValueError:
        return math.nan


def _table(header: list[str] | None, rows: list[list[Any]]) -> str:
    """Return an HTML table; ``header`` None: no header row (a two-column key/value table)."""
    head = (
        "" if header is None else "<tr>" + "".join(f"<th>{_esc(h)}</th>" for h in header) + "</tr>"
    )
    body = "".join("<tr>" + "".join(f"<td>{_esc(c)}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table>{head}{body}</table>"


def _plural(n: int, word: str, many: str | None = None) -> str:
    """Return ``"1 frame"`` / ``"2 frames"`` (``many``: the plural when not ``word + "s"``)."""
    n = int(n)
    return f"{n} {word if n == 1 else (many or word + 's')}"


def _sig(x: Any, digits: int = 3) -> str:
    """Return a number to ``digits`` significant digits, never rounded to zero (0.00034, 1.23).

    Fixed-point below 1e5 (no exponent for an operator to read); n/a for None or NaN.
    """
    try:
        v = float(x)
    except (TypeError, ValueError):
        return "n/a" if x is None else str(x)
    if not math.isfinite(v):
        return "n/a"
    if v == 0.0:
        return "0"
    if abs(v) >= 1e5 or abs(v) < 1e-6:
        return f"{v:.{digits}g}"
    decimals = max(0, digits - 1 - math.floor(math.log10(abs(v))))
    return f"{v:.{decimals}f}"


def _num(x: Any, fmt: str = "{:.3g}") -> str:
    if x is None:
        return "n/a"
    try:
        return fmt.format(float(x))
    except (TypeError, ValueError):
        return str(x)


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


_CSS = """body{font-family:sans-serif;max-width:1100px;margin:1em auto;color:#222}
table{border-collapse:collapse;margin:.5em 0}
td,th{border:1px solid #bbb;padding:2px 8px;font-size:90%}
th{background:#eee}img{max-width:100%;display:block;margin:.5em 0}.problem{color:#a00}
h2{border-bottom:1px solid #ccc;margin-top:1.5em}code{background:#f4f4f4}
.sets{display:flex;gap:12px;align-items:flex-start;flex-wrap:wrap}
figure.px{margin:.5em 0}figure.px img{image-rendering:pixelated;max-width:none;margin:0}
.pxwrap{position:relative;display:inline-block;line-height:0}
.roi{position:absolute;box-sizing:border-box;border:2px solid #ff0;outline:1px solid #000}
figcaption{font-size:80%;color:#444;max-width:340px}"""
