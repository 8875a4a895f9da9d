# SPDX-License-Identifier: BSD-3-Clause
"""Gravity travels with the data: the up direction in PLY/PCD headers (round trip, other readers),
``tripod reconstruct`` writing it (against the truth of a side-mounted capture), and ``tripod
segment`` / ``heightmaps`` / ``register --method heightmaps`` using it, ``--up`` overriding it."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from recon_synth import synth_capture
from tripod_processor.cli import main
from tripod_processor.io import clouds as cloud_io
from tripod_processor.reconstruction import evaluation as ev
from tripod_processor.scene.gravity import R_level_cloud, parse_up

E_Z = np.array([0.0, 0.0, 1.0])


def _angle_deg(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    c = a @ b / np.linalg.norm(a) / np.linalg.norm(b)
    return float(np.degrees(np.arccos(np.clip(c, -1, 1))))


def _rot_err_deg(R) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))))


# ---- file formats ------------------------------------------------------------------------------
@pytest.mark.parametrize("ext", [".ply", ".pcd"])
def test_up_round_trip_and_other_readers(tmp_path, ext):
    import open3d as o3d

    rng = np.random.default_rng(3)
    c = cloud_io.make_cloud(rng.normal(size=(500, 3)), intensity=rng.random(500).astype("f4"))
    up = np.array([0.3, -0.9, 0.2])
    path = tmp_path / f"c{ext}"
    cloud_io.write_cloud(path, c, up=up)
    back, meta = cloud_io.read_cloud_meta(path)
    np.testing.assert_allclose(meta.up, up / np.linalg.norm(up), atol=1e-8)
    for name in c.dtype.names:
        np.testing.assert_array_equal(back[name], c[name])
    # the plain readers and Open3D open the file as before (the up is a header comment)
    plain = cloud_io.read_ply(path) if ext == ".ply" else cloud_io.read_pcd(path)
    np.testing.assert_array_equal(cloud_io.xyz(plain), cloud_io.xyz(c))
    ref = np.asarray(o3d.io.read_point_cloud(str(path)).points)
    np.testing.assert_allclose(ref, cloud_io.xyz(c), atol=1e-6)
    # without an up there is none; a malformed one is a clear error
    cloud_io.write_cloud(tmp_path / f"n{ext}", c)
    assert cloud_io.read_cloud_meta(tmp_path / f"n{ext}")[1].up is None
    raw = path.read_bytes()
    bad = tmp_path / f"bad{ext}"
    bad.write_bytes(raw.replace(b"tripod up ", b"tripod up x ", 1))
    with pytest.raises(cloud_io.CloudFormatError, match="tripod up"):
        cloud_io.read_cloud_meta(bad)


def test_level_rotation_and_parse_up():
    rng = np.random.default_rng(0)
    for u in [*rng.normal(size=(20, 3)), E_Z, -E_Z, np.array([0, 1e-14, 1.0])]:
        R = R_level_cloud(u)
        np.testing.assert_allclose(R @ u / np.linalg.norm(u), E_Z, atol=1e-9)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-9)
        assert np.linalg.det(R) == pytest.approx(1.0)
    np.testing.assert_allclose(R_level_cloud(E_Z), np.eye(3))
    np.testing.assert_allclose(parse_up("0, 2,0"), [0, 1, 0])
    for bad in ("1,2", "a,b,c", "0,0,0", "nan,0,1"):
        with pytest.raises(ValueError, match="--up"):
            parse_up(bad)


# ---- reconstruct -> up -> scene commands on a side-mounted capture -------------------------------
@pytest.fixture(scope="module")
def side_run(tmp_path_factory):
    """A small capture with the lidar side-mounted (spin axis 90 deg from the pan axis),
    reconstructed with its fragments."""
    from tripod_processor.reconstruction.config import ReconstructConfig
    from tripod_processor.reconstruction.pipeline import reconstruct
    from tripod_shared.config_io import load_config

    d = tmp_path_factory.mktemp("side")
    truth = synth_capture(d / "rec.mcap", tilt_deg=90.0, lever=(0.0, 0.10, 0.08))
    x, y, z, w = Rotation.from_matrix(truth.R_imu_lidar).as_quat()
    cfg = load_config(ReconstructConfig, overrides={
        "placement.extrinsic.q_imu_lidar": [w, x, y, z],
        "placement.extrinsic.lever_arm_m": truth.lever_arm_m.tolist(),
        "output.write_mcap": False, "output.report": False})
    res = reconstruct(d / "rec.mcap", d / "out", cfg, quiet=True)
    assert len(res.fragments) == 3
    # the true T_world_lidar at each fragment's own time (the middle of the station found)
    T_true = ev.interpolate_poses(truth.trajectory_t_ns, truth.trajectory_T, res.station_t_ns)
    return res, T_true, d / "out"


def test_reconstruct_writes_up_that_matches_the_truth(side_run):
    res, T_true, out = side_run
    for k, T in enumerate(T_true):
        _, meta = cloud_io.read_cloud_meta(out / "fragments" / f"station_{k:03d}.ply")
        up_true = T[:3, :3].T @ E_Z
        assert _angle_deg(meta.up, up_true) < 0.3  # measured ~0.02 deg (IMU noise 0.02 deg)
        assert abs(meta.up[2]) < 0.2  # side-mounted: up is far from the lidar's z
    # the map is in the gravity-aligned map frame: its up is +z
    for name in ("map.ply", "map.pcd"):
        assert _angle_deg(cloud_io.read_cloud_meta(out / name)[1].up, E_Z) < 0.3


def _truth_T(T_true, tgt: int, src: int) -> np.ndarray:
    return np.linalg.inv(T_true[tgt]) @ T_true[src]


def _register(capsys, src, tgt, *extra):
    rc = main(["register", str(src), str(tgt), "--method", "heightmaps", "--threads", "2",
               *extra])
    return rc, json.loads(capsys.readouterr().out)


def test_register_heightmaps_side_mounted_pair_with_up(side_run, capsys):
    res, T_true, out = side_run
    f = out / "fragments"
    rc, r = _register(capsys, f / "station_001.ply", f / "station_000.ply")
    assert rc == 0 and r["success"] and r["up"]["source_from"] == "file"
    E = np.linalg.inv(_truth_T(T_true, 0, 1)) @ np.array(r["T_target_source"])
    assert _rot_err_deg(E[:3, :3]) < 1.0 and np.linalg.norm(E[:3, 3]) < 0.05


def test_up_option_overrides_the_file(side_run, capsys, tmp_path):
    res, T_true, out = side_run
    # copies that carry a wrong up (+z of the lidar: the side-mounted lidar's z is horizontal)
    wrong = []
    for k in (0, 2):
        c, meta = cloud_io.read_cloud_meta(out / "fragments" / f"station_{k:03d}.ply")
        cloud_io.write_ply(tmp_path / f"w{k}.ply", c, up=E_Z)
        wrong.append((tmp_path / f"w{k}.ply", meta.up))
    up = ",".join(f"{v:.7f}" for v in wrong[0][1])
    rc, r = _register(capsys, wrong[1][0], wrong[0][0], "--up", up)
    assert rc == 0 and r["success"] and r["up"]["target_from"] == "--up"
    E = np.linalg.inv(_truth_T(T_true, 0, 2)) @ np.array(r["T_target_source"])
    assert _rot_err_deg(E[:3, :3]) < 1.0 and np.linalg.norm(E[:3, 3]) < 0.05
    # segment: the file's wrong up levels the cloud onto its side; --up puts it right, and
    # the labels then match those of the original file (which carries the true up)
    seg_true, seg_up = tmp_path / "s_true.ply", tmp_path / "s_up.ply"
    assert main(["segment", str(out / "fragments" / "station_000.ply"), "-o", str(seg_true),
                 "--threads", "2"]) == 0
    assert main(["segment", str(wrong[0][0]), "-o", str(seg_up), "--up", up,
                 "--threads", "2"]) == 0
    a, ma = cloud_io.read_cloud_meta(seg_true)
    b, mb = cloud_io.read_cloud_meta(seg_up)
    assert (a["label"] == b["label"]).mean() > 0.99
    assert _angle_deg(ma.up, wrong[0][1]) < 1e-6 and _angle_deg(mb.up, wrong[0][1]) < 1e-3
    # in the level frame the floor (1) lies below the ceiling (0)
    z = (cloud_io.xyz(a) @ R_level_cloud(ma.up).T)[:, 2]
    assert np.median(z[a["label"] == 1]) < np.median(z[a["label"] == 0]) - 2.0


def test_heightmaps_levels_by_the_up(side_run, tmp_path, capsys):
    res, T_true, out = side_run
    frag = out / "fragments" / "station_000.ply"
    assert main(["heightmaps", str(frag), "-o", str(tmp_path / "hm"), "--threads", "2"]) == 0
    planes = json.loads((tmp_path / "hm" / "planes.json").read_text())
    R = np.array(planes["frame"]["R_level_cloud"])
    up = cloud_io.read_cloud_meta(frag)[1].up
    np.testing.assert_allclose(R @ up, E_Z, atol=1e-9)
    # levelled: a floor and a ceiling come out horizontal, 2.7 m apart (the box room)
    horiz = [p for p in planes["planes"] if p["label"] in (0, 1)]  # ceiling, floor
    assert {p["label"] for p in horiz} == {0, 1}
    for p in horiz:
        assert abs(abs(p["normal"][2]) - 1) < 0.01


def test_register_global_gravity_uses_the_files_up(side_run, capsys):
    """``register --global --gravity`` takes each file's up: the pose comes out level (the
    source's up onto the target's) and right.

    Station 1 onto 0 is a near tie in this box room between the truth and its 180° twin about
    the up (cloud fitness 0.55-0.60 either way; refined, the twin fits better: what station 1
    sees behind the column, station 0 does not). Until stop 37 RANSAC's best by fitness was
    the twin on 2-3 of 10 RANSAC seeds (seeds 0 and 1 among them with these fragments); the
    twin check (``register_global(twin_check=True)``, the default) refines both and counts
    free space: the twin puts points where station 0 saw through to the walls (3.4 %), the
    truth none. Held to the truth on five seeds (the command line's, 0, and 1-4 through the
    API the command calls)."""
    from tripod_processor.registration import pairwise as reg

    res, T_true, out = side_run
    f = out / "fragments"
    for src in (1, 2):
        rc = main(["register", str(f / f"station_00{src}.ply"), str(f / "station_000.ply"),
                   "--global", "--gravity", "--voxel", "0.1", "--method", "plane",
                   "--threads", "2"])
        r = json.loads(capsys.readouterr().out)
        assert rc == 0 and r["global"]["success"] and not r["global"]["ambiguous"]
        E = np.linalg.inv(_truth_T(T_true, 0, src)) @ np.array(r["T_target_source"])
        assert _rot_err_deg(E[:3, :3]) < 1.0 and np.linalg.norm(E[:3, 3]) < 0.05, src
    (s, ms), (t, mt) = (cloud_io.read_cloud_meta(f / "station_001.ply"),
                        cloud_io.read_cloud_meta(f / "station_000.ply"))
    s, t = cloud_io.xyz(s), cloud_io.xyz(t)
    for seed in range(1, 5):
        g = reg.register_global(s, t, 0.1, up_source=ms.up, up_target=mt.up, seed=seed,
                                num_threads=2)
        r = reg.register(s, t, "plane", init=g.T_target_source, voxel_size=0.1, num_threads=2)
        E = np.linalg.inv(_truth_T(T_true, 0, 1)) @ r.T_target_source
        assert _rot_err_deg(E[:3, :3]) < 1.0 and np.linalg.norm(E[:3, 3]) < 0.05, seed
    # --up belongs to the heightmaps method and --gravity only
    assert main(["register", str(f / "station_001.ply"), str(f / "station_000.ply"),
                 "--up", "0,0,1"]) == 2
    assert "--gravity" in capsys.readouterr().err
