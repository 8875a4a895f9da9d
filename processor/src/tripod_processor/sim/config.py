# SPDX-License-Identifier: BSD-3-Clause
"""Typed configuration of the digital twin (every parameter lands in ``meta.json``)."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from tripod_shared.config_io import StrictModel

Vec3 = tuple[float, float, float]


class MotionConfig(StrictModel):
    """Acquisition: station pans and transits between stations (see ``sim.motion``)."""

    settle_s: float = Field(1.0, ge=0.0, description="rest before and after each pan [s]")
    pan_s: float = Field(10.0, gt=0.5, description="duration of one station's pan [s]")
    pan_ramp_s: float = Field(0.8, ge=0.0, description="raised-cosine speed ramp of the pan [s]")
    pan_overlap_deg: float = Field(10.0, ge=0.0, description="pan beyond one full turn [deg]")
    transit_s: float = Field(4.0, gt=0.0,
                             description="carrying time between stations, at least [s]")
    max_carry_speed_m_s: float = Field(1.2, gt=0.0,
                                       description="peak walking speed; longer walks take longer")
    tilt_deg: float = Field(60.0, ge=0.0, le=90.0,
                            description="tilt of the lidar spin axis from the pan axis [deg]")
    lever_arm_m: Vec3 = Field((0.06, 0.0, 0.12),
                              description="lidar origin in the pan frame (lever arm) [m]")
    tripod_height_m: tuple[float, float] = Field((1.3, 1.6), description="head height range [m]")
    level_error_deg: float = Field(0.3, ge=0.0, description="sigma of station roll/pitch [deg]")
    max_yaw_change_deg: float = Field(180.0, ge=0.0, le=180.0,
                                      description="heading change between stations, uniform +/- [deg]")
    station_lateral_jitter_m: float = Field(0.2, ge=0.0, description="off-route offset [m]")
    sway_side_m: float = Field(0.03, ge=0.0, description="sideways sway while carried [m]")
    sway_height_m: float = Field(0.015, ge=0.0, description="vertical bob while carried [m]")
    sway_tilt_deg: float = Field(2.0, ge=0.0, description="roll/pitch sway while carried [deg]")
    lift_m: float = Field(0.05, ge=0.0, description="lift while carried [m]")


class LidarConfig(StrictModel):
    """The VLP-16 and its network link."""

    rpm: float = Field(600.0, ge=300.0, le=1200.0, description="motor speed [rpm]")
    return_mode: Literal["strongest", "last", "dual"] = "strongest"
    range_noise_m: float = Field(0.03, ge=0.0, description="sigma of Gaussian range noise [m]")
    min_range_m: float = Field(0.4, ge=0.0, description="closer returns are dropped [m]")
    max_range_m: float = Field(100.0, gt=0.0, le=130.0, description="farther = no return [m]")
    max_incidence_deg: float = Field(88.0, gt=0.0, le=90.0,
                                     description="grazing hits beyond this give no return [deg]")
    dropout: float = Field(0.001, ge=0.0, lt=1.0, description="random no-return probability")
    beam_divergence_mrad: float = Field(3.0, ge=0.0,
                                        description="footprint sampled for last/dual returns")
    dual_min_separation_m: float = Field(0.3, ge=0.0,
                                         description="closer returns merge into one [m]")
    product_id: int = Field(0x22, ge=0, le=255, description="factory byte (0x22 VLP-16)")
    clock_offset_ns: int = Field(823_456_789,
                                 description="lidar_toh clock minus host_realtime [ns] "
                                             "(free-running lidar clock)")
    network_latency_us: float = Field(60.0, ge=0.0,
                                      description="last firing to host receive, mean [us]")
    network_jitter_us: float = Field(15.0, ge=0.0, description="exponential jitter [us]")
    position_packets: bool = True
    gps: bool = Field(False, description="GPS attached: PPS locked and GPRMC in position packets")
    gps_lat_deg: float = 59.9399
    gps_lon_deg: float = 10.7217
    src_ip: str = "192.168.1.201"
    dst_ip: str = "255.255.255.255"


class ImuConfig(StrictModel):
    """The IMU Brick 2.0 (or a WitMotion-style serial IMU) rigidly fixed to the lidar."""

    protocol: Literal["tfp", "witmotion"] = "tfp"
    rate_hz: float = Field(100.0, gt=0.0, le=1000.0, description="quaternion callback rate")
    noise_deg: float = Field(0.05, ge=0.0, description="white orientation noise sigma per axis")
    yaw_drift_deg_per_min: float = Field(0.5, description="heading drift (no magnetometer)")
    yaw_offset_deg: float = Field(37.0, description="heading of the IMU's reference frame")
    latency_ms: float = Field(2.0, ge=0.0, description="sample to host read, mean [ms]")
    latency_jitter_ms: float = Field(0.3, ge=0.0, description="exponential jitter [ms]")
    clock_drift_ppm: float = Field(30.0, description="IMU oscillator rate error [ppm]")
    uid: str = Field("6wVE7W", description="Tinkerforge UID (base58)")
    t_lidar_imu_m: Vec3 = Field((0.03, -0.04, -0.05), description="IMU origin in lidar frame")
    rpy_lidar_imu_deg: Vec3 = Field((1.5, -0.8, 2.0),
                                    description="R_lidar_imu = Rz(yaw) Ry(pitch) Rx(roll)")


class SimConfig(StrictModel):
    """Everything that defines one simulated capture (deterministic per seed)."""

    scene: str = "room"
    scene_file: str | None = None
    stations: int = Field(3, ge=1, le=500)
    seed: int = 0
    start_unix_ns: int = Field(1_767_268_800_000_000_000,
                               description="host_realtime of the capture start (UNIX ns)")
    gt_rate_hz: float = Field(200.0, gt=0.0, description="rate of the TUM trajectory")
    motion: MotionConfig = MotionConfig()
    lidar: LidarConfig = LidarConfig()
    imu: ImuConfig = ImuConfig()
