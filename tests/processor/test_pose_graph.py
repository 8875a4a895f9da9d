# SPDX-License-Identifier: BSD-3-Clause
"""Pose-graph optimisation against graphs with known truth."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tripod_processor.registration import pose_graph as pg

from poses import T_from as _T, inv as _inv


def _perturb(T, rng, sigma_t, sigma_r):
    return T @ _T(rng.normal(0, sigma_r, 3), rng.normal(0, sigma_t, 3))


def _errors(A, B):
    """(translation [m], rotation [deg]) RMSE between two (N,4,4) pose sets in the same gauge."""
    dt = [np.linalg.norm(a[:3, 3] - b[:3, 3]) for a, b in zip(A, B)]
    dr = [np.degrees(Rotation.from_matrix(a[:3, :3].T @ b[:3, :3]).magnitude()) for a, b in zip(A, B)]
    return float(np.sqrt(np.mean(np.square(dt)))), float(np.sqrt(np.mean(np.square(dr))))


def _square_loop(n=16, side=4.0):
    """n tripod stations around a square room, yaw changing, z up; node 0 at the origin."""
    truth = []
    for k in range(n):
        s = 4 * side * k / n
        edge, u = divmod(s, side)
        corners = [(0, 0), (side, 0), (side, side), (0, side)]
        d = [(1, 0), (0, 1), (-1, 0), (0, -1)][int(edge)]
        x = corners[int(edge)][0] + d[0] * u
        y = corners[int(edge)][1] + d[1] * u
        truth.append(_T([0.0, 0.0, 0.7 * k], [x, y, 0.02 * np.sin(k)]))
    return np.array(truth)


def _info(sigma_t, sigma_r):
    return np.diag([1 / sigma_t**2] * 3 + [1 / sigma_r**2] * 3)


def _graph(truth, rng, sigma_t=0.01, sigma_r=0.002, loops=((0, 8), (4, 12), (0, 15), (2, 14))):
    edges = []
    for k in range(len(truth) - 1):
        meas = _perturb(_inv(truth[k]) @ truth[k + 1], rng, sigma_t, sigma_r)
        edges.append(pg.Edge(k, k + 1, meas, _info(sigma_t, sigma_r)))
    for i, j in loops:
        meas = _perturb(_inv(truth[i]) @ truth[j], rng, sigma_t, sigma_r)
        edges.append(pg.Edge(i, j, meas, _info(sigma_t, sigma_r), kind="loop"))
    chained = [truth[0]]
    for e in edges[: len(truth) - 1]:
        chained.append(chained[-1] @ e.T_i_j)
    return np.array(chained), edges


def test_loop_closure_reduces_drift_to_noise_level():
    rng = np.random.default_rng(1)
    truth = _square_loop()
    chained, edges = _graph(truth, rng)
    res = pg.optimize(chained, edges)
    assert res.converged
    assert res.rejected == 0
    t_before, r_before = _errors(chained, truth)
    t_after, r_after = _errors(res.T_world_node, truth)
    assert t_after < 0.5 * t_before
    assert t_after < 0.03 and r_after < 0.3
    # gauge: node 0 is held exactly
    np.testing.assert_allclose(res.T_world_node[0], truth[0], atol=1e-12)
    # noise-level residuals: chi2 per edge is O(6)
    assert np.median(res.edge_chi2) < 20


def test_exact_measurements_recover_truth_from_a_bad_start():
    truth = _square_loop()
    edges = [pg.Edge(k, k + 1, _inv(truth[k]) @ truth[k + 1], _info(0.01, 0.002))
             for k in range(len(truth) - 1)]
    edges.append(pg.Edge(0, 8, _inv(truth[0]) @ truth[8], _info(0.01, 0.002), kind="loop"))
    rng = np.random.default_rng(2)
    start = np.array([truth[0]] + [_perturb(T, rng, 0.2, 0.05) for T in truth[1:]])
    res = pg.optimize(start, edges, loss="none")
    t_err, r_err = _errors(res.T_world_node, truth)
    assert t_err < 1e-6 and r_err < 1e-5
    assert res.final_cost < 1e-10 < res.initial_cost


def test_outlier_loop_edge_is_rejected():
    rng = np.random.default_rng(3)
    truth = _square_loop()
    chained, edges = _graph(truth, rng)
    # a wrong loop closure: a symmetric room matched 180 degrees off
    bad = _inv(truth[3]) @ truth[11] @ _T([0, 0, np.pi], [0.5, 0, 0])
    edges.append(pg.Edge(3, 11, bad, _info(0.01, 0.002), kind="loop"))
    res = pg.optimize(chained, edges)
    assert not res.edge_inlier[-1]
    assert res.edge_inlier[:-1].all()
    assert res.rejected == 1
    t_err, r_err = _errors(res.T_world_node, truth)
    assert t_err < 0.03 and r_err < 0.3
    # without rejection and without a robust loss the wrong edge ruins the map
    res_naive = pg.optimize(chained, edges, loss="none", max_rejection_rounds=0)
    assert _errors(res_naive.T_world_node, truth)[0] > 5 * t_err


def test_wrong_odometry_edge_is_outvoted_by_loops_but_bridges_stay():
    rng = np.random.default_rng(6)
    truth = _square_loop()
    loops = ((2, 5), (3, 6), (2, 6), (3, 5), (0, 8), (4, 12))
    chained, edges = _graph(truth, rng, loops=loops)
    # odometry 3 -> 4 is wrong by 20 cm (a bad match through a door)
    edges[3] = pg.Edge(3, 4, edges[3].T_i_j @ _T([0, 0, 0.01], [0.2, 0, 0]), edges[3].information)
    clean = pg.optimize(chained, [e for k, e in enumerate(edges) if k != 3])
    res = pg.optimize(chained, edges, robust_odometry=True, reject_odometry=True)
    assert not res.edge_inlier[3] and res.rejected == 1
    # as good as if the wrong edge had never been there
    assert _errors(res.T_world_node, truth)[0] < 1.05 * _errors(clean.T_world_node, truth)[0]
    naive = pg.optimize(chained, edges, loss="none", max_rejection_rounds=0)
    assert _errors(naive.T_world_node, truth)[0] > 1.5 * _errors(clean.T_world_node, truth)[0]
    # without loops around it, the same edge is a bridge: it is kept (the graph stays whole)
    bridge = [e for e in edges if not e.is_loop]
    res2 = pg.optimize(chained, bridge, robust_odometry=True, reject_odometry=True)
    assert res2.edge_inlier.all()


def test_gravity_priors_fix_tilt_drift():
    truth = _square_loop()
    rng = np.random.default_rng(4)
    # odometry with a systematic pitch bias, as an uncorrected tilt would give; no loops
    edges = []
    for k in range(len(truth) - 1):
        meas = _inv(truth[k]) @ truth[k + 1] @ _T([0, 0.01, 0], [0, 0, 0])
        edges.append(pg.Edge(k, k + 1, meas, _info(0.01, 0.01)))
    chained = [truth[0]]
    for e in edges:
        chained.append(chained[-1] @ e.T_i_j)
    gravity = [(k, truth[k][:3, :3].T @ np.array([0, 0, 1.0]) + rng.normal(0, 1e-4, 3), 0.001)
               for k in range(len(truth))]
    res = pg.optimize(chained, edges, gravity)
    tilt = [np.degrees(np.arccos(np.clip((T[:3, :3] @ u)[2] / np.linalg.norm(u), -1, 1)))
            for T, (_, u, _) in zip(res.T_world_node, gravity)]
    tilt_before = [np.degrees(np.arccos(np.clip((T[:3, :3] @ u)[2] / np.linalg.norm(u), -1, 1)))
                   for T, (_, u, _) in zip(chained, gravity)]
    assert max(tilt_before) > 1.0
    assert max(tilt) < 0.1


def test_g2o_file(tmp_path):
    truth = _square_loop(n=4)
    graph = pg.PoseGraph()
    for T in truth:
        graph.add_node(T)
    graph.add_edge(pg.Edge(0, 1, _inv(truth[0]) @ truth[1], _info(0.01, 0.002)))
    path = tmp_path / "g.g2o"
    graph.save_g2o(path)
    lines = path.read_text().splitlines()
    assert sum(ln.startswith("VERTEX_SE3:QUAT") for ln in lines) == 4
    edge = [ln for ln in lines if ln.startswith("EDGE_SE3:QUAT")][0].split()
    assert len(edge) == 3 + 7 + 21
    assert float(edge[10]) == pytest.approx(1e4)


@pytest.mark.parametrize(
    "edges, message",
    [
        ([pg.Edge(0, 5, np.eye(4), np.eye(6))], "bad node index"),
        ([pg.Edge(0, 1, np.full((4, 4), np.nan), np.eye(6))], "non-finite"),
    ],
)
def test_bad_input_is_a_clear_error(edges, message):
    with pytest.raises(ValueError, match=message):
        pg.optimize(np.stack([np.eye(4)] * 2), edges)


def test_unknown_loss_and_empty_graph():
    with pytest.raises(ValueError, match="unknown loss"):
        pg.optimize(np.stack([np.eye(4)] * 2), [], loss="tukey")
    with pytest.raises(ValueError, match="no nodes"):
        pg.optimize(np.zeros((0, 4, 4)), [])
