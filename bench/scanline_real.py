#!/usr/bin/env python3
# SPDX-License-Identifier: BSD-3-Clause
"""Scan-line range smoothing on real VLP-16 captures: how thick a plane is before and after.

The digital twin's range noise is independent per firing, which is what smoothing along the
scan line removes; a real sensor's is partly systematic. This measures the real thing on the
public captures in ``../shared/data/velodyne`` (read in place): each 50-ms window of points is cut
into 25-cm voxels, and each planar voxel (30+ points; smallest eigenvalue < 0.2 of the middle
one, not a line) gives the RMS distance of its points to their plane. Printed: the median and
25th percentile of that RMS over all windows, for the ranges as measured and smoothed with the
calibration's setting (mean, ±5 firings, 0.1-m step), the fragments' (mean, ±5, 0.15 m) and
the linear fit's (±5, 0.15 m).

    python bench/scanline_real.py [PCAP ...]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "velodyne"
DEFAULT = ["scanparser-vlp16-gaps.pcap", "veloview-vlp16-20hz.pcap"]
#: (label, firings either side, fit, max step [m])
SETTINGS = [("as measured", 0, "mean", 0.1), ("calibration: mean ±5, 0.10 m", 5, "mean", 0.1),
            ("fragments: mean ±5, 0.15 m", 5, "mean", 0.15),
            ("option: linear ±5, 0.15 m", 5, "linear", 0.15)]


def plane_rms_m(xyz: np.ndarray, voxel_m: float = 0.25, min_points: int = 30) -> list[float]:
    """RMS distance [m] of each planar voxel's points to their own plane."""
    v = np.floor(xyz / voxel_m).astype(np.int64)
    _, inv, counts = np.unique(v, axis=0, return_inverse=True, return_counts=True)
    order = np.argsort(inv.ravel(), kind="stable")
    ends = np.cumsum(counts)
    out = []
    for a, b in zip(ends - counts, ends):
        if b - a < min_points:
            continue
        q = xyz[order[a:b]]
        q = q - q.mean(0)
        ev = np.linalg.eigvalsh(q.T @ q / len(q))
        if ev[0] < 0.2 * ev[1] and ev[1] > 0.05 * ev[2]:
            out.append(float(np.sqrt(max(ev[0], 0.0))))
    return out


def main(argv: list[str] | None = None) -> int:
    from tripod_processor.decode.timed import decode_timed_points, denoise_ranges
    from tripod_processor.reconstruction.inputs import read_recording

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("pcaps", nargs="*", help="VLP-16 captures (default: the shared data's)")
    ap.add_argument("--window-s", type=float, default=0.05)
    args = ap.parse_args(argv)
    paths = [Path(p) for p in args.pcaps] or [DATA / n for n in DEFAULT]
    print(f"{'capture':32s} {'ranges':30s} {'voxels':>6s} {'RMS median mm':>14s} {'p25 mm':>7s}")
    for path in paths:
        lidar = read_recording(path).lidar
        pts = decode_timed_points(lidar.payload, lidar.lidar_ns, 0, len(lidar.lidar_ns),
                                  min_range=0.5, max_range=30.0)
        t = pts["time_ns"]
        win = int(args.window_s * 1e9)
        for label, firings, fit, step in SETTINGS:
            rms: list[float] = []
            for w0 in range(int(t.min()), int(t.max()) - win, win):
                m = (t >= w0) & (t < w0 + win)
                if m.sum() >= 2000:
                    rms += plane_rms_m(denoise_ranges(pts[m], firings, step, fit))
            r = np.array(rms) * 1000
            print(f"{path.name:32s} {label:30s} {len(r):6d} {np.median(r):14.1f} "
                  f"{np.percentile(r, 25):7.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
