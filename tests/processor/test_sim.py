# SPDX-License-Identifier: BSD-3-Clause
"""Simulated captures: packets as the VLP-16 sends them, geometry on the mesh, labels, IMU."""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest

from tripod_processor.io.imu_log import ImuLogError, ImuLogReader
from tripod_processor.io.pcap import PcapReader
from tripod_processor.sim import fidelity
from tripod_processor.sim.capture import build_rig
from tripod_shared import tfp
from tripod_shared import velodyne as v
from tripod_shared import witmotion

from sim_fixtures import make_capture, small_config


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    """Noise-free single-return capture: geometry must be exact to the quantisation."""
    return make_capture(tmp_path_factory.mktemp("sim"), "clean", lidar={
        "range_noise_m": 0.0, "dropout": 0.0}, imu={"noise_deg": 0.0})


@pytest.fixture(scope="module")
def noisy_dual(tmp_path_factory):
    """Default noise, dual return, GPS attached, WitMotion IMU, another scene."""
    return make_capture(tmp_path_factory.mktemp("sim"), "dual", scene="two_rooms", seed=3,
                        lidar={"return_mode": "dual", "gps": True},
                        imu={"protocol": "witmotion"})


@pytest.fixture(scope="module")
def noisy(tmp_path_factory):
    return make_capture(tmp_path_factory.mktemp("sim"), "noisy", scene="corridor", seed=11)


def test_output_files(clean):
    for name in ("capture.pcap", "imu.tripimu", "labels.npz", "mesh.ply", "meta.json",
                 "config.yaml", "gt/trajectory.tum", "gt/stations.tum", "gt/stations.csv",
                 "gt/calibration.json", "gt/clocks.json", "gt/imu_truth.csv", "overview.png"):
        assert (clean / name).is_file(), name
    assert (clean / "overview.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    meta = json.loads((clean / "meta.json").read_text())
    assert meta["config"]["lidar"]["range_noise_m"] == 0.0
    assert meta["derived"]["data_packets"] > 0
    calib = json.loads((clean / "gt/calibration.json").read_text())
    T = np.array(calib["T_lidar_imu"])
    assert np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-9)


def test_packets_match_vlp16_single(clean):
    r = fidelity.packet_check(clean)
    assert r["malformed"] == 0 and r["position_malformed"] == 0
    assert r["return_modes"] == [v.RETURN_STRONGEST] and r["products"] == [v.PRODUCT_VLP16]
    assert r["toh_step_us"] == [1327, 1328]
    assert r["packets_per_s"] == pytest.approx(753.5, abs=1.0)
    # 24 sequences per packet at 600 rpm: 24 * 55.296 us * 3600 deg/s = 4.778 deg
    assert r["azimuth_step_centideg"] == pytest.approx(477.8, abs=1.0)
    assert r["position_packets"] > 0 and r["nmea"] == [""]


def test_packets_match_vlp16_dual_and_gps(noisy_dual):
    r = fidelity.packet_check(noisy_dual)
    assert r["malformed"] == 0
    assert r["return_modes"] == [v.RETURN_DUAL]
    assert r["toh_step_us"] == [663, 664]
    assert r["packets_per_s"] == pytest.approx(1507.0, abs=2.0)
    assert r["nmea"] == ["$GPRMC"]
    # a dual packet repeats each azimuth: blocks 2k and 2k+1 share it
    for d in PcapReader(noisy_dual / "capture.pcap"):
        if d.dst_port == v.DATA_PORT:
            az = [struct.unpack_from("<H", d.payload, 100 * b + 2)[0] for b in range(12)]
            assert az[0::2] == az[1::2]
            break
    pos = next(d for d in PcapReader(noisy_dual / "capture.pcap") if d.dst_port == v.POSITION_PORT)
    assert v.position_pps_state(pos.payload) == "locked"
    s = v.position_nmea(pos.payload)
    body, cs = s[1:].split("*")
    x = 0
    for ch in body.encode():
        x ^= ch
    assert f"{x:02X}" == cs


def test_noise_free_points_land_on_mesh(clean):
    f = fidelity.geometry_check(clean)
    assert f.n_points > 100_000
    assert f.dist_median_m <= 0.002
    assert f.dist_p99_m <= 0.01
    assert f.label_joined == 1.0
    assert f.label_agreement > 0.995


def test_nominal_geometry_without_vertical_offsets(tmp_path):
    """vertical_offsets=False: every laser at the origin, decoded with the nominal calibration
    (VeloView's geometry) the points land on the mesh just as well."""
    cap = make_capture(tmp_path, "nominal", stations=1, lidar={
        "range_noise_m": 0.0, "dropout": 0.0, "vertical_offsets": False})
    f = fidelity.geometry_check(cap, max_packets=1500)
    assert f.dist_median_m <= 0.002 and f.dist_p99_m <= 0.01


def test_noise_spread_matches_sigma(noisy):
    f = fidelity.geometry_check(noisy)
    assert f.range_err_robust_std_m == pytest.approx(0.03, rel=0.1)
    assert f.label_agreement > 0.98


def test_dual_return_geometry(noisy_dual):
    f = fidelity.geometry_check(noisy_dual)
    assert f.range_err_robust_std_m == pytest.approx(0.03, rel=0.15)
    assert f.label_joined == 1.0 and f.label_agreement > 0.97


def test_imu_bytes_parse_and_match_truth(clean, noisy):
    r = fidelity.imu_check(clean)
    assert r["protocol"] == "tfp" and r["garbage_bytes"] == 0 and r["times_match"]
    assert r["samples"] == r["truth_samples"] > 0
    assert r["max_err_deg"] < 0.02  # int16 quantisation only
    assert r["rate_hz"] == pytest.approx(100.0, rel=0.01)
    r = fidelity.imu_check(noisy)
    assert r["sigma_est_deg"] == pytest.approx(0.05, rel=0.15)
    # every record is exactly one CALLBACK_QUATERNION of the configured UID
    uid = tfp.base58_decode(small_config().imu.uid)
    for rec in ImuLogReader(noisy / "imu.tripimu"):
        assert len(rec.data) == tfp.QUATERNION_PACKET_SIZE
        got = tfp.TfpStreamParser(uid).feed(rec.data)
        assert len(got) == 1 and got[0].function_id == tfp.FID_CALLBACK_QUATERNION
        break


def test_witmotion_stream(noisy_dual):
    r = fidelity.imu_check(noisy_dual)
    assert r["protocol"] == "witmotion" and r["times_match"]
    assert r["sigma_est_deg"] == pytest.approx(0.05, rel=0.15)
    rec = next(iter(ImuLogReader(noisy_dual / "imu.tripimu")))
    assert rec.data[0] == witmotion.HEAD and rec.data[1] == witmotion.TYPE_QUATERNION


def test_imu_truth_follows_trajectory_and_extrinsic(clean):
    """gt/imu_truth.csv = Rz(yaw offset + drift) R_world_lidar R_lidar_imu (independent check)."""
    from scipy.spatial.transform import Rotation

    meta, cfg = fidelity.load_meta(clean)
    host, sample, q = fidelity.read_imu_truth(clean / "gt/imu_truth.csv")
    calib = json.loads((clean / "gt/calibration.json").read_text())
    R_li = np.array(calib["T_lidar_imu"])[:3, :3]
    t = (sample - cfg.start_unix_ns) * 1e-9
    _, traj = build_rig(cfg)
    R_wl, _ = traj.T_world_lidar(t)
    yaw = np.radians(cfg.imu.yaw_offset_deg + cfg.imu.yaw_drift_deg_per_min * t / 60)
    R = Rotation.from_euler("z", yaw[:, None]).as_matrix() @ R_wl @ R_li
    got = Rotation.from_quat(np.c_[q[:, 1:], q[:, :1]]).as_matrix()
    err = Rotation.from_matrix(np.swapaxes(got, 1, 2) @ R).magnitude()
    assert np.degrees(err).max() < 1e-4
    lat_ms = (host - sample) * 1e-6
    assert np.all(lat_ms > 0) and np.median(lat_ms) == pytest.approx(2.2, abs=0.3)


def test_tum_trajectory_matches_model(clean):
    meta, cfg = fidelity.load_meta(clean)
    rows = np.loadtxt(clean / "gt/trajectory.tum", skiprows=1, dtype=str)
    t_ns = np.array([int(a.replace(".", "")) for a in rows[:, 0]], dtype=np.int64)
    assert np.all(np.diff(t_ns) == 5_000_000)  # 200 Hz
    xyz = rows[:, 1:4].astype(float)
    _, traj = build_rig(cfg)
    _, p = traj.T_world_lidar((t_ns - cfg.start_unix_ns) * 1e-9)
    assert np.abs(xyz - p).max() < 2e-6
    st = np.loadtxt(clean / "gt/stations.csv", delimiter=",", skiprows=1, ndmin=2)
    assert len(st) == cfg.stations and np.all(st[:, 2] > st[:, 1])


def test_deterministic_per_seed(tmp_path, clean):
    again = make_capture(tmp_path, "again", lidar={"range_noise_m": 0.0, "dropout": 0.0},
                         imu={"noise_deg": 0.0})
    for name in ("capture.pcap", "imu.tripimu", "gt/trajectory.tum", "mesh.ply"):
        assert (again / name).read_bytes() == (clean / name).read_bytes(), name


def test_imu_log_errors(tmp_path, noisy):
    bad = tmp_path / "bad.tripimu"
    bad.write_bytes(b"not an imu log at all")
    with pytest.raises(ImuLogError):
        ImuLogReader(bad)
    data = (noisy / "imu.tripimu").read_bytes()
    cut = tmp_path / "cut.tripimu"
    cut.write_bytes(data[: len(data) - 5])
    r = ImuLogReader(cut)
    recs = list(r)
    assert r.truncated and len(recs) == len(list(ImuLogReader(noisy / "imu.tripimu"))) - 1


def test_hour_rollover_of_the_lidar_clock(tmp_path):
    """The lidar's us-past-the-hour stamp wraps inside this capture: decode, placement and the
    label join must not notice."""
    start = 1_767_268_800 * 10**9 - 3 * 10**9  # lidar clock crosses the hour ~2.2 s in
    cap = make_capture(tmp_path, "wrap", stations=1, start_unix_ns=start,
                       lidar={"range_noise_m": 0.0, "dropout": 0.0})
    toh = np.load(cap / "labels.npz")["packet_toh_us"]
    assert toh.max() > 3599 * 10**6 and toh.min() < 10**6  # it does wrap
    r = fidelity.packet_check(cap)
    assert r["toh_step_us"] == [1327, 1328]
    f = fidelity.geometry_check(cap)
    assert f.dist_median_m <= 0.002 and f.label_joined == 1.0 and f.label_agreement > 0.995


def test_labeled_points_for_segmentation(clean):
    xyz, lab, pts = fidelity.labeled_points(clean, max_packets=500)
    assert xyz.shape == (len(lab), 3) and len(lab) > 10_000 and np.all(lab < 4)
    from tripod_processor.sim.scenes import CEILING, FLOOR
    meta, _ = fidelity.load_meta(clean)
    height = meta["scene"]["params"]["height_m"]
    assert np.median(xyz[lab == FLOOR, 2]) == pytest.approx(0.0, abs=0.005)
    assert np.median(xyz[lab == CEILING, 2]) == pytest.approx(height, abs=0.005)


def test_lookup_labels_with_lidar_clock_ns(clean):
    """The join works from int64 lidar-clock nanoseconds and firing-order laser ids (the fields
    tripod decode gives), and refuses times outside every packet."""
    pts = fidelity.decode_capture(clean, max_packets=300)
    meta, cfg = fidelity.load_meta(clean)
    lidar_ns = pts.host_ns + cfg.lidar.clock_offset_ns
    laser = fidelity._LASER_OF_RING[pts.ring]
    a = fidelity.lookup_labels(lidar_ns, laser, pts.return_type, clean / "labels.npz")
    b = fidelity.join_labels(pts, clean / "labels.npz")
    assert np.array_equal(a, b) and np.all(a < 4)
    off = fidelity.lookup_labels(lidar_ns - 10**9, laser, pts.return_type, clean / "labels.npz")
    assert np.all(off == 255)


def test_mcap_recording_as_the_daemon_records(tmp_path):
    from tripod_shared.recording import RecordingReader

    cap = make_capture(tmp_path, "mcap", stations=1, mcap=True)
    r = RecordingReader(cap / "recording.mcap")
    lidar = list(r.lidar_packets())
    want = [(d.t_ns, d.payload) for d in PcapReader(cap / "capture.pcap")
            if d.dst_port == v.DATA_PORT]
    assert lidar == want
    pos = list(r.position_packets())
    assert len(pos) == sum(1 for d in PcapReader(cap / "capture.pcap")
                           if d.dst_port == v.POSITION_PORT)
    imu = list(r.imu_samples())
    recs = list(ImuLogReader(cap / "imu.tripimu"))
    assert [s.raw for s in imu] == [x.data for x in recs]
    assert [s.host_ns for s in imu] == [x.host_ns for x in recs]
    assert imu[0].driver == "tfp" and abs(np.linalg.norm(imu[0].q_world_imu) - 1) < 1e-9
    assert [e.kind for e in r.events()] == ["start", "stop"]
    assert not r.report.truncated


def test_cli_simulate(tmp_path):
    import subprocess
    import sys

    import yaml

    cfg = tmp_path / "c.yaml"
    cfg.write_text(yaml.safe_dump({"scene": "corridor", "stations": 1,
                                   "motion": {"pan_s": 1.0, "settle_s": 0.1}}))
    env = {"COLUMNS": "120", "PATH": "/usr/bin:/bin"}
    run = [sys.executable, "-m", "tripod_processor", "simulate"]
    r = subprocess.run(run + ["-o", str(tmp_path / "out"), "--config", str(cfg), "--seed", "4",
                              "--return-mode", "last"], capture_output=True, text=True,
                       timeout=120, env=env)
    assert r.returncode == 0, r.stderr
    assert "data packets" in r.stdout + r.stderr
    meta = json.loads((tmp_path / "out/meta.json").read_text())
    assert meta["config"]["scene"] == "corridor" and meta["config"]["seed"] == 4
    assert meta["config"]["lidar"]["return_mode"] == "last"
    for bad in (["--scene", "castle"], ["--rpm", "5000"], ["--config", str(tmp_path / "no.yaml")]):
        r = subprocess.run(run + ["-o", str(tmp_path / "bad")] + bad, capture_output=True,
                           text=True, timeout=120, env=env)
        assert r.returncode == 2 and r.stderr.startswith("tripod: error:"), bad
        assert r.stderr.count("\n") == 1, r.stderr


def test_mixed_pixels_put_points_between_surfaces(tmp_path):
    base = {"range_noise_m": 0.0, "dropout": 0.0}
    plain = make_capture(tmp_path, "plain", stations=1, scene="office", seed=2, lidar=base)
    mixed = make_capture(tmp_path, "mixed", stations=1, scene="office", seed=2,
                         lidar={**base, "mixed_pixels": True})
    a = fidelity.geometry_check(plain, max_packets=2000)
    b = fidelity.geometry_check(mixed, max_packets=2000)
    assert b.dist_median_m <= 0.002
    assert b.off_mesh_frac > 2 * a.off_mesh_frac and b.off_mesh_frac > 0.001


def test_tripod_legs_are_seen_on_their_surface(tmp_path):
    cap = make_capture(tmp_path, "legs", stations=1, seed=2, motion={"tripod_legs": True},
                       lidar={"range_noise_m": 0.0, "dropout": 0.0})
    meta, cfg = fidelity.load_meta(cap)
    xyz, lab, pts = fidelity.labeled_points(cap)
    _, traj = build_rig(cfg)
    tops, feet = traj.legs_world((pts.host_ns - cfg.start_unix_ns) * 1e-9)
    u = feet - tops
    length = np.linalg.norm(u, axis=2)
    u /= length[..., None]
    m = xyz[:, None, :] - tops
    s = np.clip((m * u).sum(-1), 0, length)
    axis_dist = np.linalg.norm(m - s[..., None] * u, axis=2).min(axis=1)
    on_leg = axis_dist < cfg.motion.leg_radius_m + 0.003
    assert on_leg.sum() > 10  # looking down, the lidar sees its own legs ...
    leg_pts = on_leg & (lab == 3)
    assert np.abs(axis_dist[leg_pts] - cfg.motion.leg_radius_m).max() < 0.003  # ... on the tube
    f = fidelity.geometry_check(cap)
    assert f.dist_median_m <= 0.002
