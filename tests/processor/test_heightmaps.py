# SPDX-License-Identifier: BSD-3-Clause
"""Heightmaps: relief against the mesh, PNG/JSON round trip, low-poly model, CLI (registration
by heightmaps: test_heightmap_registration.py)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tripod_processor.cli import main
from tripod_processor.io.clouds import make_cloud, write_ply
from tripod_processor.scene.heightmaps import (Heightmap, low_poly_mesh, plane_heightmap, relief_rmse,
                                         truth_heightmap, write_mesh_ply)
from tripod_processor.scene.planes import WALL, extract_planes

from scene_fixtures import room_scan


def test_relief_of_a_box_on_a_wall():
    """A 10 cm deep box on a wall shows as a 10 cm step; the rest of the wall stays at 0."""
    rng = np.random.default_rng(1)
    wall = np.c_[np.zeros(60000), rng.uniform([0, 0], [4, 2.5], (60000, 2))]
    box = np.c_[np.full(8000, 0.10), rng.uniform([1, 1], [2, 1.5], (8000, 2))]
    behind = (wall[:, 1] > 1) & (wall[:, 1] < 2) & (wall[:, 2] > 1) & (wall[:, 2] < 1.5)
    p = np.concatenate([wall[~behind], box]) + rng.normal(0, 0.01, (len(wall[~behind]) + 8000, 3)) * [1, 0, 0]
    lab = np.r_[np.full((~behind).sum(), WALL), np.full(8000, 3)]
    planes = extract_planes(p.astype(np.float32), lab)
    assert len(planes) == 1
    n = np.tile(planes[0].normal, (len(p), 1))  # every point faces the plane
    hm = plane_heightmap(p, planes[0], pixel=0.1, normals=n)
    centres = hm.pixel_centres()
    inside = ((centres[..., 1] > 1.15) & (centres[..., 1] < 1.85) & (centres[..., 2] > 1.15)
              & (centres[..., 2] < 1.35))
    outside = (centres[..., 1] > 2.5) & np.isfinite(hm.height)
    sign = np.sign(planes[0].normal[0])
    assert np.nanmedian(hm.height[inside]) * sign == pytest.approx(0.10, abs=0.01)
    assert np.nanmedian(np.abs(hm.height[outside])) < 0.005
    assert hm.counts.sum() == len(p)


def test_png_json_round_trip(tmp_path):
    p, lab, scene, _ = room_scan(31, head_steps=8)
    pl = extract_planes(p, lab)[0]
    hm = plane_heightmap(p, pl)
    hm.save(tmp_path / "a.png")
    meta = json.loads((tmp_path / "a.json").read_text())
    assert {"plane", "pixel_size_m", "origin_m", "axes", "encoding", "holes"} <= set(meta)
    back = Heightmap.load(tmp_path / "a.png")
    assert back.height.shape == hm.height.shape
    np.testing.assert_array_equal(np.isfinite(back.height), np.isfinite(hm.height))
    assert np.nanmax(np.abs(back.height - hm.height)) <= 0.5e-4 + 1e-7
    from PIL import Image

    im = Image.open(tmp_path / "a.png")
    assert im.mode in ("I;16", "I") and np.asarray(im).dtype in (np.uint16, np.int32)
    assert (np.asarray(im) == 0).sum() == meta["holes"] > 0


def test_relief_rmse_below_sensor_noise():
    """3 cm range noise; the median per 5 cm pixel must beat it against the mesh."""
    p, lab, scene, _ = room_scan(32, head_steps=24, noise_m=0.03)
    rs = scene.raycasting_scene()
    for pl in extract_planes(p, lab)[:4]:
        hm = plane_heightmap(p, pl)
        rmse, n = relief_rmse(hm, rs)
        assert n > 500 and rmse < 0.03, (pl.label, rmse, n)
    truth = truth_heightmap(hm, rs)
    assert truth.shape == hm.height.shape


def test_low_poly_mesh_of_a_room(tmp_path):
    p, lab, scene, _ = room_scan(33, kind="L", head_steps=12)
    planes = extract_planes(p, lab)
    V, T, C = low_poly_mesh(planes)
    assert len(T) >= 2 * len(planes) and set(np.unique(C)) == {0, 1, 2}
    write_mesh_ply(tmp_path / "m.ply", V, T, C)
    import open3d as o3d

    m = o3d.io.read_triangle_mesh(str(tmp_path / "m.ply"))
    assert len(m.triangles) == len(T)
    # the floor's triangles cover about its outline area
    area = sum(0.5 * np.linalg.norm(np.cross(V[b] - V[a], V[c] - V[a])) for (a, b, c), k in zip(T, C) if k == 1)
    floor = [pl for pl in planes if pl.label == 1][0]
    assert area == pytest.approx(floor.area, rel=0.25)


def test_cli_heightmaps(tmp_path, capsys):
    p, lab, _, _ = room_scan(34, head_steps=8)
    src = tmp_path / "room.ply"
    write_ply(src, make_cloud(p, label=lab.astype(np.int32)))
    out = tmp_path / "hm"
    assert main(["heightmaps", str(src), "-o", str(out), "--pixel", "0.1"]) == 0
    planes = json.loads((out / "planes.json").read_text())["planes"]
    assert len(planes) >= 4
    for pl in planes:
        assert (out / pl["heightmap"]).is_file()
        assert (out / pl["heightmap"]).with_suffix(".json").is_file()
    assert (out / "overview.png").stat().st_size > 10_000
    assert (out / "room_lowpoly.ply").is_file() and (out / "config.yaml").is_file()
    # the same low-poly room as OBJ (+ MTL), z up, faces grouped by class
    from tripod_processor.io.mesh_obj import read_obj

    v_obj, t_obj, groups = read_obj(out / "room_lowpoly.obj")
    assert len(t_obj) > 0 and (out / "room_lowpoly.mtl").is_file()
    assert set(groups) <= {"ceiling", "floor", "wall", "other"} and "floor" in groups
    floor_z = v_obj[t_obj[[g == "floor" for g in groups]]][..., 2].mean()
    ceil_z = v_obj[t_obj[[g == "ceiling" for g in groups]]][..., 2].mean()
    assert floor_z < ceil_z
    assert "pixel: 0.1" in (out / "config.yaml").read_text()
    assert main(["heightmaps", str(src), "-o", str(out), "--config", str(tmp_path / "none.yaml")]) == 2
