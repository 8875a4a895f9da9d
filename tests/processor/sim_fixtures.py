# SPDX-License-Identifier: BSD-3-Clause
"""Small simulated captures shared by the simulator and replay tests (a few seconds each)."""

from __future__ import annotations

from pathlib import Path

from tripod_processor.sim import SimConfig, simulate

SHORT_MOTION = {"pan_s": 2.0, "settle_s": 0.2, "pan_ramp_s": 0.3, "transit_s": 1.0}


def small_config(**over) -> SimConfig:
    base = {"stations": 2, "seed": 7, "motion": dict(SHORT_MOTION)}
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(base.get(k), dict):
            base[k] = {**base[k], **v}
        else:
            base[k] = v
    return SimConfig.model_validate(base)


def make_capture(root: Path, name: str, **over) -> Path:
    out = root / name
    simulate(small_config(**over), out, nthreads=2)
    return out


def make_rig_capture(root: Path, name: str = "rig", **over) -> Path:
    """A small capture of an uncalibrated rig for the processor's tests (~30 s of recording,
    a few CPU seconds): a short hall (12 x 10 m), a 10 cm lever arm, a hand-turned pan with a
    pause and a reversal, 4 ms IMU latency, 3 stations (``sim.rigs.small_rig``; ``over`` as
    there). The truth is in ``meta.json["truth"]``."""
    from tripod_processor.sim.rigs import small_rig

    out = root / name
    simulate(small_rig(**over), out, nthreads=2)
    return out


def true_stations(rec, truth):
    """The simulator's still spans as stations (0.5 s trimmed at each end), rows by lidar time."""
    import numpy as np

    from tripod_processor.reconstruction.stations import Station

    out = []
    for k, st in enumerate(truth["stations"]):
        a, b = st["still"]["lidar_ns"]
        a, b = a + int(0.5e9), b - int(0.5e9)
        pa, pb = np.searchsorted(rec.lidar.lidar_ns, [a, b])
        out.append(Station(k, a, b, int(pa), int(pb)))
    return out


def truth_extrinsic(truth):
    """The simulator's true lidar-IMU extrinsic (``meta.json["truth"]``) as an ``Extrinsic``."""
    import numpy as np
    from scipy.spatial.transform import Rotation

    from tripod_processor.reconstruction.placement import Extrinsic

    q = truth["q_imu_lidar_wxyz"]
    return Extrinsic(Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix(),
                     np.asarray(truth["lever_arm_imu_m"], float), "truth")


def segmented_rig(root: Path, name: str, stations: int, **over):
    """A small uncalibrated rig's capture (``make_rig_capture``), read, its IMU placed on the
    lidar's clock and its stations segmented as ``tripod reconstruct`` does with no calibration
    (the count asserted). Returns ``(rec, seg, orient, truth, R_imu_lidar_true)``."""
    import json

    from tripod_processor.reconstruction.config import ReconstructConfig
    from tripod_processor.reconstruction.inputs import read_recording
    from tripod_processor.reconstruction.placement import (Extrinsic, ImuOrientation,
                                                           fit_clock_map)
    from tripod_processor.reconstruction.stations import segment_stations

    cap = make_rig_capture(root, name, stations=stations, **over)
    truth = json.loads((cap / "meta.json").read_text())["truth"]
    rec = read_recording(cap)
    orient = ImuOrientation(rec.imu, fit_clock_map(rec.lidar), 0)
    rc = ReconstructConfig(num_threads=2)
    seg = segment_stations(rec.lidar, orient, Extrinsic.from_config(None, None), rc.stations,
                           [], num_threads=2, reuse={})
    assert len(seg.stations) == stations
    return rec, seg, orient, truth, truth_extrinsic(truth).R_imu_lidar
