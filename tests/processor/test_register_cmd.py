# SPDX-License-Identifier: BSD-3-Clause
"""``tripod register`` end to end on the real PCL pairs (PCD, binary_compressed too)."""

from __future__ import annotations

import json

import numpy as np

from tripod_processor.io import clouds as cloud_io
from tripod_processor.cli import main


def _rot_err_deg(T, G) -> float:
    dR = np.asarray(T)[:3, :3].T @ G[:3, :3]
    return float(np.degrees(np.arccos(np.clip((np.trace(dR) - 1) / 2, -1, 1))))


def test_register_room_scans_global_gravity(registration_dir, capsys, tmp_path):
    d = registration_dir / "pcl"
    out = tmp_path / "res.json"
    rc = main(["register", str(d / "room_scan2.pcd"), str(d / "room_scan1.pcd"), "--voxel", "0.1",
               "--global", "--gravity", "-o", str(out), "--threads", "2"])
    assert rc == 0
    res = json.loads(capsys.readouterr().out)
    G = cloud_io.read_matrix4(d / "room_scan2_to_room_scan1_reference.txt")
    T = np.array(res["T_target_source"])
    assert res["converged"] and res["global"]["success"]
    assert _rot_err_deg(T, G) < 2.0 and np.linalg.norm(T[:3, 3] - G[:3, 3]) < 0.1
    assert json.loads(out.read_text()) == res
    assert json.loads((tmp_path / "res.options.json").read_text())["voxel"] == 0.1


def test_register_init_file_and_methods(registration_dir, capsys, tmp_path):
    d = registration_dir / "pcl"
    G = cloud_io.read_matrix4(d / "room_scan2_to_room_scan1_reference.txt")
    init = tmp_path / "init.txt"
    T0 = G.copy()
    T0[:3, 3] += [0.2, -0.1, 0.0]
    np.savetxt(init, T0)
    for method in ("plane", "lm"):
        rc = main(["register", str(d / "room_scan2.pcd"), str(d / "room_scan1.pcd"), "-m", method,
                   "--init", str(init), "--voxel", "0.1", "--max-distance", "0.5,0.2",
                   "--loss", "huber"])
        assert rc == 0
        T = np.array(json.loads(capsys.readouterr().out)["T_target_source"])
        assert _rot_err_deg(T, G) < 2.0 and np.linalg.norm(T[:3, 3] - G[:3, 3]) < 0.1


def test_register_bad_input_is_one_line(tmp_path, capsys):
    assert main(["register", str(tmp_path / "none.pcd"), str(tmp_path / "none.ply")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("tripod: error: no such file") and "\n" not in err
    bad = tmp_path / "bad.pcd"
    bad.write_text("garbage\n")
    assert main(["register", str(bad), str(bad)]) == 2
    assert capsys.readouterr().err.startswith("tripod: error:")
    empty = tmp_path / "empty.ply"
    cloud_io.write_cloud(empty, cloud_io.make_cloud(np.zeros((2, 3), np.float32)))
    assert main(["register", str(empty), str(empty)]) == 2
    assert "finite points" in capsys.readouterr().err
    assert main(["register", str(empty), str(empty), "-m", "ndt"]) == 2
    assert main(["register", str(empty), str(empty), "--global"]) == 2
