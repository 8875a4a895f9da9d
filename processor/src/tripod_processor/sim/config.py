# SPDX-License-Identifier: BSD-3-Clause
"""Typed configuration of the digital twin (every parameter lands in ``meta.json``)."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

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
                                      description="heading change between stations, "
                                                  "uniform +/- [deg]")
    station_lateral_jitter_m: float = Field(0.2, ge=0.0, description="off-route offset [m]")
    sway_side_m: float = Field(0.03, ge=0.0, description="sideways sway while carried [m]")
    sway_height_m: float = Field(0.015, ge=0.0, description="vertical bob while carried [m]")
    sway_tilt_deg: float = Field(2.0, ge=0.0, description="roll/pitch sway while carried [deg]")
    lift_m: float = Field(0.05, ge=0.0, description="lift while carried [m]")
    tripod_legs: bool = Field(False, description="the tripod's three legs are in the scene "
                                                 "(the lidar sees them when looking down)")
    leg_radius_m: float = Field(0.015, gt=0.0, description="leg tube radius [m]")
    leg_spread_m: float = Field(0.5, gt=0.0, description="foot distance from the pan axis [m]")
    # --- pan profile (issue 12); the defaults keep the motor pan above, byte for byte
    pan_profile: Literal["constant", "hand"] = Field(
        "constant", description="constant: a motor pan at one cruise speed (raised-cosine ramps "
                                "of pan_ramp_s); hand: a hand-turned head whose speed changes "
                                "every ~pan_speed_change_s by up to +/- pan_speed_variation")
    pan_turns: float | None = Field(
        None, ge=0.5, le=2.0, description="net turn of one pan [turns]; default 1 + "
                                          "pan_overlap_deg / 360")
    pan_turns_jitter: float = Field(0.0, ge=0.0, le=0.3,
                                    description="per-station uniform +/- on pan_turns [turns]")
    pan_speed_variation: float = Field(0.5, ge=0.0, lt=1.0,
                                       description="hand: speed levels uniform in "
                                                   "(1 +/- this) x the mean")
    pan_speed_change_s: float = Field(1.5, gt=0.1,
                                      description="hand: mean time between speed changes [s]")
    pan_pause_s: float = Field(0.0, ge=0.0,
                               description="a pause of this length inside every pan, at a "
                                           "random place (0: none) [s]")
    pan_reversal_deg: float = Field(0.0, ge=0.0, le=120.0,
                                    description="inside every pan the head turns back by this "
                                                "much, then on (0: none) [deg]")
    pan_reversal_s: float = Field(1.0, gt=0.0, description="duration of the turn back [s]")
    route_span: float = Field(1.0, gt=0.0, le=1.0,
                              description="share of the scene's route the stations spread "
                                          "over (< 1: part of a big hall; carries shorter)")

    @model_validator(mode="after")
    def _pan_fits(self) -> "MotionConfig":
        gaps = [w for w, on in ((self.pan_pause_s, self.pan_pause_s > 0),
                                (self.pan_reversal_s, self.pan_reversal_deg > 0)) if on]
        need = 2 * min(self.pan_ramp_s, self.pan_s / 4) + sum(
            w + 2 * min(self.pan_ramp_s, 0.5) for w in gaps)
        if gaps and need > 0.8 * self.pan_s:
            raise ValueError(f"pan_s {self.pan_s:g} s is too short for the pause and reversal "
                             f"asked for (they and the ramps need {need:.1f} s, at most 80 %)")
        return self

    @property
    def is_motor_default(self) -> bool:
        """The original motor pan (no profile options used): ``motion._ramp_angle`` exactly."""
        return (self.pan_profile == "constant" and self.pan_turns is None
                and self.pan_turns_jitter == 0.0 and self.pan_pause_s == 0.0
                and self.pan_reversal_deg == 0.0)


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
    vertical_offsets: bool = Field(
        True, description="lasers offset along z as in the VLP-16 manual (velodyne-decoder's "
                          "built-in geometry); False: all lasers at the origin (VeloView's)")
    mixed_pixels: bool = Field(
        False, description="footprints on two surfaces closer than dual_min_separation_m "
                           "return a range between them (edge artefacts), not the centre's")
    product_id: int = Field(0x22, ge=0, le=255, description="factory byte (0x22 VLP-16)")
    clock_offset_ns: int | None = Field(
        None, description="lidar_toh clock minus host_realtime [ns]; default 823456789 "
                          "(free-running lidar clock), or -1200000 with gps (lidar on UTC "
                          "through PPS, host clock 1.2 ms ahead by NTP)")
    network_latency_us: float = Field(60.0, ge=0.0,
                                      description="last firing to host receive, mean [us]")
    network_jitter_us: float = Field(15.0, ge=0.0, description="exponential jitter [us]")
    position_packets: bool = True
    gps: bool = Field(False, description="GPS attached: PPS locked and GPRMC in position packets")
    gps_lat_deg: float = 59.9399
    gps_lon_deg: float = 10.7217
    src_ip: str = "192.168.1.201"
    dst_ip: str = "255.255.255.255"

    @model_validator(mode="after")
    def _derived_clock_offset(self) -> "LidarConfig":
        if self.clock_offset_ns is None:
            self.clock_offset_ns = -1_200_000 if self.gps else 823_456_789
        return self


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


class SceneSizeConfig(StrictModel):
    """Fixed dimensions of a parametric scene instead of the seed's draw (None: drawn). Only the
    fields the scene has may be set: room/office/hall width, depth, height; corridor length
    (first leg), leg2 (0: a straight corridor), width, height."""

    width_m: float | None = Field(None, gt=1.0, le=200.0,
                                  description="room/office/hall: x extent; corridor: its width [m]")
    depth_m: float | None = Field(None, gt=1.0, le=200.0, description="y extent [m]")
    height_m: float | None = Field(None, gt=1.8, le=30.0, description="floor to ceiling [m]")
    length_m: float | None = Field(None, gt=3.0, le=300.0,
                                   description="corridor: length of the first leg [m]")
    leg2_m: float | None = Field(None, ge=0.0, le=300.0,
                                 description="corridor: length of the second leg, 0 = none [m]")


class SimConfig(StrictModel):
    """Everything that defines one simulated capture (deterministic per seed)."""

    scene: str = "room"
    scene_file: str | None = None
    scene_size: SceneSizeConfig | None = Field(
        None, description="fixed scene dimensions (default: drawn from the seed)")
    route_xy: list[tuple[float, float]] | None = Field(
        None, description="route of the tripod through free space (x, y) [m]; default: the "
                          "scene's own (parametric scenes) or a loop inset from the bounds")
    route_closed: bool = Field(True, description="route_xy is a loop")
    stations: int = Field(3, ge=1, le=500)
    seed: int = 0
    start_unix_ns: int = Field(1_767_268_800_000_000_000,
                               description="host_realtime of the capture start (UNIX ns)")
    gt_rate_hz: float = Field(200.0, gt=0.0, description="rate of the TUM trajectory")
    mcap: bool = Field(False, description="also write recording.mcap, as the daemon records")
    motion: MotionConfig = MotionConfig()
    lidar: LidarConfig = LidarConfig()
    imu: ImuConfig = ImuConfig()
