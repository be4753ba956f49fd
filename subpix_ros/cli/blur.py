"""``subpix blur``: the camera's optics blur, measured on straight edges, as a ``blur_sigma``.

The reconstruction's ``blur_sigma: auto`` measures the blur on straight edges in each flight
and falls back to a low value (0.2 px) where a flight shows none (fields, water, forest).
This command measures it once, from photographs of a slanted-edge target (a dark square on
white paper, tilted 5-10 degrees, at the flight's focus) or from a flight bag that passed
over roofs or road markings, and writes the value for the flights without edges: the
reconstruction takes a given ``blur_sigma`` as a calibration and still checks it against
any edges those flights have.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from subpix_ros.cli import CliError
from subpix_ros.cli._images import luma, read_image

TARGET_HINT = (
    "photograph a straight dark/bright edge tilted 5-10 deg from the image axes (e.g. a black "
    "square on white paper) at the flight's focus, or give a flight over roofs or road markings"
)


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``subpix blur`` subcommand to the CLI's subparsers ``sub``."""
    parser = sub.add_parser(
        "blur",
        help="measure the camera's optics blur on straight edges (images or a bag): blur_sigma",
        description="Measure the optics blur (Gaussian std, input px) on straight edges in "
        "images or in a flight bag's camera frames, pool the frames' estimates (biased low) "
        "and print the blur_sigma to give the reconstruction for this camera's flights "
        "without straight edges. The blur is in pixels of the frames measured: measure at the "
        "resolution and focus the flight's camera topic delivers.",
    )
    parser.add_argument(
        "inputs",
        nargs="+",
        metavar="INPUT",
        help="image files, or a rosbag2 bag (directory, .mcap or .db3)",
    )
    parser.add_argument(
        "--camera-topic",
        default=None,
        metavar="T",
        help="a bag's image topic (default: picked as by process)",
    )
    parser.add_argument(
        "--max-frames",
        type=int,
        default=20,
        metavar="N",
        help="frames measured per bag, spread evenly over it (default 20)",
    )
    parser.add_argument(
        "--yaml",
        default=None,
        metavar="FILE",
        help="write the result as a parameter file (reconstruction_node: blur_sigma) for "
        "--params / --params-file",
    )
    parser.set_defaults(func=run)


def _image_frames(path: Path):
    """Yield ``(label, mono frame)`` of one image file."""
    yield path.name, luma(read_image(path))


def _bag_frames(path: Path, camera_topic: str | None, max_frames: int):
    """Yield ``(label, mono frame)`` of up to ``max_frames`` camera frames spread over a bag."""
    from subpix_ros.io.bags import BagError
    from subpix_ros.process.inputs import InputError, open_flight

    try:
        flight = open_flight(path, camera_topic, None)
    except (InputError, BagError) as exc:
        raise CliError(f"cannot read {path}: {exc}") from None
    if flight.camera_topic is None or not flight.frames_total:
        raise CliError(f"{path}: no camera frames (topics: {', '.join(sorted(flight.topics))})")
    step = max(1, -(-flight.frames_total // max_frames))  # ceil: at most max_frames
    k = 0
    try:
        for kind, item in flight.events():
            if kind == "bad_frame":
                k += 1
                continue
            if kind != "frame":
                continue
            if k % step == 0:
                yield f"{path.name} @ {item.stamp_ns * 1e-9:.3f} s", luma(item.image)
            k += 1
    except BagError as exc:
        raise CliError(f"{path}: {exc}") from None


def _frames(args: argparse.Namespace):
    """Yield ``(label, mono frame)`` of every input, images and bags alike."""
    for name in args.inputs:
        path = Path(name)
        if not path.exists():
            raise CliError(f"cannot read {name}: no such file or directory")
        if path.is_dir() or path.suffix in (".mcap", ".db3"):
            yield from _bag_frames(path, args.camera_topic, args.max_frames)
        else:
            yield from _image_frames(path)


def run(args: argparse.Namespace) -> int:
    """Measure each frame, print each estimate and the pooled blur; write --yaml when asked."""
    from subpix_ros.core.blur import estimate_blur, pool_estimates

    if args.max_frames < 1:
        raise CliError("--max-frames must be >= 1")
    estimates = []
    size = None
    for label, frame in _frames(args):
        this = f"{frame.shape[1]}x{frame.shape[0]}"
        if size is not None and this != size:
            raise CliError(
                f"{label} is {this}, the frames before it {size}: a blur in pixels holds for one "
                "resolution; measure at the one the flight's camera topic delivers"
            )
        size = this
        e = estimate_blur([frame])
        estimates.append(e)
        print(
            f"{label}: " + (f"{e.sigma:.3f} px ({e.reason})" if e.source == "edges" else e.reason)
        )
    if not estimates:  # a bag whose camera frames all failed to decode
        raise CliError("no frame could be decoded: nothing measured")
    pooled = pool_estimates(estimates)
    if pooled.source != "edges":
        raise CliError(
            f"no usable straight edge in {len(estimates)} frames: no blur measured; {TARGET_HINT}"
        )
    fill = f", pixel fill {pooled.fill_factor:.2f}" if pooled.fill_factor < 1.0 else ""
    print(
        f"camera blur: blur_sigma {pooled.sigma:.3f} px of {size} frames ({pooled.reason}{fill}); "
        "give it to the reconstruction for this camera's flights without straight edges, at "
        "this resolution"
    )
    if args.yaml:
        text = (
            f"# subpix blur, {size} frames: {pooled.reason}\n"
            "/**/reconstruction_node:\n"  # the node in any namespace, as config/*.yaml
            "  ros__parameters:\n"
            f'    blur_sigma: "{pooled.sigma:.3f}"\n'
        )
        try:
            Path(args.yaml).write_text(text)
        except OSError as exc:
            raise CliError(f"cannot write {args.yaml}: {exc}") from None
        print(f"parameters: {args.yaml}")
    return 0
