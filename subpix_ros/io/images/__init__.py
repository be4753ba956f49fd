"""sensor_msgs/Image and sensor_msgs/CompressedImage <-> numpy (numpy/OpenCV only).

Messages are duck-typed: any object with ``height``, ``width``, ``encoding``,
``is_bigendian``, ``step`` and ``data`` works (rclpy ``sensor_msgs.msg.Image``,
a rosbags ``Image``, a dataclass). ``data`` may be ``bytes``, ``bytearray``,
``array.array('B')``, ``memoryview`` or a numpy ``uint8`` array.

Array conventions (shared by all of subpix_ros): images are numpy arrays,
mono ``H x W`` or colour ``H x W x C``; colour is in OpenCV BGR(A) order unless
the encoding says otherwise. Row ``r`` of the message is row ``r`` of the array
(no flips); pixel values are not rescaled except where stated below.

Supported encodings (ROS ``sensor_msgs/image_encodings`` names):

* plain: ``mono8 mono16 bgr8 rgb8 bgra8 rgba8 bgr16 rgb16 bgra16 rgba16`` and
  the generic ``{8,16,32,64}{U,S,F}C{1..4}`` (``8UC1``, ``16UC1``, ``32FC1`` ...;
  valid depths 8U 8S 16U 16S 32S 32F 64F);
* Bayer mosaics ``bayer_rggb8 bayer_bggr8 bayer_gbrg8 bayer_grbg8`` (and the
  ``...16`` variants): demosaiced with OpenCV (bilinear) to BGR; each pixel
  keeps its own measured colour sample, except the 1-pixel image border,
  which OpenCV fills from its neighbours;
* packed YUV 4:2:2: ``yuv422`` = ``uyvy`` (byte order U Y0 V Y1) and
  ``yuv422_yuy2`` = ``yuyv`` (Y0 U Y1 V), old and new names: decoded with
  OpenCV (BT.601) to BGR8.

``desired`` in :func:`image_to_numpy` (decided here, documented once):

* ``"passthrough"`` -- the image as stored, no colour or depth conversion.
  For plain encodings this is a **zero-copy view** into ``data`` (read-only
  when ``data`` is ``bytes``; copy it before writing), ``H x W`` for one
  channel, ``H x W x C`` otherwise, native byte order. Bayer and YUV
  encodings are not usable arrays as stored, so they are decoded to BGR
  (Bayer keeps its bit depth; YUV gives uint8).
* ``"raw"`` -- the stored samples without any decoding, also a zero-copy view:
  Bayer as the ``H x W`` mosaic, YUV 4:2:2 as ``H x W x 2`` bytes.
* ``"bgr8"`` -- ``H x W x 3`` uint8 BGR. Mono is replicated to three channels,
  RGB is reordered, alpha dropped; 16-bit data is scaled by 255/65535 (rounded).
* ``"mono8"`` -- ``H x W`` uint8 luminance: OpenCV's BT.601
  ``Y = 0.299 R + 0.587 G + 0.114 B`` for colour, Bayer demosaiced to grey,
  the video-range Y plane rescaled to 0..255 for YUV; 16-bit scaled by 255/65535.
* ``"mono"`` -- ``H x W`` single-channel luminance in the stored bit depth
  (uint8 stays uint8, 16-bit stays uint16, single-channel signed/float stays
  as is). Float luminance with the METHODS.md A weights is left to ``core``.

Float and signed images have no defined display scale: asking for ``bgr8`` or
``mono8`` from them raises. Generic encodings (``8UC3`` ...) have no colour
order: they convert only to a target with the same number of channels.

Size rules: ``height`` and ``width`` must be positive; ``step`` (bytes per row)
must be at least ``width * channels * bytes_per_sample``; ``data`` must hold
exactly ``step * height`` bytes. Longer data is bad input (issue 7) and is
rejected with the byte counts in the message; pass ``allow_trailing=True`` to
accept and ignore trailing bytes. Every violation raises
:class:`ImageConversionError` (a ``ValueError``) naming the problem; a garbled
array is never returned. Float images may contain NaN/Inf: they are converted
as they are, and :func:`finite_fraction` / :func:`require_finite` let callers
reject them.

Memory: a plain passthrough never copies, so an 8000 x 6000 frame costs no
extra memory; conversions allocate only their output (plus one byte-swapped
copy for big-endian multi-byte data).
"""

from .checks import FrameFormatTracker, finite_fraction, require_finite
from .compressed import (
    compressed_format,
    compressed_to_numpy,
    compressible_encoding,
    numpy_to_compressed,
)
from .encodings import DESIRED, KNOWN_ENCODINGS, EncodingInfo, ImageConversionError, encoding_info
from .raw import image_to_numpy, numpy_to_image_fields

__all__ = [
    "ImageConversionError",
    "EncodingInfo",
    "DESIRED",
    "KNOWN_ENCODINGS",
    "encoding_info",
    "image_to_numpy",
    "numpy_to_image_fields",
    "compressed_format",
    "compressed_to_numpy",
    "compressible_encoding",
    "numpy_to_compressed",
    "finite_fraction",
    "require_finite",
    "FrameFormatTracker",
]
