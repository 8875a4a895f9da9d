# SPDX-License-Identifier: BSD-3-Clause
"""The turns' IMU time offset alone (issue 12), on random rigs: ways of fitting one set of pairs.

Runs the pipeline up to the calibration's turns (read, clock map, stations, hand-eye mount) on
each rig of ``bench/rigs.py`` (its capture cache), registers the turns' sweep pairs as the
pipeline does (``calibration.turn_measurements``: stations' and carries', the pipeline's
passes), then fits them several ways (``calibration.fit_turn_offset``) and prints each way's
error against the truth and its claimed sigma. Some 15-30 CPU-s a rig instead of a full
reconstruction's 30-60; a way worth keeping is then checked end to end with ``bench/rigs.py``.
Development seeds only (0-9999).

    .venv/bin/python bench/turn_offset.py --seeds 83 87 171 --json /tmp/turns.json
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

#: name -> fit_turn_offset keywords; "stations" / "carries": that kind's pairs alone
WAYS = {
    "joint": {},
    "joint+mount": {"carry_mount": True},
    "split": {"combine": "split"},
    "split+floor1": {"combine": "split", "carry_floor_ms": 1.0},
    "split+mount": {"combine": "split", "carry_mount": True},
    "split+mount+floor1": {"combine": "split", "carry_mount": True, "carry_floor_ms": 1.0},
    "split+mount+floor2": {"combine": "split", "carry_mount": True, "carry_floor_ms": 2.0},
    # the pipeline's default since stop 38 (calibration.turn_carry_floor_ms 0.5)
    "split+mount+floor.5": {"combine": "split", "carry_mount": True, "carry_floor_ms": 0.5},
    # ... with one disagreeing station or carry left out (calibration.turn_cluster_outlier_z 3)
    "split+mount+floor.5+z3": {"combine": "split", "carry_mount": True, "carry_floor_ms": 0.5,
                               "cluster_outlier_z": 3.0},
    "stations": {"kind": False},
    "carries": {"kind": True},
    "carries+mount": {"kind": True, "carry_mount": True},
    # the carries' pairs registered again with the walk's velocity de-skewed (carry_velocity)
    "V:joint": {"v": True},
    "V:joint+mount": {"v": True, "carry_mount": True},
    "V:split+floor1": {"v": True, "combine": "split", "carry_floor_ms": 1.0},
    "V:split+mount+floor1": {"v": True, "combine": "split", "carry_mount": True,
                             "carry_floor_ms": 1.0},
    "V:carries": {"v": True, "kind": True},
    "V:carries+mount": {"v": True, "kind": True, "carry_mount": True},
}


def run_one(work: Path, seed: int, threads: int, sets: dict, velocity: bool,
            anchor_s: float = 0.0) -> dict:
    from rigs import simulate_cached

    from tripod_shared.config_io import load_config

    from tripod_processor.reconstruction import calibration as C
    from tripod_processor.reconstruction.config import ReconstructConfig
    from tripod_processor.reconstruction.evaluation import true_time_offset_ns
    from tripod_processor.reconstruction.inputs import read_recording
    from tripod_processor.reconstruction.pipeline import _calibrate_mount
    from tripod_processor.reconstruction.placement import (Extrinsic, ImuOrientation,
                                                           fit_clock_map)
    from tripod_processor.reconstruction.stations import segment_stations

    c0 = time.process_time()
    cap, _, _ = simulate_cached(work, seed, threads)
    truth = json.loads((cap / "meta.json").read_text())["truth"]
    cfg = load_config(ReconstructConfig, overrides={"num_threads": threads, **sets})
    rec = read_recording(cap)
    clock = fit_clock_map(rec.lidar)
    true_ms = true_time_offset_ns(cap, rec) * 1e-6
    ext = Extrinsic.from_config(None, None)
    orient = ImuOrientation(rec.imu, clock, 0, smooth_s=cfg.placement.imu_smooth_s)
    marks = [(int(clock.to_lidar(np.array([h]))[0]), label) for h, label in rec.marks]
    seg = segment_stations(rec.lidar, orient, ext, cfg.stations, marks, num_threads=threads)
    if not seg.stations:
        return {"seed": seed, "error": "no stations"}
    ext, orient, _ = _calibrate_mount(rec, seg, orient, ext, cfg, threads, {}, True, [])
    cc = cfg.calibration
    kw = dict(max_stations=cc.max_turn_stations, carries=C.carry_spans(seg.stations),
              denoise_firings=cc.range_denoise_firings,
              pairs_per_station=cc.turn_pairs_per_station,
              pairs_per_carry=cc.turn_pairs_per_carry,
              station_information=cc.turn_station_information,
              uses_per_sweep=cc.turn_sweep_uses)
    # the pipeline's passes (the old joint fit decides a second pass's de-skew)
    tm = C.turn_measurements(rec.lidar, seg.stations, orient, ext, threads, **kw)
    first = C.fit_turn_offset(tm, orient, ext, anchor_smooth_s=anchor_s)
    if (cc.turn_passes > 1 and first.sigma_ms <= 4.0
            and abs(first.offset_ns - orient.time_offset_ns) >= 0.5e6):
        orient = orient.with_offset(first.offset_ns)
        tm = C.turn_measurements(rec.lidar, seg.stations, orient, ext, threads, **kw)
    q = truth["q_imu_lidar_wxyz"]
    from scipy.spatial.transform import Rotation

    R_true = Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix()
    mount_err = float(np.degrees(Rotation.from_matrix(ext.R_imu_lidar.T @ R_true).magnitude()))
    row = {"seed": seed, "true_ms": true_ms, "mount_err_deg": mount_err,
           "n_station_pairs": int((~tm.is_carry).sum()), "n_carry_pairs": int(tm.is_carry.sum())}
    tv = C.turn_measurements(rec.lidar, seg.stations, orient, ext, threads,
                             **{**kw, "pairs_per_station": 0}, carry_velocity=True
                             ) if velocity else C.TurnMeasurements([], np.zeros(0, np.int64),
                                                                   np.zeros(0, bool), tm.a_lidar)
    st = tm.subset(~tm.is_carry)
    tm_v = C.TurnMeasurements(st.meas + tv.meas, np.concatenate([st.cluster, tv.cluster]),
                              np.concatenate([st.is_carry, tv.is_carry]), tm.a_lidar)
    row["n_carry_pairs_v"] = len(tv.meas)
    for name, way in WAYS.items():
        if way.get("v") and not velocity:
            continue
        way = {"anchor_smooth_s": anchor_s, **way}
        kind = way.pop("kind", None)
        base = tm_v if way.pop("v", False) else tm
        sub = base if kind is None else base.subset(base.is_carry == kind)
        r = C.fit_turn_offset(sub, orient, ext, **way)
        row[name] = {"err_ms": r.offset_ns * 1e-6 - true_ms, "sigma_ms": r.sigma_ms,
                     "pairs": r.pairs}
    row["cpu_s"] = time.process_time() - c0
    return row


def summarise(rows: list[dict]) -> None:
    ok = [r for r in rows if "error" not in r]
    print(f"\n{len(ok)} rigs")
    print(f"{'way':22s} {'median':>7s} {'RMS':>7s} {'max':>7s} {'<=1ms':>6s} {'|z|RMS':>7s}")
    for name in WAYS:
        if name not in ok[0]:
            continue
        e = np.array([r[name]["err_ms"] for r in ok])
        s = np.array([r[name]["sigma_ms"] for r in ok])
        f = np.isfinite(e) & np.isfinite(s)
        a = np.abs(e[f])
        z = a / s[f]
        print(f"{name:22s} {np.median(a):7.2f} {np.sqrt(np.mean(a**2)):7.2f} {a.max():7.2f} "
              f"{int((a <= 1).sum()):3d}/{len(ok):<2d} {np.sqrt(np.mean(z**2)):7.2f}"
              + (f"  ({int((~f).sum())} without)" if (~f).any() else ""))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", required=True)
    ap.add_argument("--work", type=Path, default=Path("/tmp/tripod-bench-rigs"))
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--anchor", type=float, default=0.0, metavar="S",
                    help="every way (and the passes) with the prediction anchored at the "
                         "de-skew's IMU noise, smoothed over S seconds "
                         "(calibration.turn_anchor_smooth_s; default 0: slerped afresh)")
    ap.add_argument("--velocity", action="store_true",
                    help="also the ways with the carries' walk de-skewed (V:, more CPU)")
    a = ap.parse_args()
    if any(s >= 10000 for s in a.seeds):
        ap.error("development seeds only (0-9999)")
    sets = {}
    for kv in a.set:
        k, v = kv.split("=", 1)
        sets[k] = json.loads(v) if v[:1] in "[{0123456789-tfn" else v
    rows = []
    for seed in a.seeds:
        try:
            row = run_one(a.work, seed, a.threads, sets, a.velocity, a.anchor)
        except Exception as exc:  # one line, counted
            row = {"seed": seed, "error": f"{type(exc).__name__}: {exc}"[:200]}
        rows.append(row)
        if "error" in row:
            print(f"seed {seed}: {row['error']}", flush=True)
        else:
            print(f"seed {seed}: true {row['true_ms']:.2f} ms, mount {row['mount_err_deg']:.2f}°, "
                  f"pairs {row['n_station_pairs']}+{row['n_carry_pairs']}, "
                  f"{row['cpu_s']:.0f} CPU-s | " + "  ".join(
                      f"{n} {row[n]['err_ms']:+.2f}±{row[n]['sigma_ms']:.2f}" for n in WAYS
                      if n in row),
                  flush=True)
        if a.json:
            a.json.write_text(json.dumps(rows, indent=1))
    summarise(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
