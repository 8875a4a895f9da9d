# SPDX-License-Identifier: BSD-3-Clause
"""Survey formats written by tripod and read back by their own libraries: LAS 1.4 / LAZ
(laspy + lazrs), E57 (pye57 / libE57Format), OBJ (Open3D's reader)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from tripod_processor.io.e57 import LABEL_FIELD, NO_LABEL, E57Scan, read_e57, write_e57
from tripod_processor.io.las import LasCloud, read_las, write_las
from tripod_processor.preprocess import (
    lookup_keys,
    voxel_downsample,
    voxel_keys,
    voxel_majority,
    voxel_mean,
)
from tripod_processor.reconstruction.survey import ASPRS_CLASS, asprs_codes, labels_from_asprs


def _cloud(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    pts = rng.uniform([-12.0, -3.0, -1.5], [25.0, 9.0, 3.2], (n, 3))
    inten = rng.uniform(0, 255, n).astype(np.float32)
    inten[::97] = np.nan  # unknown
    station = rng.integers(-1, 7, n).astype(np.int32)
    label = rng.choice([0, 1, 2, 3, NO_LABEL], n).astype(np.uint8)
    return pts, inten, station, label


@pytest.mark.parametrize("ext", ["las", "laz"])
def test_las_round_trip_within_quantisation(tmp_path, ext):
    import laspy

    pts, inten, station, label = _cloud(20_000)
    path = tmp_path / f"map.{ext}"
    write_las(path, LasCloud(pts, inten, station, asprs_codes(label)))
    las = laspy.read(path)  # the independent reader (lazrs decompresses LAZ)
    assert las.header.version == laspy.header.Version(1, 4)
    assert las.header.point_format.id == 6
    assert las.header.are_points_compressed == (ext == "laz")
    got = np.stack([las.x, las.y, las.z], axis=1)
    assert np.abs(got - pts).max() <= 0.5e-4 + 1e-9  # 0.1 mm grid
    expect_i = np.round(np.nan_to_num(inten) * 256)
    np.testing.assert_array_equal(np.asarray(las.intensity), expect_i.astype(np.uint16))
    np.testing.assert_array_equal(np.asarray(las.point_source_id), station + 1)
    np.testing.assert_array_equal(labels_from_asprs(np.asarray(las.classification)), label)
    back = read_las(path)
    ok = np.isfinite(inten)
    assert np.abs(back.intensity[ok] - inten[ok]).max() <= 0.5 / 256
    np.testing.assert_array_equal(back.station, station)


def test_asprs_mapping_is_documented_and_invertible():
    assert ASPRS_CLASS == {0: 64, 1: 2, 2: 6, 3: 1}  # ceiling, floor=ground, wall=building
    labels = np.array([0, 1, 2, 3, NO_LABEL], np.uint8)
    np.testing.assert_array_equal(asprs_codes(labels), [64, 2, 6, 1, 0])
    np.testing.assert_array_equal(labels_from_asprs(asprs_codes(labels)), labels)


def _scans():
    out = []
    for k in range(3):
        pts, inten, _, label = _cloud(5000 + 100 * k, seed=k)
        T = np.eye(4)
        T[:3, :3] = Rotation.from_euler("zyx", [40.0 * k + 5, 1.0 * k, -2.0], degrees=True
                                        ).as_matrix()
        T[:3, 3] = [3.0 * k, -1.25 * k, 1.4]
        out.append(E57Scan(f"station_{k:03d}", pts, T, inten, label,
                           1_700_000_000_000_000_000 + k * 10**10,
                           1_700_000_005_000_000_000 + k * 10**10))
    return out


def test_e57_round_trip_one_scan_per_station(tmp_path):
    import pye57

    scans = _scans()
    path = tmp_path / "stations.e57"
    write_e57(path, scans)
    e57 = pye57.E57(str(path))  # the independent reader: pye57's own API
    assert e57.scan_count == 3
    for i, s in enumerate(scans):
        h = e57.get_header(i)
        assert LABEL_FIELD in h.point_fields
        raw = e57.read_scan_raw(i, ignore_unsupported_fields=True)
        got = np.stack([raw["cartesianX"], raw["cartesianY"], raw["cartesianZ"]], axis=1)
        assert np.abs(got - s.points).max() <= 0.5e-4 + 1e-9
        # pye57 applies the pose: the points land in the map frame, T_map_station · p
        glob = e57.read_scan(i, intensity=True, transform=True)
        gp = np.stack([glob["cartesianX"], glob["cartesianY"], glob["cartesianZ"]], axis=1)
        want = s.points @ s.T_map_station[:3, :3].T + s.T_map_station[:3, 3]
        assert np.abs(gp - want).max() < 1e-3
        ok = np.isfinite(s.intensity)
        np.testing.assert_allclose(raw["intensity"][ok], s.intensity[ok], atol=1e-4)
    e57.close()
    back = read_e57(path)
    for s, b in zip(scans, back):
        assert b.name == s.name
        np.testing.assert_allclose(b.T_map_station, s.T_map_station, atol=1e-12)
        np.testing.assert_array_equal(b.label, s.label)
        np.testing.assert_array_equal(np.isnan(b.intensity), np.isnan(s.intensity))
        assert abs(b.start_ns - s.start_ns) < 1000 and abs(b.end_ns - s.end_ns) < 1000


def test_voxel_attributes_follow_the_downsample_lattice():
    rng = np.random.default_rng(3)
    pts = rng.uniform(-2, 2, (50_000, 3)).astype(np.float32)
    val = rng.uniform(0, 255, len(pts)).astype(np.float32)
    st = rng.integers(0, 3, len(pts))
    size = 0.1
    cent = voxel_downsample(pts, size)
    keys = voxel_keys(pts, size)
    uk, mean = voxel_mean(keys, val)
    got = lookup_keys(uk, mean, voxel_keys(cent, size), np.float32(np.nan))
    assert np.isfinite(got).mean() > 0.999  # centroids fall in their own voxel
    # brute force for a few voxels
    for i in range(0, len(cent), 997):
        if not np.isfinite(got[i]):
            continue
        m = keys == voxel_keys(cent[i:i + 1], size)[0]
        assert got[i] == pytest.approx(val[m].mean(), rel=1e-5)
        mk, major = voxel_majority(keys[m], st[m])
        counts = np.bincount(st[m], minlength=3)
        assert major[0] == int(np.argmax(counts))


def test_obj_mesh_opens_in_open3d(tmp_path):
    import open3d as o3d
    from tripod_processor.io.mesh_obj import read_obj, write_obj
    from tripod_processor.scene.heightmaps import CLASS_COLOURS, CLASS_NAMES

    v = np.array([[0, 0, 0], [4, 0, 0], [4, 3, 0], [0, 3, 0], [0, 0, 2.5], [4, 0, 2.5]], float)
    tri = np.array([[0, 1, 2], [0, 2, 3], [0, 1, 5], [0, 5, 4]])
    cls = np.array([1, 1, 2, 2])
    path = tmp_path / "room.obj"
    write_obj(path, v, tri, cls, list(CLASS_NAMES), CLASS_COLOURS)
    assert (tmp_path / "room.mtl").read_text().count("newmtl") == 4
    mesh = o3d.io.read_triangle_mesh(str(path))
    # Open3D gives each material its own vertices: compare the triangles' corners
    corners = np.asarray(mesh.vertices)[np.asarray(mesh.triangles)]
    np.testing.assert_allclose(corners, v[tri], atol=1e-6)
    rv, rt, groups = read_obj(path)
    np.testing.assert_array_equal(rt, tri)
    assert groups == ["floor", "floor", "wall", "wall"]


def test_cli_export_of_clouds(tmp_path, capsys):
    import laspy
    import pye57

    from tripod_processor.cli import main
    from tripod_processor.io.clouds import make_cloud, write_ply

    pts, inten, station, label = _cloud(3000, seed=5)
    src = tmp_path / "labelled.ply"
    write_ply(src, make_cloud(pts, intensity=np.nan_to_num(inten), label=label.astype(np.int32)))
    assert main(["export", "las", str(src), "-o", str(tmp_path / "c.laz")]) == 0
    las = laspy.read(tmp_path / "c.laz")
    np.testing.assert_array_equal(labels_from_asprs(np.asarray(las.classification)), label)
    assert set(np.unique(las.point_source_id)) == {0}  # no station field: unknown
    assert main(["export", "e57", str(src), "-o", str(tmp_path / "c.e57")]) == 0
    e57 = pye57.E57(str(tmp_path / "c.e57"))
    assert e57.scan_count == 1 and e57.get_header(0).point_count == 3000
    e57.close()
    np.testing.assert_array_equal(read_e57(tmp_path / "c.e57")[0].label, label)
    # bad input: one line, exit 2
    capsys.readouterr()
    assert main(["export", "las", str(src), "-o", str(tmp_path / "c.txt")]) == 2
    assert main(["export", "e57", str(tmp_path / "missing"), "-o", str(tmp_path / "x.e57")]) == 2
    assert main(["export", "e57", str(tmp_path), "-o", str(tmp_path / "x.e57")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and all(e.startswith("tripod: error:") for e in err)


def test_map_attributes_one_sort_matches_the_reference():
    from tripod_processor.reconstruction.survey import map_attributes

    rng = np.random.default_rng(11)
    frags = [rng.uniform(-1, 1, (n, 3)).astype(np.float32) for n in (4000, 2500, 6000)]
    inten = [rng.uniform(0, 255, len(p)).astype(np.float32) for p in frags]
    inten[1][::5] = np.nan
    stations = [4, 7, 9]
    size = 0.2
    allp = np.concatenate(frags)
    cent = voxel_downsample(allp, size)
    got_i, got_s = map_attributes(frags, inten, stations, cent, size)
    # reference: voxel_mean / voxel_majority (two sorts) on the same points
    keys = voxel_keys(allp, size)
    uk, mean = voxel_mean(keys, np.concatenate(inten))
    mk, major = voxel_majority(keys, np.repeat(stations, [len(p) for p in frags]))
    ck = voxel_keys(cent, size)
    np.testing.assert_allclose(got_i, lookup_keys(uk, mean, ck, np.float32(np.nan)), rtol=1e-6)
    np.testing.assert_array_equal(got_s, lookup_keys(mk, major, ck, -1))
    assert (got_s >= 0).mean() > 0.99
