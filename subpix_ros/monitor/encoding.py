"""Images and stamps as the monitor sends them: 8-bit BGR, shrunk, labelled, JPEG."""

from __future__ import annotations

import math

import cv2
import numpy as np
from foxglove.messages import CompressedImage, Timestamp


def _ts(stamp_ns: int) -> Timestamp:
    return Timestamp(sec=int(stamp_ns // 1_000_000_000), nsec=int(stamp_ns % 1_000_000_000))


def _ts_json(stamp_ns: int) -> dict:
    return {"sec": int(stamp_ns // 1_000_000_000), "nsec": int(stamp_ns % 1_000_000_000)}


def _num(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(float(x)) else float(x)


#: Decimals of a served shift (px): 1e-5 px, far below the estimator's best standard error
#: (about 1e-3 px), so the operator's figures do not change while each message is a fifth shorter.
SHIFT_DECIMALS = 5
#: Significant digits of a served standard error.
STD_DIGITS = 3
#: Significant digits of a served telemetry figure (a 56 m height to the mm, an interval to 0.1 ms).
TELEMETRY_DIGITS = 5


def _px(x: float | None) -> float | None:
    """Return a finite shift (px) rounded to :data:`SHIFT_DECIMALS`, else None."""
    x = _num(x)
    return None if x is None else round(x, SHIFT_DECIMALS)


def _sig(x: float | None, digits: int = STD_DIGITS) -> float | None:
    """Return a finite value rounded to ``digits`` significant digits, else None."""
    x = _num(x)
    return None if x is None else float(f"{x:.{digits}g}")


def _to_bgr(image: np.ndarray) -> np.ndarray:
    if image.ndim == 2 or (image.ndim == 3 and image.shape[2] == 1):
        return image.reshape(image.shape[:2])
    if image.ndim == 3 and image.shape[2] in (3, 4):
        return image[:, :, :3]
    raise ValueError(f"monitor: image of shape {image.shape} is neither mono nor colour")


def _to_u8(image: np.ndarray) -> np.ndarray:
    if image.dtype == np.uint8:
        return image
    if image.dtype == np.uint16:
        return (image >> 8).astype(np.uint8)
    return np.clip(image, 0, 255).astype(np.uint8)


def _shrink(image: np.ndarray, max_px: int) -> np.ndarray:
    h, w = image.shape[:2]
    s = max_px / max(h, w)
    if s >= 1.0:
        return image
    return cv2.resize(
        image, (max(1, round(w * s)), max(1, round(h * s))), interpolation=cv2.INTER_AREA
    )


def _label(image: np.ndarray, text: str) -> np.ndarray:
    out = (
        cv2.cvtColor(image, cv2.COLOR_GRAY2BGR) if image.ndim == 2 else np.ascontiguousarray(image)
    )
    scale = max(0.4, out.shape[1] / 900)
    th = max(1, round(scale * 2))
    (tw, tht), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, th)
    cv2.rectangle(out, (0, 0), (tw + 8, tht + base + 8), (0, 0, 0), -1)
    cv2.putText(
        out, text, (4, tht + 4), cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), th, cv2.LINE_AA
    )
    return out


def sr_label(detail: str, fallback: str | None = None) -> str:
    """Return the label of a super-resolved crop (``detail``: factor and crop window).

    With ``fallback`` (why the reconstruction fell back) the crop is the bicubic upscale of
    the reference and says so, with the reason cut to 60 characters.
    """
    if fallback is None:
        return "super-resolved" + detail
    why = " ".join(str(fallback).split())
    return f"BICUBIC FALLBACK, not super-resolved{detail}: {why[:60] or 'no reason given'}"


def same_as_bicubic(sr: np.ndarray, bicubic: np.ndarray, crop: int = 256) -> bool:
    """Return True if the central ``crop`` square of ``sr`` is ``bicubic``'s to within 1 DN.

    How a monitor fed over DDS (an ``Image`` carries no "fell back" flag) tells a
    reconstruction's bicubic fallback: that image is the reference's bicubic upscale (rounded
    from float32, so within 1 DN of OpenCV's integer bicubic); a super-resolved image of a
    textured scene differs by several DN.
    """
    h, w = sr.shape[:2]
    r0, c0 = max(0, (h - crop) // 2), max(0, (w - crop) // 2)
    a = sr[r0 : r0 + crop, c0 : c0 + crop]
    b = bicubic[r0 : r0 + crop, c0 : c0 + crop]
    if a.shape != b.shape or a.size == 0:
        return False
    return bool(cv2.norm(a, b, cv2.NORM_INF) <= 1.0)


def _jpeg(img: np.ndarray, quality: int, stamp_ns: int, frame_id: str) -> bytes:
    ok, buf = cv2.imencode(
        ".jpg", np.ascontiguousarray(img), [cv2.IMWRITE_JPEG_QUALITY, int(quality)]
    )
    if not ok:
        raise ValueError("JPEG encoding failed")
    return CompressedImage(
        timestamp=_ts(stamp_ns), frame_id=frame_id, data=buf.tobytes(), format="jpeg"
    ).encode()
