# SPDX-License-Identifier: BSD-3-Clause
"""Compression benchmark: tripod's codec (auto: learned octree or predictive scan coding) against
Google Draco, side by side.

Clouds: held-out simulated fragments (by default one station of ``tripod simulate`` in a room
and in an office, with seeds the shipped model never saw; or ``--sim FILE...`` clouds) and the
real scans
../shared/data/registration/pcl/room_scan1/2.pcd, and real VLP-16 rotations decoded as ``tripod decode``
writes them (sensor frame, firing order; one rotation and 10 concatenated, nominal angles and
the manual's per-laser vertical offsets). For each: Draco (DracoPy, compression level 10)
at quantisation 8..12 bits and the tripod codec on the same grid steps; rate = bits per input
point, distortion = symmetric D1 PSNR. Prints one table per cloud and a summary of the goals:
rate <= 0.5x Draco's at equal PSNR, encode >= 0.5 M points/s, decode >= 1 M points/s. The
'modes' column gives the geometry mode auto chose at each tripod step (O octree, P predictive).

For the simulated clouds (known Gaussian range noise sigma) a second table puts a noise floor
next to the rates: where the grid step is far below sigma, every point must carry its own range
noise, which costs about log2(sigma sqrt(2 pi e) / step) bits per point with an entropy-coded
quantiser of that step; and wherever Draco's D1 RMSE is below sigma, at least log2(sigma / RMSE)
(Shannon's rate-distortion bound of a Gaussian, whatever the step). Where a floor comes near or
above half of Draco's rate, the 0.5x goal is out of reach for any codec: the bits left must also
say where on the surfaces the points are.

    .venv/bin/python bench/compression.py [--plot docs/compression_rd.png] [--sim a.ply ...]
    .venv/bin/python bench/compression.py --quick   # real VLP-16 rotations only, 1 repeat,
                                                    # plot under /tmp (make bench-quick)
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
REAL = REPO.parent / "shared" / "data" / "registration" / "pcl"
VELODYNE = REPO.parent / "shared" / "data" / "velodyne"
# real VLP-16 captures decoded as `tripod decode` writes them (sensor frame, firing order):
# (file, calibration); "manual" has the per-laser vertical offsets (the per-laser model's case)
VLP16_CAPTURES = (("veloview-vlp16-20hz.pcap", "veloview"), ("mrpt-vlp16-gps.pcap", "manual"))
N_ROTATIONS = 10
HELD_OUT = (("room", 901), ("office", 902))  # tripod simulate scene, seed (not trained on)
N_SIM = 1_000_000


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--plot", type=Path, default=REPO / "docs" / "compression_rd.png")
    ap.add_argument("--sim", type=Path, nargs="*", default=[], help="simulated fragments")
    ap.add_argument("--repeat", type=int, default=2, help="timing repeats (best of)")
    ap.add_argument("--tables-from", type=Path, default=None, metavar="JSON",
                    help="print the tables of a saved run (the plot's .json) instead of running")
    ap.add_argument("--sensor-frame", action="store_true",
                    help="also bench the simulated fragments in the lidar frame (investigation)")
    ap.add_argument("--only", default=None, metavar="TEXT",
                    help="bench only the clouds whose name contains TEXT (e.g. VLP-16)")
    ap.add_argument("--quick", action="store_true",
                    help="the real VLP-16 clouds only, one timing repeat, plot to /tmp")
    args = ap.parse_args(argv)
    if args.quick:
        args.only = args.only or "VLP-16"
        args.repeat = 1
        if args.plot == ap.get_default("plot"):  # leave the committed picture alone
            args.plot = Path(tempfile.gettempdir()) / "tripod-bench-compression-quick.png"

    from tripod_processor.io.clouds import read_cloud, xyz
    from tripod_processor.compression.rd import draco_available, plot_rd, run_rd
    from tripod_processor.compression.simdata import simulated_fragments
    from tripod_processor.compression.train import HELD_OUT_SEEDS
    from tripod_processor.sim.config import SimConfig

    if args.tables_from is not None:
        from tripod_processor.compression.rd import RDPoint

        saved = json.loads(args.tables_from.read_text())
        curves = {k: [RDPoint(**r) for r in v] for k, v in saved.items()}
        # runs before n_points was recorded: every point decoded by Draco or the predictive mode
        sizes = {k: max(max(r.n_points for r in v), max(r.n_decoded for r in v))
                 for k, v in curves.items()}
        sigma = SimConfig().lidar.range_noise_m
        print_summary(curves, sizes, {k: sigma for k in curves if k.startswith("sim ")},
                      load=None)
        return 0
    if not draco_available():
        print("bench/compression.py needs DracoPy: pip install -e 'processor[bench]'")
        return 1
    clouds: dict[str, np.ndarray] = {}
    noise_m: dict[str, float] = {}  # Gaussian range noise of the simulated clouds [m]
    for p in args.sim:
        clouds[f"sim:{p.name}"] = xyz(read_cloud(p), np.float32)
    want = (lambda name: args.only is None or args.only in name)
    if not args.sim and (want("sim") or args.sensor_frame):
        sigma = SimConfig().lidar.range_noise_m
        for scene, seed in HELD_OUT:
            assert seed in HELD_OUT_SEEDS
            print(f"simulating {scene} seed {seed}", file=sys.stderr)
            frames = ("world", "lidar") if args.sensor_frame else ("world",)
            frags = simulated_fragments(scene, seed, frames=frames)
            # a 1 M-point fragment, as in the issue (a random subset of the 10 s pan, in firing
            # order); with --sensor-frame the same points as the lidar reported them, too
            keep = np.sort(np.random.default_rng(seed).choice(len(frags[0]),
                                                              min(len(frags[0]), N_SIM), False))
            clouds[f"sim {scene} seed {seed}"] = frags[0][keep]
            noise_m[f"sim {scene} seed {seed}"] = sigma
            if args.sensor_frame:
                clouds[f"sim {scene} seed {seed} (lidar frame)"] = frags[1][keep]
                noise_m[f"sim {scene} seed {seed} (lidar frame)"] = sigma
            if args.sensor_frame:  # and a contiguous 10 rotations of it, in firing order
                clouds[f"sim {scene} seed {seed} lidar frame, 10 rotations"] = frags[1][:290_000]
                noise_m[f"sim {scene} seed {seed} lidar frame, 10 rotations"] = sigma
    for name in ("room_scan1", "room_scan2"):
        if want(name):
            clouds[f"{name} (real)"] = xyz(read_cloud(REAL / f"{name}.pcd"), np.float32)
    for file, calibration in VLP16_CAPTURES:
        rotations = vlp16_rotations(VELODYNE / file, calibration)
        for label, pts in (("1 rotation", rotations[0]),
                           (f"{len(rotations)} rotations", np.concatenate(rotations))):
            name = f"VLP-16 {file.split('.')[0]} ({calibration}), {label}"
            if want(name):
                clouds[name] = pts
    clouds = {k: v for k, v in clouds.items() if want(k)}
    noise_m = {k: v for k, v in noise_m.items() if k in clouds}

    curves = {}
    for name, pts in clouds.items():
        print(f"running {name}: {len(pts)} points", file=sys.stderr)
        curves[name] = run_rd(pts, range(8, 13), True, repeat=args.repeat)
    print_summary(curves, {k: len(v) for k, v in clouds.items()}, noise_m,
                  load=os.getloadavg()[0])
    args.plot.parent.mkdir(parents=True, exist_ok=True)
    plot_rd(curves, args.plot)
    args.plot.with_suffix(".json").write_text(json.dumps(
        {k: [r.as_dict() for r in v] for k, v in curves.items()}, indent=1))
    print(f"plot: {args.plot}")
    return 0


def vlp16_rotations(path: Path, calibration: str) -> list[np.ndarray]:
    """Up to N_ROTATIONS whole rotations (the first, partial one skipped) of a capture, as
    ``tripod decode`` writes them: (N, 3) float32 [m], sensor frame, firing order."""
    from tripod_processor.decode import DecodeConfig, decode_file

    out = []
    for frame in decode_file(path, DecodeConfig(calibration=calibration)):
        if frame.index > 0:
            p = frame.points
            out.append(np.stack([p["x"], p["y"], p["z"]], 1).astype(np.float32))
        if len(out) == N_ROTATIONS + 1:
            break
    return out[:-1] if len(out) > 2 else out  # the last one may be partial too


def print_summary(curves: dict, sizes: dict, noise_m: dict, load: float | None) -> None:
    """The per-cloud RD tables, the summary of the goals and the noise floors."""
    from rich.console import Console
    from rich.table import Table

    from tripod_processor.compression.rd import print_rd_tables
    from tripod_processor.compression.rd import ratio_at_equal_psnr

    print_rd_tables(curves)
    summary = Table(title=f"summary ({os.cpu_count()} CPUs visible): tripod bpp / Draco bpp at "
                          "equal D1 PSNR; slowest tripod speed over q8..q12 in input M points/s, "
                          "wall clock and per CPU second")
    for col in ("cloud", "points", "q8", "q9", "q10", "q11", "q12", "modes q7-13", "enc wall",
                "dec wall", "enc cpu", "dec cpu"):
        summary.add_column(col, justify="right")
    for name, rows in curves.items():
        ratio = ratio_at_equal_psnr(rows)
        ours = [r for r in rows if r.codec == "tripod" and 8 <= r.q_bits <= 12]
        modes = "".join("P" if r.mode == "predictive" else "O"
                        for r in sorted((r for r in rows if r.codec == "tripod"),
                                        key=lambda r: r.q_bits))
        summary.add_row(name, str(sizes[name]),
                        *[f"{ratio[q]:.2f}" if q in ratio else "-" for q in range(8, 13)], modes,
                        f"{min(r.encode_mpts_s for r in ours):.2f}",
                        f"{min(r.decode_mpts_s for r in ours):.2f}",
                        f"{min(r.encode_mpts_cpu_s for r in ours):.2f}",
                        f"{min(r.decode_mpts_cpu_s for r in ours):.2f}")
    Console(width=max(Console().width, 150)).print(summary)
    for name, sigma in noise_m.items():
        Console(width=max(Console().width, 150)).print(noise_floor_table(name, curves[name],
                                                                         sigma))
    if load is not None:
        print(f"load average during the run: {load:.1f} (shared machine: wall-clock "
              "rates drop with load; CPU-second rates do not)")


def noise_floor_table(name: str, rows, sigma_m: float):
    """Rich table: Draco's rate, the 0.5x goal, ours and the range-noise floors, per Draco q."""
    import math

    from rich.table import Table

    from tripod_processor.compression.rd import ratio_at_equal_psnr

    ratio = ratio_at_equal_psnr(rows)
    table = Table(title=f"{name}: range noise sigma = {1e3 * sigma_m:.0f} mm; bits per point at "
                        "Draco's D1 PSNR (floors: the points' own noise; quantiser floor where "
                        "step << sigma, Shannon's where RMSE < sigma)")
    for col in ("q", "step mm", "Draco RMSE mm", "Draco bpp", "goal 0.5x", "tripod bpp",
                "floor log2(s*sqrt(2pi e)/step)", "floor log2(s/RMSE)",
                "goal - floors: bits left for angles, which points"):
        table.add_column(col, justify="right")
    for r in sorted((r for r in rows if r.codec == "draco"), key=lambda r: r.q_bits):
        ecsq = math.log2(sigma_m * math.sqrt(2 * math.pi * math.e) / r.step_m)
        shannon = math.log2(sigma_m / (1e-3 * r.rmse_mm))
        ours = f"{ratio[r.q_bits] * r.bpp:.2f}" if r.q_bits in ratio else "-"
        # the quantiser's floor needs step << sigma; Shannon's R(D) of a Gaussian holds for any
        # distortion below the noise (RMSE < sigma)
        fine = r.step_m < sigma_m / 4
        below = 1e-3 * r.rmse_mm < sigma_m
        left_ecsq = f"{0.5 * r.bpp - ecsq:+.2f}" if fine else "n/a"
        left_shannon = f"{0.5 * r.bpp - shannon:+.2f}" if below else "n/a"
        table.add_row(str(r.q_bits), f"{1e3 * r.step_m:.2f}", f"{r.rmse_mm:.2f}", f"{r.bpp:.2f}",
                      f"{0.5 * r.bpp:.2f}", ours, f"{ecsq:.2f}" if fine else f"({ecsq:.2f})",
                      f"{shannon:.2f}" if below else f"({shannon:.2f})",
                      f"{left_ecsq} / {left_shannon}")
    return table


if __name__ == "__main__":
    sys.exit(main())
