# SPDX-License-Identifier: BSD-3-Clause
"""Registration by heightmap matching: poses against the truth on synthetic rooms and
simulator station scans (a furnished rectangular room, whose 180 deg twin must be rejected), an
empty symmetric room and non-overlapping pairs reported as failures, the pieces (2-D RANSAC,
free-space test, Hu moments), and ``tripod register --method heightmaps``."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tripod_processor.scene import heightmap_registration as hr
from tripod_processor.cli import main
from tripod_processor.io.clouds import make_cloud, write_ply
from tripod_processor.sim.scenes import make_scene
from tripod_processor.sim.station_scan import box_room, pose, station_scan


def _pose_error(T, T_true):
    E = np.linalg.inv(T_true) @ T
    return (float(np.degrees(np.arccos(np.clip((np.trace(E[:3, :3]) - 1) / 2, -1, 1)))),
            float(np.linalg.norm(E[:3, 3])))


def _station(scene, xy, yaw_deg, seed, z=1.4):
    """A static station scan (3 head tilts, 0.4 deg azimuth steps: ~43 k points) and its pose."""
    T = pose(yaw_deg=yaw_deg, xyz=(*xy, z))
    return station_scan(scene, T, tilts_deg=(-20, 0, 20), azimuth_step_deg=0.4, seed=seed), T


def _turn(points, yaw, t):
    c, s = np.cos(yaw), np.sin(yaw)
    T = np.eye(4)
    T[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    T[:3, 3] = t
    return (points @ T[:3, :3].T + T[:3, 3]).astype(np.float32), T


@pytest.mark.parametrize("seed", [41, 42])
def test_register_by_heightmaps(seed):
    from tripod_processor.scene.heightmap_registration import register_by_heightmaps
    from tripod_processor.sim.rooms import free_station, make_room, scan

    scene = make_room(seed)
    rng = np.random.default_rng(seed)
    a, b = free_station(scene, rng), free_station(scene, rng)
    pa, la = scan(scene, a, head_steps=10, noise_m=0.03, seed=1)
    pb, lb = scan(scene, b, head_steps=10, noise_m=0.03, seed=2)
    tgt, Ta = _turn(pa, 0.3, [1, 2, 0.1])
    src, Tb = _turn(pb, -2.0, [-3, 0.5, -0.2])
    r = register_by_heightmaps(src, tgt, source_labels=lb, target_labels=la,
                               viewpoint_source=(Tb @ [*b, 1])[:3],
                               viewpoint_target=(Ta @ [*a, 1])[:3])
    ang, dist = _pose_error(r.T_target_source, Ta @ np.linalg.inv(Tb))
    assert ang < 1.0 and dist < 0.05, (ang, dist)
    assert r.success and r.fitness > 0.5 and r.structure_fitness > 0.5
    assert r.free_space_violation < 0.02


def test_furnished_rectangular_room_rejects_its_twin():
    """A rectangular room matches its 180 deg twin in walls, floor and ceiling; the furniture
    and free space must pick the right one (labels from the shipped segmenter)."""
    room = make_scene("room", 7)
    w, d = room.params["width_m"], room.params["depth_m"]
    tgt, T_w_t = _station(room, (0.35 * w, 0.4 * d), 30.0, 1)
    src, T_w_s = _station(room, (0.7 * w, 0.6 * d), -110.0, 2, z=1.5)
    r = hr.register_by_heightmaps(src, tgt)
    ang, dist = _pose_error(r.T_target_source, np.linalg.inv(T_w_t) @ T_w_s)
    assert ang <= 1.0 and dist <= 0.05, (ang, dist)
    assert r.success and r.ambiguity < 0.9
    # the twin was among the hypotheses, and lost
    twins = [v for v in r.verified if _pose_error(v[2], np.linalg.inv(T_w_t) @ T_w_s)[0] > 170]
    assert twins and all(t[1] < r.verified[0][1] for t in twins)


def test_empty_symmetric_room_is_ambiguous_not_a_guess():
    """An empty box room looks the same under a half turn: no unique answer, so no success."""
    scene = box_room()
    tgt, _ = _station(scene, (2.0, 1.8), 30.0, 1)
    src, _ = _station(scene, (4.5, 2.6), -110.0, 2)
    r = hr.register_by_heightmaps(src, tgt)
    assert not r.success and r.ambiguity > 0.97


@pytest.mark.parametrize("other", [("corridor", 3), ("room", 8)])
def test_non_overlapping_pair_fails(other):
    room = make_scene("room", 7)
    w, d = room.params["width_m"], room.params["depth_m"]
    tgt, _ = _station(room, (0.35 * w, 0.4 * d), 30.0, 1)
    scene = make_scene(*other)
    src, _ = _station(scene, tuple(0.5 * scene.route[0] + 0.5 * scene.route[1]), -110.0, 2)
    r = hr.register_by_heightmaps(src, tgt)
    assert not r.success and r.structure_fitness < 0.4


def test_rigid_2d_ransac_with_outliers():
    rng = np.random.default_rng(0)
    a = rng.uniform(-5, 5, (60, 2))
    yaw, t = 2.1, np.array([1.5, -3.0])
    R = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
    b = a @ R.T + t + rng.normal(0, 0.01, a.shape)
    b[:30] = rng.uniform(-8, 8, (30, 2))  # half the matches wrong
    sets = hr.rigid_2d_ransac(a, b, inlier_m=0.05, seed=1)
    members, y, tt = sets[0]
    assert set(members.tolist()) >= set(range(30, 60)) and len(members) < 34
    assert abs((y - yaw + np.pi) % (2 * np.pi) - np.pi) < np.radians(0.2)
    np.testing.assert_allclose(tt, t, atol=0.02)


def test_range_image_free_space():
    """A wall 4 m in front of the sensor: a point 2 m out was seen through, one on or behind the
    wall was not; a direction without returns is no evidence."""
    yy, zz = np.meshgrid(np.linspace(-3, 3, 300), np.linspace(-1, 1, 100))
    wall = np.stack([np.full(yy.size, 4.0), yy.ravel(), zz.ravel()], 1)
    from tripod_processor.scene.heightmap_registration.verification import _RangeImage as RangeImage

    ri = RangeImage(wall, (0.0, 0.0, 0.0))
    probe = np.array([[2.0, 0.0, 0.0], [4.0, 0.5, 0.0], [6.0, 0.0, 0.0], [-2.0, 0.0, 0.0]])
    assert ri.seen_through(probe).tolist() == [True, False, False, False]


def test_keypoints_and_shapes_on_a_plan_image():
    """ORB finds corners on a plan heightmap; the shape blobs of the furniture carry Hu moments
    that do not change when the room turns."""
    from tripod_processor.sim.rooms import free_station, make_room, scan

    scene = make_room(42)
    st = free_station(scene, np.random.default_rng(42))
    p, lab = scan(scene, st, head_steps=10, noise_m=0.03, seed=1)
    turned, _ = _turn(p, 1.0, [0, 0, 0])
    a = hr.level_scan(p, lab)
    b = hr.level_scan(turned, lab)
    img, lo = hr.plan_image(a, 0.05)
    assert img.dtype == np.uint8 and img.max() > 200
    ij, desc = hr.orb_keypoints(img)
    assert len(ij) > 50 and desc.shape == (len(ij), 32)
    ca, da = hr.shape_blobs(a)
    cb, db = hr.shape_blobs(b)
    assert len(ca) >= 2 and len(ca) == len(cb)
    m = hr.match_nearest(da, db, k=1, max_distance=0.5)
    assert len(m) >= len(ca) - 1


def test_hu_moments_are_rotation_invariant():
    from scipy import ndimage

    from tripod_processor.scene.heightmap_registration import hu_moments

    m = np.zeros((200, 200), bool)
    m[50:150, 80:120] = True
    m[50:70, 80:160] = True  # an L
    r = ndimage.rotate(m.astype(float), 37, order=0, reshape=True) > 0.5
    h1, h2 = hu_moments(m), hu_moments(r)
    np.testing.assert_allclose(h1[:4], h2[:4], rtol=0.05)


def test_cli_register_heightmaps_method(tmp_path, capsys):
    from tripod_processor.sim.rooms import free_station, make_room, scan

    scene = make_room(43)
    rng = np.random.default_rng(43)
    a, b = free_station(scene, rng), free_station(scene, rng)
    pa, _ = scan(scene, a, head_steps=10, noise_m=0.03, seed=1)
    pb, _ = scan(scene, b, head_steps=10, noise_m=0.03, seed=2)
    src, Tb = _turn(pb, 2.5, [2, -1, 0])
    write_ply(tmp_path / "t.ply", make_cloud(pa))
    write_ply(tmp_path / "s.ply", make_cloud(src))
    capsys.readouterr()
    assert main(["register", str(tmp_path / "s.ply"), str(tmp_path / "t.ply"),
                 "--method", "heightmaps", "-o", str(tmp_path / "r.json")]) == 0
    out = json.loads(capsys.readouterr().out)
    E = Tb @ np.array(out["T_target_source"])  # truth: T_target_source = Tb^-1
    ang = np.degrees(np.arccos(np.clip((np.trace(E[:3, :3]) - 1) / 2, -1, 1)))
    assert ang < 1.0 and np.linalg.norm(E[:3, 3]) < 0.05, (ang, E[:3, 3])
    assert out["method"] == "heightmaps" and (tmp_path / "r.json").is_file()
    assert out["success"] is True and out["structure_fitness"] > 0.5
    assert {"free_space_violation", "ambiguity", "twin_ambiguity", "proposer"} <= out.keys()


def _tipped(axis_deg: float, tilt_deg: float) -> np.ndarray:
    """(3, 3) a turn by ``tilt_deg`` about the horizontal axis at ``axis_deg`` of azimuth."""
    from scipy.spatial.transform import Rotation

    a = np.radians(axis_deg)
    return Rotation.from_rotvec(np.radians(tilt_deg) * np.array([np.cos(a), np.sin(a), 0.0])
                                ).as_matrix()


def test_walls_correct_an_imu_up_that_is_off():
    """A lidar with its spin axis vertical sees a band of walls and little floor; the up its
    fragments carry (the IMU's gravity) is off by 0.8 deg, in another direction at each station.
    Levelled by that up alone the pair is ~1.3 deg and several cm off; the walls (made vertical
    by ``structure_up``) fix the level and the pair registers within 1 deg / 5 cm."""
    from tripod_processor.scene.heightmap_registration import register_by_heightmaps
    from tripod_processor.sim.rooms import free_station, make_room, scan

    scene = make_room(43)
    rng = np.random.default_rng(43)
    a, b = free_station(scene, rng), free_station(scene, rng)
    clouds = []
    for st, seed, axis in ((a, 1, 20.0), (b, 2, 170.0)):
        p, lab = scan(scene, st, head_steps=10, noise_m=0.03, seed=seed)
        d = p - st
        band = np.abs(d[:, 2]) < np.tan(np.radians(15.0)) * np.linalg.norm(d[:, :2], axis=1)
        R = _tipped(axis, 0.8)  # the cloud's true up is R @ e_z; the IMU says e_z
        clouds.append(((p[band] - st) @ R.T, lab[band], R))
    (pt, lt, Rt), (ps, lsb, Rs) = clouds
    T_true = np.eye(4)
    T_true[:3, :3] = Rt @ Rs.T
    T_true[:3, 3] = Rt @ (b - a)
    # the up from the "IMU", off by 0.8 deg in each cloud
    up = np.array([0.0, 0.0, 1.0])
    r = register_by_heightmaps(ps.astype(np.float32), pt.astype(np.float32), source_labels=lsb,
                               target_labels=lt, source_up=up, target_up=up)
    ang, dist = _pose_error(r.T_target_source, T_true)
    assert ang < 1.0 and dist < 0.05, (ang, dist)
    assert r.success
    # the structure's up of each cloud is within 0.2 deg of its true up
    for P, lab, R in clouds:
        lv = hr.level_scan(P, lab, gravity=True)
        up_est = lv.T_level_scan[2, :3]
        assert np.degrees(np.arccos(np.clip(up_est @ (R @ [0, 0, 1.0]), -1, 1))) < 0.2


def test_structure_up_is_fused_with_the_prior_by_uncertainty():
    """``structure_up`` in a frame whose +z is the IMU's up: walls that agree correct a prior
    that is 0.8 deg off; walls that scatter by ~1 deg barely move a prior that is right; a
    mislabelled plane 7 deg off (a sloped surface called wall) and a structure that alone says
    2 deg are not trusted."""
    from types import SimpleNamespace

    from tripod_processor.scene.heightmap_registration.levelling import structure_up
    from tripod_processor.scene.planes import FLOOR, WALL

    def wall(azimuth_deg, up, n_points=10_000):
        a = np.radians(azimuth_deg)
        h = np.array([np.cos(a), np.sin(a), 0.0])
        n = h - (h @ up) * up  # vertical for ``up``: n . up = 0
        return SimpleNamespace(label=WALL, normal=n / np.linalg.norm(n),
                               indices=np.arange(n_points))

    def angle(u, v):
        return float(np.degrees(np.arccos(np.clip(u @ v / np.linalg.norm(v), -1, 1))))

    true_up = _tipped(30.0, 0.8) @ [0.0, 0.0, 1.0]  # the IMU (+z) is 0.8 deg off
    walls = [wall(az, true_up) for az in (0, 90, 180, 270, 45, 135)]
    assert angle(structure_up(walls), true_up) < 0.1
    # the prior is right; the walls scatter by ~1 deg (noisy, mislabelled): little moves
    z = np.array([0.0, 0.0, 1.0])
    rng = np.random.default_rng(3)
    noisy = [wall(az, _tipped(rng.uniform(0, 360), rng.uniform(0.3, 0.9)) @ z)
             for az in (0, 90, 180, 270, 45, 135)]
    assert angle(structure_up(noisy), z) < 0.3
    # one sloped "wall" 7 deg off among good ones is dropped
    sloped = wall(10.0, _tipped(100.0, 7.0) @ z, 20_000)
    assert angle(structure_up([*walls, sloped]), true_up) < 0.1
    # a structure that says 2 deg (the prior is right to ~1 deg): the walls that say > 1 deg
    # are dropped, the two left (0.7 deg each, no scatter to judge them by) barely move it
    off = _tipped(200.0, 2.0) @ z
    assert angle(structure_up([wall(az, off) for az in (0, 90, 180, 270)]), z) < 0.1
    # a floor tilted with the true up agrees with the walls
    floor = SimpleNamespace(label=FLOOR, normal=true_up, indices=np.arange(20_000))
    assert angle(structure_up([*walls, floor]), true_up) < 0.1


def test_structure_up_trusts_no_structure_whose_walls_and_floors_disagree():
    """A vertical lidar sees the floor only far from the station (a ring at 6-13 m), and such
    a floor's plane can lean by ~1 deg (dev fragment: 0.9 deg at an IMU up 0.01 deg off; the
    level then 0.6 deg off put the floor height 6 cm off at 12 m). When the walls and the
    floors / ceilings, each solved alone, disagree by D, the structure is uncertain by at least
    D / 2 and a right prior barely moves, whichever part is off; parts that agree still
    correct a prior that is 0.8 deg off."""
    from types import SimpleNamespace

    from tripod_processor.scene.heightmap_registration.levelling import structure_up
    from tripod_processor.scene.planes import CEILING, FLOOR, WALL

    def wall(azimuth_deg, up):
        a = np.radians(azimuth_deg)
        h = np.array([np.cos(a), np.sin(a), 0.0])
        n = h - (h @ up) * up
        return SimpleNamespace(label=WALL, normal=n / np.linalg.norm(n),
                               indices=np.arange(10_000))

    def level(label, up):
        return SimpleNamespace(label=label, normal=up if label == FLOOR else -up,
                               indices=np.arange(20_000))

    def angle(u, v):
        return float(np.degrees(np.arccos(np.clip(u @ v / np.linalg.norm(v), -1, 1))))

    z = np.array([0.0, 0.0, 1.0])  # the prior (IMU up) is right
    off = _tipped(60.0, 0.9) @ z
    azimuths = range(0, 360, 30)
    floors_off = [*(wall(az, z) for az in azimuths),
                  level(FLOOR, off), level(FLOOR, off), level(CEILING, off)]
    walls_off = [*(wall(az, off) for az in azimuths),
                 level(FLOOR, z), level(FLOOR, z), level(CEILING, z)]
    for planes in (floors_off, walls_off):
        assert angle(structure_up(planes, parts=False), z) > 0.3  # the joint fit's pull
        assert angle(structure_up(planes), z) < 0.15
    true_up = _tipped(30.0, 0.8) @ z  # the prior 0.8 deg off, walls and floors agree
    agree = [*(wall(az, true_up) for az in azimuths), level(FLOOR, true_up),
             level(CEILING, true_up)]
    assert angle(structure_up(agree), true_up) < 0.1


def test_level_height_from_shared_floors_then_ceilings():
    """The height between two gravity-levelled scans: fixed by their floors when both are
    trusted, else by their ceilings (a vertical lidar may see the ceiling of a low room but not
    its floor), else left free (None: the level ICP's)."""
    from tripod_processor.scene.heightmap_registration.levelling import LevelledScan
    from tripod_processor.scene.heightmap_registration.pipeline import _level_height

    def scan(height, floor, ceiling):
        e = np.zeros((0, 2))
        return LevelledScan(np.eye(4), e, np.zeros(0), e, height, np.zeros(0, int), floor,
                            ceiling)

    assert _level_height(scan(2.8, True, False), scan(2.6, True, True)) == 0.0
    # no floor in the source: its level frame stands 0.3 m off; the ceilings tell by how much
    assert _level_height(scan(2.5, False, True), scan(2.8, True, True)) == pytest.approx(0.3)
    assert _level_height(scan(2.5, False, False), scan(2.8, True, True)) is None


def test_only_a_sizeable_ceiling_shares_its_height():
    """A gravity-levelled scan with no floor: its ceiling plane shares its height with another
    scan only when it covers at least MIN_TRUSTED_CEILING_M2 (a strip of a soffit seen by a
    vertical lidar's band passes for a ceiling otherwise)."""
    from tripod_processor.scene.heightmap_registration.levelling import (
        MIN_TRUSTED_CEILING_M2, level_scan)

    rng = np.random.default_rng(7)

    def scan(ceiling_side_m):
        # four walls of a 4 x 4 m room between z = 0.3 and 2.4 (no floor), and a square ceiling
        # patch at z = 2.5 of the given side (dense, 2 mm noise)
        n = 40_000
        t, z = rng.uniform(-2, 2, n), rng.uniform(0.3, 2.4, n)
        side = rng.integers(0, 4, n)
        x = np.where(side == 0, -2.0, np.where(side == 1, 2.0, t))
        y = np.where(side == 2, -2.0, np.where(side == 3, 2.0, t))
        walls = np.c_[x, y, z]
        m = 20_000
        c = np.c_[rng.uniform(-ceiling_side_m / 2, ceiling_side_m / 2, (m, 2)), np.full(m, 2.5)]
        P = np.r_[walls, c] + rng.normal(0, 0.002, (n + m, 3))
        lab = np.r_[np.full(n, 2), np.zeros(m, int)]
        return level_scan(P, lab, gravity=True)

    assert MIN_TRUSTED_CEILING_M2 > 1.0
    small, large = scan(1.0), scan(2.0)  # 1 and 4 m^2
    assert not small.floor_trusted and not large.floor_trusted
    assert large.ceiling_trusted and not small.ceiling_trusted


def test_a_sloped_surface_is_no_trusted_floor():
    """A gravity-levelled scan that saw no floor (a vertical lidar's band in a small room) but a
    sloped surface labelled floor, with nothing below it: that slope is neither the floor nor
    trusted as one (it was, and a pair came back 19 cm off with success = true); a level patch
    in its place is."""
    from tripod_processor.scene.heightmap_registration.levelling import (
        MAX_LEVEL_PLANE_TILT_DEG, level_scan)

    rng = np.random.default_rng(11)

    def scan(lean_deg):
        # four walls of a 4 x 4 m room between z = 0.3 and 2.4 and a 1.5 x 1.5 m patch labelled
        # floor at z = 0.3 leaning ``lean_deg`` about x (2 mm noise)
        n, m = 40_000, 20_000
        t, z = rng.uniform(-2, 2, n), rng.uniform(0.3, 2.4, n)
        side = rng.integers(0, 4, n)
        x = np.where(side == 0, -2.0, np.where(side == 1, 2.0, t))
        y = np.where(side == 2, -2.0, np.where(side == 3, 2.0, t))
        u, v = rng.uniform(-0.75, 0.75, (2, m))
        a = np.radians(lean_deg)
        patch = np.c_[u, v * np.cos(a), 0.3 + v * np.sin(a)]
        P = np.r_[np.c_[x, y, z], patch] + rng.normal(0, 0.002, (n + m, 3))
        lab = np.r_[np.full(n, 2), np.ones(m, int)]
        return level_scan(P, lab, gravity=True)

    assert 1.5 < MAX_LEVEL_PLANE_TILT_DEG < 8.0
    level, sloped = scan(0.0), scan(8.0)
    assert level.floor_trusted
    assert abs(level.T_level_scan[2, 3] + 0.3) < 0.01  # the patch is the floor
    assert not sloped.floor_trusted


def _no_floor_pair(seed: int, head_steps: int, band: bool):
    """Two stations of a furnished box room (``sim.rooms``) with every floor and ceiling point
    removed (no shared floor or ceiling fixes the height); ``band``: only what a vertical lidar's
    +/- 15 deg sees as well (a band of walls). Returns (source, source labels, target, target
    labels, T_true)."""
    from tripod_processor.sim.rooms import free_station, make_room, scan

    scene = make_room(seed, kind="box")
    rng = np.random.default_rng(seed)
    a, b = free_station(scene, rng), free_station(scene, rng)
    clouds = []
    for st, s in ((a, 1), (b, 2)):
        p, lab = scan(scene, st, head_steps=head_steps, noise_m=0.03, seed=s)
        d = p - st
        keep = lab >= 2  # walls and other only
        if band:
            keep &= np.abs(d[:, 2]) < np.tan(np.radians(15.0)) * np.linalg.norm(d[:, :2], axis=1)
        clouds.append(((p[keep] - st).astype(np.float32), lab[keep]))
    T_true = np.eye(4)
    T_true[:3, 3] = b - a
    return clouds[1][0], clouds[1][1], clouds[0][0], clouds[0][1], T_true


def test_height_without_shared_floor_or_ceiling():
    """Neither floor nor ceiling is shared. A band of walls (a vertical lidar's) does not fix the
    height: here the level ICP leaves the pose 6 cm off in height, which used to come back as
    ``success = true``; now ``height_observed`` is false and so is ``success``. Where both scans
    see horizontal surfaces (table and cabinet tops) the height comes from them: within 1 deg /
    5 cm, trusted."""
    up = [0.0, 0.0, 1.0]
    ps, ls_, pt, lt_, T_true = _no_floor_pair(42, 10, band=True)
    r = hr.register_by_heightmaps(ps, pt, source_labels=ls_, target_labels=lt_, source_up=up,
                                  target_up=up)
    ang, dist = _pose_error(r.T_target_source, T_true)
    assert ang < 1.0  # right in yaw and plan; the height is the guess
    assert not r.success or dist < 0.05, (ang, dist)  # before: 6.1 cm off, success = true
    assert not r.height_observed and not r.success
    # the whole scan less floor and ceiling: the furniture's tops give the height
    ps, ls_, pt, lt_, T_true = _no_floor_pair(43, 30, band=False)
    r = hr.register_by_heightmaps(ps, pt, source_labels=ls_, target_labels=lt_, source_up=up,
                                  target_up=up)
    ang, dist = _pose_error(r.T_target_source, T_true)
    assert ang < 1.0 and dist < 0.05, (ang, dist)
    assert r.height_observed and r.success


def test_height_evidence_finds_a_slide_and_rejects_a_flat_histogram():
    """``height_evidence`` on the furniture's tops of two scans put 20 cm apart in height gives
    the correction to a centimetre; on a band of walls it says not observable."""
    from tripod_processor.scene.heightmap_registration.height import height_evidence

    ps, _, pt, _, T_true = _no_floor_pair(43, 30, band=False)
    placed = ps @ T_true[:3, :3].T + T_true[:3, 3]
    e = height_evidence(placed + [0.0, 0.0, 0.2], pt)
    assert e.observable and abs(e.dz + 0.2) < 0.01, e
    ps, _, pt, _, T_true = _no_floor_pair(42, 10, band=True)
    e = height_evidence(ps @ T_true[:3, :3].T + T_true[:3, 3], pt)
    assert not e.observable, e


def test_a_table_top_taken_for_the_floor_is_no_observed_height():
    """Two gravity-levelled scans of a furnished room: the target sees its floor, the source (a
    vertical lidar's band sees little near the floor) nothing below a level patch 18 cm up that
    is labelled floor, so both "floors" are trusted and fix the height 18 cm off. The horizontal
    patches both scans saw above the floors (desk and cabinet tops) contradict it: the height is
    reported unobservable and ``success`` is false (it was ``success = true``, 18 cm off, as a
    vertical rig's pair of reconstruct's fragments came back 23 cm off on a fresh split); with
    the true floor in the source the pair stays right and trusted."""
    from tripod_processor.sim.rooms import free_station, make_room

    seed = 43
    ps, ls_, pt, lt_, T_true = _no_floor_pair(seed, 30, band=False)
    rng = np.random.default_rng(seed)  # the stations of _no_floor_pair: floor at -z in each frame
    st_t, st_s = free_station(make_room(seed, kind="box"), rng), free_station(
        make_room(seed, kind="box"), rng)
    rng = np.random.default_rng(5)

    def floor_patch(z, side, n):  # a level patch labelled floor, 3 mm noise
        u = rng.uniform(-side / 2, side / 2, (n, 2))
        return np.c_[u, z + rng.normal(0, 0.003, n)].astype(np.float32), np.ones(n, int)

    fp, fl = floor_patch(-st_t[2], 3.0, 8000)
    pt, lt_ = np.r_[pt, fp], np.r_[lt_, fl]
    up = [0.0, 0.0, 1.0]
    for lift, wrong in ((0.0, False), (0.18, True)):
        keep = ps[:, 2] > -st_s[2] + lift - 0.08  # nothing seen below the patch
        fp, fl = floor_patch(-st_s[2] + lift, 2.0, 6000)
        r = hr.register_by_heightmaps(np.r_[ps[keep], fp], pt, source_labels=np.r_[ls_[keep], fl],
                                      target_labels=lt_, source_up=up, target_up=up)
        ang, dist = _pose_error(r.T_target_source, T_true)
        assert ang < 1.0, ang
        if wrong:  # the shared "floors" put it off by the patch's height: not trusted
            assert dist > 0.1, dist
            assert not r.height_observed and not r.success
        else:
            assert dist < 0.05 and r.height_observed and r.success, (dist, r.success)
