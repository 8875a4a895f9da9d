# SPDX-License-Identifier: BSD-3-Clause
"""IMU model: the orientation an IMU Brick 2.0 reports, and the bytes it sends.

The IMU is rigidly fixed to the lidar (R_lidar_imu, t_lidar_imu). It fuses gyro and gravity but
has no magnetometer, so its reference frame ``imu_ref`` shares the world's vertical while its
heading is arbitrary (``yaw_offset_deg``) and drifts (``yaw_drift_deg_per_min``)::

    R_ref_imu(t) = Rz(yaw_offset + drift * t) @ R_world_lidar(t) @ R_lidar_imu @ Exp(noise)

with white noise of ``noise_deg`` per axis. Samples come every ``1 / rate_hz`` of the IMU's own
oscillator (``clock_drift_ppm`` off), and reach the host ``latency_ms`` (+ exponential jitter)
after the instant they describe. Bytes: a TFP CALLBACK_QUATERNION (fid 39, int16 w,x,y,z
scaled by 16383) per sample, or a WitMotion 0x55 0x59 quaternion frame (scale 32768).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from tripod_shared import tfp, witmotion

from .config import ImuConfig
from .motion import rot_z, rpy_matrix


@dataclass
class ImuStream:
    """sample_ns: (N,) capture-relative true sample time; host_ns: (N,) host_realtime read time;
    q_true, q_meas: (N, 4) w, x, y, z of R_ref_imu without and with noise; chunks: bytes."""

    sample_ns: np.ndarray
    host_ns: np.ndarray
    q_true: np.ndarray
    q_meas: np.ndarray
    chunks: list[bytes]


def R_lidar_imu(cfg: ImuConfig) -> np.ndarray:
    return rpy_matrix(*cfg.rpy_lidar_imu_deg)


def wxyz(R: np.ndarray) -> np.ndarray:
    """(N, 4) w, x, y, z quaternions of rotation matrices (N, 3, 3), w >= 0."""
    q = Rotation.from_matrix(R).as_quat()  # x, y, z, w
    q = np.concatenate([q[:, 3:], q[:, :3]], axis=1)
    return q * np.where(q[:, :1] < 0, -1.0, 1.0)


def simulate_imu(cfg: ImuConfig, trajectory, duration_ns: int, start_unix_ns: int,
                 seed: int) -> ImuStream:
    rng = np.random.default_rng([seed, 0x1403])
    period_ns = 1e9 / cfg.rate_hz * (1.0 + cfg.clock_drift_ppm * 1e-6)
    t0 = rng.uniform(0, period_ns)
    n = int((duration_ns - t0) // period_ns) + 1
    sample_ns = np.round(t0 + period_ns * np.arange(n)).astype(np.int64)
    sample_ns = sample_ns[sample_ns < duration_ns]
    t_s = sample_ns * 1e-9
    R_wl, _ = trajectory.T_world_lidar(t_s)
    R_wi = R_wl @ R_lidar_imu(cfg)
    yaw = np.radians(cfg.yaw_offset_deg + cfg.yaw_drift_deg_per_min * t_s / 60.0)
    R_ref_imu = rot_z(yaw) @ R_wi
    q_true = wxyz(R_ref_imu)
    if cfg.noise_deg > 0:
        noise = Rotation.from_rotvec(rng.normal(0, np.radians(cfg.noise_deg), (len(t_s), 3)))
        q_meas = wxyz(R_ref_imu @ noise.as_matrix())
    else:
        q_meas = q_true.copy()
    lat = cfg.latency_ms * 1e6 + rng.exponential(max(cfg.latency_jitter_ms, 1e-9) * 1e6, len(t_s))
    host = start_unix_ns + sample_ns + np.round(lat).astype(np.int64)
    host = np.maximum.accumulate(host)  # one serial line: bytes arrive in order
    if cfg.protocol == "tfp":
        uid = tfp.base58_decode(cfg.uid)
        chunks = [tfp.encode_quaternion_callback(uid, *q) for q in q_meas.tolist()]
    else:
        chunks = [witmotion.encode_quaternion(*q) for q in q_meas.tolist()]
    return ImuStream(sample_ns, host, q_true, q_meas, chunks)
