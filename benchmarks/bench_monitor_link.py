#!/usr/bin/env python3
"""Live monitor on a small link: kbit/s per channel with six nodes' statuses, a long track, footprints.

A :class:`subpix_ros.monitor.Monitor` at ``--kbps`` (default 100: a telemetry radio) is fed what a
flight's operator link carries besides the images: six nodes' /diagnostics at 1 Hz with the key
sets the nodes report while running (about 50 keys each: the stage's counters, rates, latencies,
process load), a survey track of ``--track`` GNSS fixes already flown (lawnmower legs with 0.5 m
of noise) and 5 fixes/s more, a footprint per camera frame served (4/s, as ``monitor_node`` draws
them), shifts at ``--shift-hz`` and telemetry at 5 Hz; plus the images (a 640-px camera frame,
a 1800-px mosaic changing every 2 s, a super-resolved pair every 4 s). A foxglove.sdk.v1 client in
this process subscribes to everything and the table gives what it received per channel over the
last ``--seconds - 4`` s (after the start-up burst).

``python benchmarks/bench_monitor_link.py --kbps 100``; :class:`Flight` is the tests' feeder too
(``test/monitor/test_monitor_budget.py``).
"""

from __future__ import annotations

import argparse
import math
import sys
import threading
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from subpix_ros.monitor import TOPICS, Monitor, MonitorConfig  # noqa: E402
from subpix_ros.monitor.client import FoxgloveClient  # noqa: E402
from subpix_ros.monitor.geo import EARTH_RADIUS_M, footprint_lonlat  # noqa: E402

LAT0, LON0 = 42.8, -76.7
T0 = 1_700_000_000_000_000_000

# what every node reports (StageNode: process, DDS profile, diagnostics totals)
_COMMON = {
    "errors_total": "0",
    "executor": "single",
    "fastdds_profile": "/opt/subpix/share/subpix_ros/config/fastdds_large_messages.xml",
    "last_error": "",
    "opencv_threads": "2",
    "process_cpu_cores": "0.69",
    "process_rss_mb": "412",
    "process_rss_peak_mb": "466",
    "recent_problems": "",
    "started_unix_s": "1795971905.5",
    "warnings_total": "0",
}
# a stage node's worker and rates, on top
_STAGE = {
    "dropped_frames": "0",
    "queue_depth": "0",
    "worker_cpu_ms_per_item": "41.2",
    "worker_errors": "0",
    "input_hz": "10.000",
    "input_total": "0",
    "output_hz": "10.000",
    "output_total": "0",
    "latency_p50_ms": "48.1",
    "latency_max_ms": "97.3",
    "dropped": "0",
    "errors": "0",
    "fallbacks": "0",
    "frames_in": "0",
    "kept": "0",
    "last_warning": "",
    "resets": "0",
    "skipped": "0",
    "warnings": "0",
}
# each node's own keys, as results.mcap of the sample flights records them
NODES = {
    "registration_node": {
        "inliers": "737",
        "last_selection": "step 0.491 px ~ 1/p = 0.5 px",
        "last_tracking_fallback": "tracking lost: 10 of 548 tie points consistent with the prior",
        "reference_reason": "set complete",
        "reference_stamp_ns": "1717000000533333248",
        "references": "3",
        "references_predicted": "0",
        "registration_failures": "0",
        "rms_along_px": "0.01007836567",
        "rms_cross_px": "0.006068862114",
        "rms_px": "0.01176454597",
        "telemetry_agrees": "1",
        "telemetry_check": "agrees: the frames moved 1.001x (+- 0.001) the telemetry's expected "
        "shift, rotated -0.0 deg (+- 0.1), over 21 frame pairs",
        "telemetry_pairs": "21",
        "telemetry_rotation_deg": "-0.007131018597",
        "telemetry_scale": "1.001251002",
        "tracked": "20",
        "warped": "0",
        "register_ms_p50": "38.2",
        "register_ms_max": "75.9",
    },
    "shift_node": {
        "cond": "46.19156773",
        "iterations": "2",
        "pixels": "189660",
        "u": "-0.1301690185",
        "u_std": "0.0003337983861",
        "v": "-0.1099231401",
        "v_std": "0.0002889870944",
        "shift_failures": "0",
        "shift_ms_p50": "12.1",
        "shift_ms_max": "20.4",
    },
    "reconstruction_node": {
        "fallback_reason": "",
        "fell_back": "0",
        "frames": "8",
        "frames_without_shift": "0",
        "memory_estimate_mb": "71.9",
        "memory_reduced": "0",
        "memory_reduction": "",
        "method": "map",
        "motion_blur_px": "",
        "noise_sigma": "0.7109675432",
        "pending_sets": "0",
        "released_mb": "",
        "sets_complete": "3",
        "sets_dropped": "0",
        "sets_flushed": "0",
        "sets_incomplete": "0",
        "sets_skipped_budget": "0",
        "shifts_disputed": "0",
        "workspace_mb": "17.5",
        "reconstruct_ms_p50": "812.0",
        "reconstruct_ms_max": "1411.3",
    },
    "mosaic_node": {
        "frames_added": "24",
        "frames_skipped": "0",
        "in_canvas": "24",
        "seam_residual_px": "0.01402616952",
        "add_ms_p50": "21.7",
        "add_ms_max": "44.0",
    },
    "telemetry_node": {
        "link": "open",
        "gnss_status": "0",
        "fix_hz": "5.000",
        "fix_total": "0",
        "heartbeat_age_s": "0.4",
        "system_id": "1",
    },
    "monitor_node": {
        "budget_kbps": "100.0",
        "sent_kbps": "99.1",
        "clients": "1",
        "camera_quality": "25",
        "camera_sent": "0",
        "mosaic_quality": "25",
        "mosaic_sent": "0",
        "sr_quality": "25",
        "sr_sent": "0",
        "shifts_without_std": "0",
        "stale_nodes": "none",
        "telemetry_age_s": "0.2",
        "images_hz": "10.000",
        "images_total": "0",
        "input_hz": "25.000",
        "input_total": "0",
    },
}


def statuses(t: float) -> list[dict]:
    """Six nodes' statuses at ``t`` s into the flight: the counters and rates move each second."""
    out = []
    for k, (name, own) in enumerate(NODES.items()):
        values = dict(_COMMON, pid=str(4100 + k), **own)
        if name not in ("telemetry_node", "monitor_node"):
            values.update(_STAGE)
        for key in list(values):
            if key.endswith("_total") or key in ("frames_in", "kept", "inliers"):
                values[key] = str(int(10 * t) + k)
            elif key.endswith("_hz"):
                values[key] = f"{9.95 + 0.01 * ((int(t) + k) % 9):.3f}"
        values["process_cpu_cores"] = f"{0.5 + 0.01 * ((int(t) * 7 + k) % 40):.2f}"
        out.append({"name": name, "level": 0, "message": "ok", "values": values})
    return out


def survey(n: int, speed_mps: float = 10.0, rate_hz: float = 5.0, seed: int = 1) -> list:
    """Return a lawnmower survey: ``n`` fixes (lon, lat) at ``rate_hz``, 300 m legs 50 m apart."""
    rng = np.random.default_rng(seed)
    step = speed_mps / rate_hz
    leg, gap = 300.0, 50.0
    pts = []
    for i in range(n):
        s = i * step
        k, r = divmod(s, leg + gap)
        if r < leg:
            e, nn = (r if k % 2 == 0 else leg - r), k * gap
        else:
            e, nn = (leg if k % 2 == 0 else 0.0), k * gap + (r - leg)
        e, nn = e + rng.normal(0, 0.5), nn + rng.normal(0, 0.5)
        lat = LAT0 + math.degrees(nn / EARTH_RADIUS_M)
        lon = LON0 + math.degrees(e / (EARTH_RADIUS_M * math.cos(math.radians(LAT0))))
        pts.append((lon, lat))
    return pts


def images():
    """Return a camera frame (640x480), a mosaic (1800x1350), a super-resolved crop (640x640)."""
    src = cv2.imread(str(sorted((ROOT / "data" / "seneca").glob("*.jpg"))[0]), cv2.IMREAD_COLOR)
    camera = cv2.resize(src, (640, 480), interpolation=cv2.INTER_AREA)
    mosaic = cv2.resize(src, (1800, 1350), interpolation=cv2.INTER_AREA)
    sr = cv2.resize(camera[:320, :320], (640, 640), interpolation=cv2.INTER_CUBIC)
    return camera, mosaic, sr


class Flight:
    """Feed a monitor as a flight would, in a thread, until :meth:`stop`.

    Shifts at ``shift_hz`` (every camera frame), telemetry and fixes at 5 Hz, a footprint with
    each of the 4 camera frames per second the monitor takes, six nodes' statuses at 1 Hz, the
    mosaic every 2 s and a super-resolved pair every 4 s. ``track`` fixes are flown at once
    (the map's track is long already): before a client connects, so they cost the link nothing;
    :meth:`start` starts the flight.
    """

    def __init__(self, mon: Monitor, *, shift_hz: float = 10.0, track: int = 2000) -> None:
        self.mon, self.shift_hz = mon, shift_hz
        self.path = survey(track + 20000)
        self.k = 0
        for lon, lat in self.path[:track]:
            self.mon.on_fix(lat, lon, 120.0, T0)
            self.k += 1
        self.camera, self.mosaic, self.sr = images()
        self.fed_shifts = 0
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)

    def start(self) -> "Flight":
        """Start feeding (a thread)."""
        self.thread.start()
        return self

    def _run(self) -> None:
        dt = 0.05  # 20 Hz tick
        i, t0 = 0, time.monotonic()
        next_shift = 0.0
        while not self._stop.is_set():
            t = i * dt
            stamp = T0 + int(t * 1e9)
            if t >= next_shift:
                next_shift += 1.0 / self.shift_hz
                u = 0.41 + 0.01 * math.sin(t)
                self.mon.on_shift(stamp, u, 0.27, 0.0003337983861, 0.0002889870944, True, 0.4, 0.3)
                self.fed_shifts += 1
            if i % 4 == 0:  # 5 Hz: fix, telemetry
                lon, lat = self.path[self.k % len(self.path)]
                self.k += 1
                self.mon.on_fix(lat, lon, 120.0, stamp)
                self.mon.on_telemetry(
                    stamp,
                    expected_u=0.4,
                    expected_v=0.3,
                    speed_mps=10.0 + 0.1 * math.sin(t),
                    height_m=120.0,
                    frame_interval_s=0.1,
                )
            if i % 5 == 0:  # 4 Hz: a camera frame and its footprint
                self.mon.on_camera(self.camera, stamp)
                lon, lat = self.path[self.k % len(self.path)]
                self.mon.on_footprint(
                    footprint_lonlat(lat, lon, 120.0, 0.3, 640, 480, 4.3, 1.54), stamp
                )
            if i % 20 == 0:
                self.mon.on_diagnostics(statuses(t))
            if i % 40 == 0:
                self.mon.on_mosaic(np.roll(self.mosaic, i, axis=1), stamp)
            if i % 80 == 0:
                self.mon.on_super_resolved(self.sr, self.sr, stamp, 2)
            i += 1
            time.sleep(max(0.0, t0 + i * dt - time.monotonic()))

    def stop(self) -> None:
        """Stop feeding."""
        self._stop.set()
        self.thread.join()


def per_channel_kbps(client: FoxgloveClient, lo: float, hi: float) -> dict[str, float]:
    """Return what ``client`` received per topic between monotonic ``lo`` and ``hi``, kbit/s."""
    return {
        t: sum(r.wire for r in client.messages(t) if lo <= r.t < hi) * 8 / 1000 / (hi - lo)
        for t in TOPICS
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kbps", type=float, default=100.0, help="bandwidth_kbps")
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--shift-hz", type=float, default=10.0)
    ap.add_argument("--track", type=int, default=2000, help="fixes flown before the start")
    a = ap.parse_args()

    mon = Monitor(MonitorConfig(port=0, bandwidth_kbps=a.kbps))
    flight = Flight(mon, shift_hz=a.shift_hz, track=a.track)
    client = FoxgloveClient(mon.url)
    client.wait(lambda: len(client.channels) == len(TOPICS), 10)
    time.sleep(0.3)
    start = time.monotonic()
    flight.start()
    time.sleep(a.seconds)
    end = time.monotonic()
    flight.stop()
    stats = mon.link_stats()
    problem = getattr(mon, "budget_problem", lambda: None)()
    client.close()
    mon.close()
    kbps = per_channel_kbps(client, start + 4.0, end)
    essential = [t for t in TOPICS if not TOPICS[t].endswith("CompressedImage")]
    print(
        f"bandwidth_kbps {a.kbps:g}, 6 nodes, {a.track} fixes flown + 5/s, "
        f"shifts {a.shift_hz:g}/s, {a.seconds - 4:g} s window\n"
    )
    print("| channel | kbit/s | messages | bytes/message |\n|---|---|---|---|")
    for t in TOPICS:
        msgs = [r for r in client.messages(t) if start + 4.0 <= r.t < end]
        size = sum(r.wire for r in msgs) / len(msgs) if msgs else 0
        print(f"| {t} | {kbps[t]:.1f} | {len(msgs)} | {size:.0f} |")
    ess = sum(kbps[t] for t in essential)
    print(f"| essentials | {ess:.1f} ({100 * ess / a.kbps:.0f} % of the budget) | | |")
    print(f"| images | {sum(kbps.values()) - ess:.1f} | | |")
    print(f"| total | {sum(kbps.values()):.1f} | | |")
    print(f"\nrungs {stats['levels']}")
    if problem:
        print(f"monitor says: {problem}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
