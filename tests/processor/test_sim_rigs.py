# SPDX-License-Identifier: BSD-3-Clause
"""Rig variety of the digital twin (issue 12): pan profiles, scene sizes, the rig sampler and
the truth written to meta.json."""

from __future__ import annotations

import json

import numpy as np
import pytest
from pydantic import ValidationError
from sim_fixtures import make_rig_capture

from tripod_processor.sim import MotionConfig, SimConfig, make_scene
from tripod_processor.sim.capture import build_rig
from tripod_processor.sim.motion import Route, Trajectory, plan_pan
from tripod_processor.sim.rigs import (DEV_SEEDS, MAX_RECORDING_S, TEST_SEEDS, draw_rig,
                                       small_rig)
from tripod_processor.sim.scenes import check_route

HAND = dict(pan_profile="hand", pan_s=14.0, pan_turns=1.1, pan_pause_s=1.5,
            pan_reversal_deg=25.0, pan_reversal_s=1.0, pan_ramp_s=0.6,
            pan_speed_variation=0.5, pan_speed_change_s=1.5)


def _speed(plan):
    return np.gradient(plan.angle, plan.dt_s)


def test_hand_turned_pan_is_uneven_pauses_reverses_and_turns_as_asked():
    cfg = MotionConfig(**HAND)
    plan = plan_pan(cfg, 2 * np.pi * 1.1, np.random.default_rng(4))
    tau = np.arange(len(plan.angle)) * plan.dt_s
    w = _speed(plan)
    # the total turn requested
    assert plan.angle[-1] == pytest.approx(2 * np.pi * 1.1, abs=1e-9)
    assert plan.angle[0] == 0.0
    # one pause: the head stands for its whole length
    (pa, pb), = plan.pauses_s
    assert pb - pa == pytest.approx(1.5)
    inside = (tau > pa + 1e-3) & (tau < pb - 1e-3)
    assert np.abs(w[inside]).max() < 1e-6
    # one reversal: it turns back by 25 deg, then on
    (ra, rb), = plan.reversals_s
    i0, i1 = np.searchsorted(tau, [ra, rb])
    assert plan.angle[i0] - plan.angle[i1] == pytest.approx(np.radians(25.0), abs=1e-6)
    assert (w[i0:i1] < 0).mean() > 0.95 and (w[:i0 - 1] >= -1e-9).all()
    assert plan.angle[-1] > plan.angle[i0]  # ... and on past where it turned back
    # uneven: away from the ramps and gaps, the forward speed changes by far more than a motor's
    busy = np.ones_like(tau, dtype=bool)
    for a, b in plan.pauses_s + plan.reversals_s:
        busy &= (tau < a - 0.6) | (tau > b + 0.6)
    busy &= (tau > 0.6) & (tau < cfg.pan_s - 0.6)
    cruise = w[busy]
    assert cruise.min() > 0 and cruise.max() / cruise.min() > 1.4
    # smooth: speed continuous (no jump larger than a hand's acceleration allows in a step)
    assert np.abs(np.diff(w)).max() / plan.dt_s < np.radians(2000)


def test_motor_pan_is_constant_between_ramps_and_keeps_its_turn():
    cfg = MotionConfig(pan_s=10.0, pan_turns=0.95, pan_pause_s=1.0)
    plan = plan_pan(cfg, 2 * np.pi * 0.95, np.random.default_rng(0))
    tau = np.arange(len(plan.angle)) * plan.dt_s
    w = _speed(plan)
    (pa, pb), = plan.pauses_s
    cruise = w[(tau > 1.0) & (tau < 9.0) & ((tau < pa - 0.6) | (tau > pb + 0.6))]
    assert np.ptp(cruise) < 1e-6 * cruise.mean()
    assert plan.angle[-1] == pytest.approx(2 * np.pi * 0.95)


def test_default_pan_is_the_original_motor_pan():
    cfg = MotionConfig()
    assert cfg.is_motor_default
    scene = make_scene("room", 2)
    traj = Trajectory(scene.route, True, 3, cfg, np.random.default_rng(1))
    assert traj.pans is None  # the original _ramp_angle path, so old captures stay bit for bit


def test_pan_too_short_for_pause_and_reversal_is_one_clear_error():
    with pytest.raises(ValidationError, match="too short for the pause and reversal"):
        MotionConfig(pan_s=3.0, pan_pause_s=1.5, pan_reversal_deg=20.0, pan_reversal_s=1.0)


def test_trajectory_follows_the_per_station_pans():
    cfg = MotionConfig(**HAND, pan_turns_jitter=0.05)
    scene = make_scene("room", 1)
    traj = Trajectory(scene.route, True, 4, cfg, np.random.default_rng(2),
                      pan_rng=np.random.default_rng(3))
    nets = [traj.pan_net_rad(k) for k in range(4)]
    assert len(set(np.round(nets, 9))) == 4  # each station turns its own amount
    assert all(2 * np.pi * 1.05 - 1e-9 <= x <= 2 * np.pi * 1.15 + 1e-9 for x in nets)
    for st in traj.stations:
        phi = traj.base_state(np.array([st.t_pan_start_s - 0.1, st.t_pan_start_s,
                                        st.t_pan_end_s, st.t_pan_end_s + 0.1]))[4]
        assert phi[2] - phi[1] == pytest.approx(nets[st.index], abs=1e-9)
        assert phi[0] == phi[1] and phi[2] == phi[3]  # it rests in the settle time


def test_scene_sizes_big_hall_long_corridor_small_room():
    hall = make_scene("hall", 3, {"width_m": 40.0, "depth_m": 25.0, "height_m": 8.0})
    lo, hi = hall.bounds
    assert hi[0] - lo[0] == pytest.approx(40.0) and hi[1] - lo[1] == pytest.approx(25.0)
    corr = make_scene("corridor", 3, {"length_m": 30.0, "leg2_m": 0.0, "width_m": 2.0})
    lo, hi = corr.bounds
    assert hi[0] - lo[0] == pytest.approx(30.0) and hi[1] - lo[1] == pytest.approx(2.0)
    assert Route(corr.route, False).length == pytest.approx(28.0, abs=0.01)
    room = make_scene("room", 3, {"width_m": 3.5, "depth_m": 3.3})
    for sc in (hall, corr, room):
        check_route(sc, sc.route, sc.closed_route)
    with pytest.raises(ValueError, match="has no size length_m"):
        make_scene("hall", 3, {"length_m": 10.0})
    with pytest.raises(ValueError, match="too small"):
        make_scene("room", 3, {"width_m": 2.0})
    # a config without sizes keeps the seed's draw
    assert make_scene("hall", 3).params == make_scene("hall", 3, {"width_m": None}).params


def test_rig_sampler_is_deterministic_and_in_range():
    assert set(DEV_SEEDS).isdisjoint(TEST_SEEDS)
    assert draw_rig(17).model_dump() == draw_rig(17).model_dump()
    assert draw_rig(17).model_dump() != draw_rig(18).model_dump()
    cfgs = [draw_rig(s) for s in range(40)]  # development seeds
    seen = {"profile": set(), "mode": set(), "scene": set(), "pause": 0, "rev": 0}
    for c in cfgs:
        m = c.motion
        assert 0.0 <= m.tilt_deg <= 90.0
        assert np.linalg.norm(m.lever_arm_m) <= 0.2
        assert 0.0 <= c.imu.latency_ms <= 10.0 and 0.0 <= c.imu.latency_jitter_ms <= 1.0
        assert 4.0 <= m.pan_s <= 60.0 and 0.9 <= m.pan_turns <= 1.2
        assert 2.0 <= m.transit_s <= 30.0
        scene, traj = build_rig(c)
        assert traj.duration_s <= MAX_RECORDING_S or c.stations == 2
        assert np.all(traj.transit_s <= 30.0 + 1e-6)  # carries 2-30 s, long walks included
        lo, hi = scene.bounds
        assert max(hi[:2] - lo[:2]) <= 40.0 + 1e-9
        for k in range(c.stations):
            assert 2 * np.pi * 0.87 <= traj.pan_net_rad(k) <= 2 * np.pi * 1.23
        seen["profile"].add(m.pan_profile)
        seen["mode"].add(c.lidar.return_mode == "dual")
        seen["scene"].add(c.scene)
        seen["pause"] += m.pan_pause_s > 0
        seen["rev"] += m.pan_reversal_deg > 0
    assert seen["profile"] == {"constant", "hand"} and seen["mode"] == {True, False}
    assert seen["scene"] == {"room", "hall", "corridor"}
    assert seen["pause"] > 0 and seen["rev"] > 0


@pytest.fixture(scope="module")
def rig_capture(tmp_path_factory):
    return make_rig_capture(tmp_path_factory.mktemp("rig"))


def test_truth_in_meta_matches_the_trajectory(rig_capture):
    from tripod_processor.reconstruction.placement import load_extrinsic_file

    meta = json.loads((rig_capture / "meta.json").read_text())
    truth = meta["truth"]
    cfg = SimConfig.model_validate(meta["config"])
    assert cfg.model_dump() == small_rig().model_dump()
    _, traj = build_rig(cfg)
    start, off = cfg.start_unix_ns, cfg.lidar.clock_offset_ns
    assert len(truth["stations"]) == 3
    for k, st in enumerate(truth["stations"]):
        a, b = st["still"]["host_ns"]
        assert st["still"]["lidar_ns"] == [a + off, b + off]
        t = (np.linspace(a, b, 40) - start) * 1e-9
        _, p = traj.T_world_base(t)
        assert np.ptp(p, axis=0).max() < 1e-9  # the tripod stands over the whole interval
        if k + 1 < len(truth["stations"]):  # ... and is carried right after it
            _, p2 = traj.T_world_base(np.array([(b - start) * 1e-9, (b - start) * 1e-9 + 1.0]))
            assert np.linalg.norm(p2[1] - p2[0]) > 1e-3
        pa, pb = st["pan"]["host_ns"]
        phi = traj.base_state((np.array([pa, pb]) - start) * 1e-9)[4]
        assert np.degrees(phi[1] - phi[0]) == pytest.approx(st["net_turn_deg"], abs=1e-6)
        (qa, qb), = [p["host_ns"] for p in st["pauses"]]
        phi = traj.base_state((np.linspace(qa, qb, 20)[1:-1] - start) * 1e-9)[4]
        assert np.ptp(phi) < 1e-6
        (ra, rb), = [p["host_ns"] for p in st["reversals"]]
        phi = traj.base_state((np.array([ra, rb]) - start) * 1e-9)[4]
        assert np.degrees(phi[0] - phi[1]) == pytest.approx(20.0, abs=1e-4)
    q, ell = load_extrinsic_file(rig_capture / "gt" / "calibration.json")
    assert np.allclose(truth["lever_arm_imu_m"], ell, atol=1e-8)
    assert np.allclose(np.abs(np.dot(truth["q_imu_lidar_wxyz"], q)), 1.0, atol=1e-9)
    along, across = truth["lever_arm_along_axis_m"], truth["lever_arm_across_axis_m"]
    assert np.hypot(along, across) == pytest.approx(np.linalg.norm([0.08, 0.06, 0.03]))
    assert truth["imu_time_offset_ms"] == -4.0 and truth["imu_latency_ms"] == 4.0
    assert truth["tilt_deg"] == 60.0 and truth["pan_profile"] == "hand"
