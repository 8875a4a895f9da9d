# SPDX-License-Identifier: BSD-3-Clause
"""Reconstruction: placement, stations, time offset, odometry/SLAM, outputs, bad input, CLI —
on a small synthetic tripod capture with known truth (``recon_synth``)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from recon_synth import synth_capture
from tripod_processor.io import clouds as cloud_io
from tripod_processor.reconstruction import evaluation as ev
from tripod_processor.reconstruction.config import ReconstructConfig
from tripod_processor.reconstruction.inputs import RecordingError, read_recording
from tripod_processor.reconstruction.outputs import read_tum
from tripod_processor.reconstruction.placement import (Extrinsic, ImuOrientation,
                                                        host_to_lidar_offset_ns, place_points)
from tripod_shared.config_io import ConfigError, load_config


def _ext_overrides(truth) -> dict:
    x, y, z, w = Rotation.from_matrix(truth.R_imu_lidar).as_quat()
    return {"placement.extrinsic.q_imu_lidar": [w, x, y, z],
            "placement.extrinsic.lever_arm_m": truth.lever_arm_m.tolist()}


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    path = tmp_path_factory.mktemp("synth") / "rec.mcap"
    truth = synth_capture(path)
    return path, truth


@pytest.fixture(scope="module")
def run(capture, tmp_path_factory):
    from tripod_processor.reconstruction.pipeline import reconstruct

    path, truth = capture
    out = tmp_path_factory.mktemp("recon")
    # with the survey files (E57, LAZ): the default path (without) is the other tests' and demo's
    cfg = load_config(ReconstructConfig, overrides={**_ext_overrides(truth),
                                                    "output.write_e57": True,
                                                    "output.write_las": "laz"})
    res = reconstruct(path, out, cfg, quiet=True)
    return res, truth, out


# ---- placement ---------------------------------------------------------------------------------
def test_slerp_matches_scipy_and_holds_at_the_ends():
    from tripod_processor.reconstruction.inputs import ImuTrack

    rng = np.random.default_rng(0)
    t = np.arange(50, dtype=np.int64) * 10_000_000  # a periodic IMU (de-jitter keeps it)
    rots = Rotation.from_rotvec(np.cumsum(rng.normal(0, 0.05, (50, 3)), axis=0))
    q = rots.as_quat()[:, [3, 0, 1, 2]]
    q[::3] *= -1  # sign flips must not matter
    o = ImuOrientation(ImuTrack(t, q), host_minus_lidar_ns=0)
    tq = np.linspace(t[0], t[-1], 333).astype(np.int64)
    ref = Slerp(t.astype(float), rots)(tq.astype(float))
    got = Rotation.from_matrix(o.rotation_at(tq))
    assert np.degrees((ref.inv() * got).magnitude()).max() < 1e-6
    ends = o.rotation_at(np.array([t[0] - 10**9, t[-1] + 10**9]))
    np.testing.assert_allclose(ends[0], rots[0].as_matrix(), atol=1e-9)
    np.testing.assert_allclose(ends[1], rots[-1].as_matrix(), atol=1e-9)


def test_native_placement_matches_the_model():
    from tripod_processor.reconstruction.inputs import ImuTrack

    rng = np.random.default_rng(1)
    t_imu = np.arange(0, 2_000_000_000, 10_000_000, dtype=np.int64)
    rots = Rotation.from_euler("z", np.linspace(0, 60, len(t_imu))[:, None], degrees=True)
    o = ImuOrientation(ImuTrack(t_imu, rots.as_quat()[:, [3, 0, 1, 2]]), 0)
    ext = Extrinsic(Rotation.from_euler("x", 30, degrees=True).as_matrix(),
                    np.array([0.05, -0.02, 0.12]))
    xyz = rng.uniform(-5, 5, (2000, 3))
    t = rng.integers(0, 2_000_000_000, 2000).astype(np.int64)
    anchor = 1_000_000_000
    got = place_points(xyz, t, o, ext, anchor)
    R_wi = o.rotation_at(t)
    p_w = np.einsum("nij,nj->ni", R_wi, xyz @ ext.R_imu_lidar.T + ext.lever_arm_m)
    R_a = o.rotation_at(np.array([anchor]))[0]
    expect = (p_w - R_a @ ext.lever_arm_m) @ (R_a @ ext.R_imu_lidar)
    np.testing.assert_allclose(got, expect, atol=2e-5)


def test_native_placement_in_firing_order_under_fast_turns():
    # points in firing order (2.3 µs apart, the way packets decode) while the head turns fast
    # about a changing axis: the native core's grid interpolation between exact rotations must
    # agree with the per-point slerp, also across the IMU samples' kinks
    from tripod_processor.reconstruction.inputs import ImuTrack

    rng = np.random.default_rng(2)
    t_imu = np.arange(0, 500_000_000, 5_000_000, dtype=np.int64)  # 200 Hz
    ang = np.cumsum(rng.normal(0, 1.5, (len(t_imu), 3)), axis=0)  # up to ~300 °/s, kinked
    rots = Rotation.from_euler("zyx", ang, degrees=True)
    o = ImuOrientation(ImuTrack(t_imu, rots.as_quat()[:, [3, 0, 1, 2]]), 0)
    ext = Extrinsic(Rotation.from_euler("x", 30, degrees=True).as_matrix(),
                    np.array([0.05, -0.02, 0.12]))
    n = 150_000
    t = 1_000_000 + np.arange(n, dtype=np.int64) * 2304 + rng.integers(-5, 5, n)
    xyz = rng.uniform(-10, 10, (n, 3))
    anchor = 200_000_000
    got = place_points(xyz, t, o, ext, anchor, num_threads=2)
    R_wi = o.rotation_at(t)
    p_w = np.einsum("nij,nj->ni", R_wi, xyz @ ext.R_imu_lidar.T + ext.lever_arm_m)
    R_a = o.rotation_at(np.array([anchor]))[0]
    expect = (p_w - R_a @ ext.lever_arm_m) @ (R_a @ ext.R_imu_lidar)
    np.testing.assert_allclose(got, expect, atol=3e-5)  # float32 at 17 m: ~1 µm


def test_clock_mapping_and_marks(capture):
    path, truth = capture
    rec = read_recording(path)
    assert rec.hour_source == "host"
    # packets' host stamps run 0.3 s + packet time + jitter ahead of the lidar clock
    d = host_to_lidar_offset_ns(rec.lidar)
    assert 300_000_000 < d < 302_000_000
    assert abs(rec.lidar.lidar_ns[0] - truth.t0_ns) < 1000  # the packets carry whole µs
    assert [label for _, label in rec.marks] == ["station-0", "station-1", "station-2"]
    assert len(rec.imu) == 2000


# ---- whole run on the synthetic capture -------------------------------------------------------
def test_stations_found_and_labelled(run):
    res, truth, _ = run
    st = res.segmentation.stations
    assert len(st) == len(truth.stations_span_ns) == 3
    for s, (a, b) in zip(st, truth.stations_span_ns):
        assert a - 10**8 <= s.start_ns and s.end_ns <= b + 10**8  # inside the true station
        assert s.duration_s > 0.6 * (b - a) * 1e-9
    assert [s.label for s in st] == ["station-0", "station-1", "station-2"]


def test_fragment_bounded_memory_path_keeps_the_cloud(run):
    # a long station is filtered at half the voxel whenever its placed points pass max_points;
    # the fragment must stay the same surface, about as dense
    from scipy.spatial import cKDTree

    from tripod_processor.reconstruction.fragments import build_fragment
    from tripod_processor.reconstruction.placement import fit_clock_map

    res, truth, _ = run
    rec = res.recording
    orient = ImuOrientation(rec.imu, fit_clock_map(rec.lidar), res.time_offset_ns,
                            smooth_s=ReconstructConfig().placement.imu_smooth_s)  # the run's
    st = res.fragments[0].station
    fc = ReconstructConfig().fragments  # the run's scan-line smoothing
    smoothing = dict(denoise_firings=fc.range_denoise_firings, denoise_fit=fc.range_denoise_fit,
                     denoise_max_step_m=fc.range_denoise_max_step_m)
    whole = build_fragment(rec.lidar, st, orient, res.extrinsic, 0.02, 0.4, 100.0, 2,
                           **smoothing)
    bounded = build_fragment(rec.lidar, st, orient, res.extrinsic, 0.02, 0.4, 100.0, 2,
                             chunk=100, max_points=whole.raw_points // 5, **smoothing)
    assert bounded.raw_points == whole.raw_points
    np.testing.assert_allclose(whole.points, res.fragments[0].points)
    assert abs(len(bounded.points) - len(whole.points)) < 0.05 * len(whole.points)
    d, _ = cKDTree(whole.points).query(bounded.points)
    assert np.median(d) < 0.01


def test_time_offset_estimate(tmp_path):
    """The IMU's latency is found from the data where the head's turn rate varies (at a
    constant rate a time offset only turns the whole fragment, and nothing can see it)."""
    from tripod_processor.reconstruction.calibration import estimate_time_offset
    from tripod_processor.reconstruction.config import StationConfig
    from tripod_processor.reconstruction.stations import segment_stations

    path = tmp_path / "wobble.mcap"
    truth = synth_capture(path, stations=((2.0, 1.5, 0.0), (4.8, 1.4, 40.0)),
                          pan_wobble_deg=15.0, imu_latency_ms=8.0)
    rec = read_recording(path)
    q = Rotation.from_matrix(truth.R_imu_lidar).as_quat()
    ext = Extrinsic(truth.R_imu_lidar, truth.lever_arm_m)
    o = ImuOrientation(rec.imu, host_to_lidar_offset_ns(rec.lidar))
    seg = segment_stations(rec.lidar, o, ext, StationConfig())
    assert len(seg.stations) == 2 and q is not None
    off, info = estimate_time_offset(rec.lidar, seg.stations, o, ext, 0.08)
    # IMU stamps are late by the latency (+ up to 0.5 ms jitter); the packets' by their fill
    # time (1.33 ms): the correction that puts the IMU on the lidar clock is about -6.9 ms
    expect_ms = -(truth.imu_time_offset_ns * 1e-6 + 0.25 - 1.33)
    assert abs(off * 1e-6 - expect_ms) < 0.8  # measured 0.26 ms off
    assert info["best_spread_m"] < 0.6 * info["zero_spread_m"]  # measured 0.51


def test_station_accuracy_against_truth(run):
    res, truth, out = run
    T_true = ev.interpolate_poses(truth.trajectory_t_ns, truth.trajectory_T, res.station_t_ns)
    e = ev.pose_errors(res.slam.T_optimized, T_true)
    # measured 0.35 mm / 0.019 deg, drift 0.028 % of 5.4 m (the goals: 2 cm, 0.2 deg,
    # 0.5 %; these bounds catch a regression long before it reaches them)
    assert e.ate_m < 0.002 and e.ate_deg < 0.06
    drift, path_m = ev.odometry_drift(res.slam.T_odometry, T_true)
    assert path_m > 5 and drift < 0.1
    r = ev.evaluate_run(out, truth.trajectory_t_ns, truth.trajectory_T)
    assert r["ate_cm"] < 0.2 and r["stations"] == 3


def test_map_lies_on_the_scene(run):
    res, truth, out = run
    from recon_synth import default_scene

    pts = cloud_io.xyz(cloud_io.read_ply(out / "map.ply"))
    t, T_est = read_tum(out / "stations.tum")
    A = ev.align_poses(T_est, ev.interpolate_poses(truth.trajectory_t_ns, truth.trajectory_T, t))
    p = pts @ A[:3, :3].T + A[:3, 3]
    # distance to the nearest face of the box room or its boxes
    scene = default_scene()
    boxes = [scene.room] + scene.obstacles
    d = np.full(len(p), np.inf)
    for b in boxes:
        lo, hi = np.array(b.lo), np.array(b.hi)
        inside = np.all((p >= lo) & (p <= hi), axis=1)
        out_d = np.linalg.norm(np.maximum(0, np.maximum(lo - p, p - hi)), axis=1)
        in_d = np.min(np.minimum(p - lo, hi - p), axis=1)
        d = np.minimum(d, np.where(inside, in_d, out_d))
    assert np.median(d) < 0.0025  # measured 1.0 mm
    assert np.percentile(d, 95) < 0.01  # measured 4.9 mm


def test_outputs_open_in_the_usual_tools(run):
    res, truth, out = run
    for name in ("map.ply", "map.pcd", "stations.tum", "trajectory.tum", "pose_graph.g2o",
                 "config.yaml", "result.json", "report.md", "report_planes.png",
                 "report_topdown.png", "reconstruction.mcap"):
        assert (out / name).stat().st_size > 0, name
    assert len(cloud_io.read_pcd(out / "map.pcd")) == len(cloud_io.read_ply(out / "map.ply"))
    assert len(list((out / "fragments").glob("station_*.ply"))) == 3
    # TUM: one line per station at its middle time, lidar time in UNIX seconds
    t, T = read_tum(out / "stations.tum")
    np.testing.assert_array_equal(t, res.station_t_ns)
    assert abs(t[0] * 1e-9 - truth.t0_ns * 1e-9) < 30
    # trajectory at >= 10 Hz over the whole recording
    tt, _ = read_tum(out / "trajectory.tum")
    assert np.all(np.diff(tt) <= 100_000_000)
    assert tt[0] - res.recording.lidar.lidar_ns[0] < 100_000_000
    assert res.recording.lidar.lidar_ns[-1] - tt[-1] < 100_000_000
    # z up: the floor is the lowest large surface, below every station
    z = cloud_io.xyz(cloud_io.read_ply(out / "map.ply"))[:, 2]
    assert np.percentile(z, 1) < T[:, 2, 3].min() - 1.0
    # the effective config reloads as the same config
    cfg2 = load_config(ReconstructConfig, out / "config.yaml")
    assert cfg2.placement.extrinsic.lever_arm_m == pytest.approx(truth.lever_arm_m.tolist())
    summary = json.loads((out / "result.json").read_text())
    assert summary["stations"] == 3 and summary["loop_edges"] >= 1
    # g2o: 3 vertices, every edge
    g2o = (out / "pose_graph.g2o").read_text().splitlines()
    assert sum(ln.startswith("VERTEX_SE3:QUAT") for ln in g2o) == 3
    assert sum(ln.startswith("EDGE_SE3:QUAT") for ln in g2o) == len(res.slam.edges)
    # violin statistics: floor/ceiling and walls found in every fragment
    planes = json.loads((out / "plane_errors.json").read_text())
    assert len(planes["horizontal"]) == 3 and len(planes["vertical"]) == 3


def test_foxglove_mcap(run):
    from mcap.reader import make_reader
    import base64

    _, _, out = run
    with open(out / "reconstruction.mcap", "rb") as fh:
        reader = make_reader(fh)
        schemas = {s.name for s in reader.get_summary().schemas.values()}
        assert schemas == {"foxglove.PointCloud", "foxglove.FrameTransform"}
        seen = {}
        for schema, channel, message in reader.iter_messages():
            body = json.loads(message.data)
            seen[channel.topic] = seen.get(channel.topic, 0) + 1
            if schema.name == "foxglove.PointCloud":
                n = len(base64.b64decode(body["data"])) // body["point_stride"]
                assert n > 1000 and body["fields"][0]["name"] == "x"
            else:
                assert body["parent_frame_id"] == "map"
    assert seen["/map"] == 1 and seen["/fragments"] == 3 and seen["/tf"] > 100


# ---- SLAM: disconnected stations are reported, never merged -------------------------------------
def test_station_without_overlap_is_reported_disconnected(run):
    from tripod_processor.reconstruction.config import OdometryConfig, SlamConfig
    from tripod_processor.reconstruction.fragments import Fragment
    from tripod_processor.reconstruction.slam import run_odometry, run_slam
    import dataclasses

    res, _, _ = run
    frags = list(res.fragments)
    # a fourth fragment from somewhere else: a long, narrow corridor none of the others saw
    rng = np.random.default_rng(5)
    n = 40000
    pts = np.stack([rng.uniform(-20, 20, n), rng.choice([-0.8, 0.8], n) + rng.normal(0, .005, n),
                    rng.uniform(-1.4, 1.3, n)], 1)
    floor = np.stack([rng.uniform(-20, 20, n), rng.uniform(-0.8, 0.8, n), np.full(n, -1.4)], 1)
    other = np.concatenate([pts, floor]).astype(np.float32)
    st = dataclasses.replace(frags[-1].station, index=3)
    frags.append(Fragment(st, other, np.eye(3), len(other)))
    T, edges, comp, notes = run_odometry(frags, OdometryConfig())
    slam = run_slam(frags, T, edges, comp, OdometryConfig(), SlamConfig())
    assert slam.disconnected == [3]
    assert any("disconnected" in n for n in slam.notes)
    assert slam.component[:3].tolist() == [0, 0, 0] and slam.component[3] != 0


# ---- bad input -----------------------------------------------------------------------------------
def test_recording_without_imu_is_a_clear_error(tmp_path):
    from tripod_processor.reconstruction.pipeline import reconstruct

    path = tmp_path / "noimu.mcap"
    synth_capture(path, stations=((2.0, 1.5, 0.0), (4.0, 1.5, 20.0)), station_s=3.5,
                  carry_s=1.5, with_imu=False)
    with pytest.raises(RecordingError, match="no IMU samples"):
        reconstruct(path, tmp_path / "out", quiet=True)
    proc = subprocess.run([sys.executable, "-m", "tripod_processor", "reconstruct", str(path),
                           "-o", str(tmp_path / "out2"), "--quiet"], capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.strip().count("\n") == 0 and "no IMU samples" in proc.stderr


def test_truncated_recording_keeps_what_was_written(capture, tmp_path):
    from tripod_processor.reconstruction.pipeline import reconstruct

    path, truth = capture
    cut = tmp_path / "cut.mcap"
    data = path.read_bytes()
    cut.write_bytes(data[: int(len(data) * 0.62)])
    cfg = load_config(ReconstructConfig, overrides={**_ext_overrides(truth),
                                                    "output.report": False,
                                                    "output.write_mcap": False})
    res = reconstruct(cut, tmp_path / "out", cfg, quiet=True)
    assert res.recording.truncated
    assert any("cut off" in n for n in res.notes)
    assert 1 <= len(res.fragments) <= 2


def test_missing_and_garbage_input(tmp_path):
    with pytest.raises(RecordingError, match="no such recording"):
        read_recording(tmp_path / "nope.mcap")
    junk = tmp_path / "junk.bin"
    junk.write_bytes(np.random.default_rng(0).bytes(5000))
    with pytest.raises(RecordingError):
        read_recording(junk)


def test_config_errors_name_the_key(tmp_path):
    with pytest.raises(ConfigError, match="unknown key 'odometry.voxel'"):
        load_config(ReconstructConfig, overrides={"odometry.voxel": 0.1})
    proc = subprocess.run([sys.executable, "-m", "tripod_processor", "reconstruct",
                           "--print-default-config"], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0
    p = tmp_path / "c.yaml"
    p.write_text(proc.stdout)
    assert load_config(ReconstructConfig, p) == ReconstructConfig()


def test_mount_rotation_calibrated_from_the_data(capture):
    """Hand-eye on sweep pairs recovers the mount up to the turn about the pan axis, which the
    fragments cannot see (and need not)."""
    from tripod_processor.reconstruction.calibration import calibrate_mount
    from tripod_processor.reconstruction.config import StationConfig
    from tripod_processor.reconstruction.placement import fit_clock_map
    from tripod_processor.reconstruction.stations import segment_stations

    path, truth = capture
    rec = read_recording(path)
    o = ImuOrientation(rec.imu, fit_clock_map(rec.lidar))
    seg = segment_stations(rec.lidar, o, Extrinsic(truth.R_imu_lidar, truth.lever_arm_m),
                           StationConfig())
    ext, info = calibrate_mount(rec.lidar, seg.stations, o)
    assert ext.source == "calibrated" and info["pairs"] >= 3
    pan_axis_imu = np.array([0.0, 0.0, 1.0])  # the head pans about the IMU's z here
    a_true = truth.R_imu_lidar.T @ pan_axis_imu  # the pan axis in the lidar frame
    a_est = ext.R_imu_lidar.T @ pan_axis_imu
    assert np.degrees(np.arccos(np.clip(a_true @ a_est, -1, 1))) < 0.5
    assert np.degrees(np.arccos(np.clip(a_true @ np.array([0, 0, 1.0]), -1, 1))) > 20  # not trivial


def _stalled_imu_stamps(lost=()):
    """100 Hz IMU stamps read by a host that stalls 120 ms every 2 s (samples then read in a
    burst), with read jitter; optionally some samples lost."""
    from numpy.random import default_rng

    rng = default_rng(4)
    P, n = 10_000_000, 6000
    true = 7_000_000_000 + np.arange(n, dtype=np.int64) * P
    host = true + 250_000 + rng.exponential(300_000, n).astype(np.int64)
    for s in range(100, n - 20, 200):
        host[s:s + 12] = np.maximum(host[s:s + 12], true[s + 12] + 100_000)
    host = np.sort(host)
    keep = np.setdiff1d(np.arange(n), lost)
    return true[keep], host[keep]


def test_dejitter_removes_host_stalls():
    from tripod_processor.reconstruction.placement import dejitter_periodic

    true, host = _stalled_imu_stamps()
    err = dejitter_periodic(host) - true
    assert (np.percentile(host - true, 99) - np.percentile(host - true, 1)) > 50e6  # stalls
    assert np.abs(err - np.median(err)).max() < 1e6  # < 1 ms once de-jittered
    assert 0 < np.median(err) < 1e6  # at the latency floor


def test_dejitter_keeps_raw_stamps_when_samples_were_lost():
    from tripod_processor.reconstruction.placement import _strictly_increasing, dejitter_periodic

    _, host = _stalled_imu_stamps(lost=(1500, 3100, 4700))
    assert np.array_equal(dejitter_periodic(host), _strictly_increasing(host))


# ---- survey deliverables: E57 per station, LAS/LAZ map (read back by pye57 and laspy) ----------
def test_survey_deliverables(run, tmp_path):
    import laspy
    import pye57

    from tripod_processor.cli import main
    from tripod_processor.io.e57 import NO_LABEL, read_e57
    from tripod_processor.reconstruction.survey import labels_from_asprs

    res, truth, out = run
    t_st, T_st = read_tum(out / "stations.tum")
    # E57: one scan per station, points in the station frame, the pose of stations.tum
    e57 = pye57.E57(str(out / "stations.e57"))
    assert e57.scan_count == 3
    for k in range(3):
        h = e57.get_header(k)
        frag = cloud_io.read_ply(out / "fragments" / f"station_{k:03d}.ply")
        assert h.point_count == len(frag)
        glob = e57.read_scan(k, intensity=True, transform=True)
        p_map = np.stack([glob["cartesianX"], glob["cartesianY"], glob["cartesianZ"]], 1)
        want = cloud_io.xyz(frag) @ T_st[k][:3, :3].T + T_st[k][:3, 3]
        assert np.abs(p_map - want).max() < 2e-4  # 0.1 mm grid + float32 fragment points
        # the synthetic lidar returns intensity 100 everywhere
        assert np.nanmedian(glob["intensity"]) == pytest.approx(100.0)
    e57.close()
    scans = read_e57(out / "stations.e57")
    labelled = np.concatenate([s.label for s in scans])
    assert np.isin(labelled, [0, 1, 2, 3, NO_LABEL]).all()
    assert (labelled != NO_LABEL).mean() > 0.9
    for s, tk in zip(scans, t_st):
        assert s.start_ns < tk < s.end_ns
    # LAS: the map with intensity, station and ASPRS classes
    las = laspy.read(out / "map.laz")
    mp = cloud_io.read_ply(out / "map.ply")
    assert len(las.points) == len(mp) == res.map_points
    xyz_las = np.stack([las.x, las.y, las.z], 1)
    assert np.abs(xyz_las - cloud_io.xyz(mp)).max() <= 0.5e-4 + 1e-6
    assert set(np.unique(las.point_source_id)) <= {1, 2, 3}  # station + 1
    np.testing.assert_array_equal(np.asarray(las.point_source_id) - 1, mp["station"])
    np.testing.assert_array_equal(labels_from_asprs(np.asarray(las.classification)), mp["label"])
    assert np.median(las.intensity) == 100 * 256
    # the floor (lowest points) is mostly ASPRS ground, the ceiling mostly code 64
    z = xyz_las[:, 2]
    cls = np.asarray(las.classification)
    assert (cls[z < np.percentile(z, 3)] == 2).mean() > 0.7
    assert (cls[z > np.percentile(z, 97)] == 64).mean() > 0.7
    # tripod export rebuilds the same E57 from the folder, and LAS from map.ply
    assert main(["export", "e57", str(out), "-o", str(tmp_path / "s.e57")]) == 0
    again = read_e57(tmp_path / "s.e57")
    for a, b in zip(scans, again):
        np.testing.assert_array_equal(a.points, b.points)
        np.testing.assert_array_equal(a.label, b.label)
        np.testing.assert_allclose(a.T_map_station, b.T_map_station, atol=1e-6)
    assert main(["export", "las", str(out / "map.ply"), "-o", str(tmp_path / "m.las")]) == 0
    las2 = laspy.read(tmp_path / "m.las")
    np.testing.assert_array_equal(np.asarray(las2.classification), cls)
    np.testing.assert_array_equal(np.asarray(las2.point_source_id),
                                  np.asarray(las.point_source_id))


def test_cli_survey_flag_writes_the_survey_files(capture, tmp_path):
    import pye57

    from tripod_processor.cli import main

    path, truth = capture
    cut = tmp_path / "cut.mcap"  # two stations: a short run
    data = path.read_bytes()
    cut.write_bytes(data[: int(len(data) * 0.62)])
    calib = tmp_path / "calib.yaml"
    q = _ext_overrides(truth)
    calib.write_text(json.dumps({"q_imu_lidar": [float(v) for v in
                                                 q["placement.extrinsic.q_imu_lidar"]],
                                 "lever_arm_m": q["placement.extrinsic.lever_arm_m"]}))
    out = tmp_path / "out"
    assert main(["reconstruct", str(cut), "-o", str(out), "--survey", "--quiet", "--calibration",
                 str(calib), "--set", "output.report=false", "--set",
                 "output.write_mcap=false"]) == 0
    t, _ = read_tum(out / "stations.tum")
    e57 = pye57.E57(str(out / "stations.e57"))
    assert e57.scan_count == len(t) >= 1
    e57.close()
    assert (out / "map.laz").stat().st_size > 0
    assert set(cloud_io.read_ply(out / "map.ply").dtype.names) == {"x", "y", "z", "intensity",
                                                                    "station", "label"}
