# SPDX-License-Identifier: BSD-3-Clause
"""Odometry chain, loop closures and the pose graph over station fragments.

Node k is T_world_lidar of station k at its middle time. Odometry edges join consecutive
stations; loop candidates are station pairs close in the odometry map, registered from that map's
guess (the top-down seeds when it fails) and kept when verified; the pose graph (IMU gravity
priors on every node, Cauchy loss on loops) rejects the loops that disagree with the rest; an
edge between stations whose IMU tilt is fitted over the station carries yaw and position only
(``tilt_free_information``).
Stations no registration reaches are reported as disconnected, never merged.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..registration import pose_graph as pg
from .config import OdometryConfig, SlamConfig
from .fragments import Fragment
from .odometry import CloudCache, PairResult
from .scaleout import register_pairs, thread_workers


def inv(T: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out


@dataclass
class SlamResult:
    T_odometry: np.ndarray  # (N, 4, 4) chained odometry, T_world_lidar per station
    T_optimized: np.ndarray  # (N, 4, 4) after the pose graph
    edges: list[pg.Edge]
    graph: pg.PoseGraph
    graph_result: pg.GraphResult | None
    component: np.ndarray  # (N,) int, connected-component id; 0 is the map
    disconnected: list[int] = field(default_factory=list)
    loop_candidates: int = 0
    notes: list[str] = field(default_factory=list)

def optimize_graph(graph: pg.PoseGraph, scfg: SlamConfig, num_threads: int = 0):
    """Optimise a station pose graph with the SLAM config's robust loss and outlier rules
    (node 0 fixed); the one place both SLAM and the multi-recording merge call."""
    return graph.optimize(loss=scfg.loss, loss_scale=scfg.loss_scale,
                          outlier_chi2=scfg.outlier_chi2, num_threads=num_threads,
                          fixed_node=0, robust_odometry=scfg.robust_odometry,
                          reject_odometry=scfg.robust_odometry)


def _edge(i: int, j: int, r: PairResult, kind: str) -> pg.Edge:
    return pg.Edge(i, j, r.T_target_source, r.information, kind, r.fitness, r.rmse)


def run_odometry(frags: list[Fragment], cfg: OdometryConfig, num_threads: int = 0,
                 progress=None, cache: CloudCache | None = None, engine=None
                 ) -> tuple[np.ndarray, list[pg.Edge], np.ndarray, list[str]]:
    """Chain consecutive registrations. Returns T_world_lidar (N,4,4), edges, component ids,
    notes. A failed pair is retried against the two stations before; if those fail too a new
    component starts there. Every pair (k, k-1) is independent of the others: they run first,
    as one map on ``engine`` (:mod:`.engine`; in process by default), the retries after."""
    n = len(frags)
    cache = cache or CloudCache(cfg.point_sigma_m, num_threads)
    T = np.tile(np.eye(4), (n, 1, 1))
    if n:
        T[0, :3, :3] = frags[0].R_world_lidar  # gravity-aligned world, yaw from the IMU
    comp = np.zeros(n, dtype=int)
    edges: list[pg.Edge] = []
    notes: list[str] = []
    found: dict[int, tuple[int, PairResult]] = {}  # station -> (the station it joined, pair)
    todo = list(range(1, n))
    for back in (1, 2, 3):
        pairs = [(k, k - back) for k in todo if k - back >= 0]
        if not pairs:
            break
        res = register_pairs(engine, frags, pairs, cfg, num_threads, cache,
                             progress=progress if back == 1 else None)
        found.update({k: (i, r) for (k, i), r in zip(pairs, res) if r.ok})
        todo = [k for k, _ in pairs if k not in found]
    for k in range(1, n):
        if k in found:
            i, r = found[k]
            T[k] = T[i] @ r.T_target_source
            comp[k] = comp[i]
            edges.append(_edge(i, k, r, "odometry"))
            if k - i > 1:
                notes.append(f"station {k}: registered to station {i} (not {k - 1})")
            if r.fitness < cfg.min_fitness:
                notes.append(f"station {k}: registered to station {i} at a low overlap "
                             f"({r.fitness:.0%}), kept as free space agrees (violation "
                             f"{r.violation:.2%})")
        else:
            comp[k] = comp[:k].max() + 1
            T[k] = np.eye(4)
            T[k, :3, :3] = frags[k].R_world_lidar
            notes.append(f"station {k}: no overlap with the stations before it")
    return T, edges, comp, notes


def _merge_components(comp: np.ndarray, i: int, j: int) -> None:
    a, b = comp[i], comp[j]
    if a != b:
        lo, hi = min(a, b), max(a, b)
        comp[comp == hi] = lo


def run_slam(frags: list[Fragment], T_odom: np.ndarray, odom_edges: list[pg.Edge],
             comp: np.ndarray, ocfg: OdometryConfig, scfg: SlamConfig, num_threads: int = 0,
             progress=None, cache: CloudCache | None = None, engine=None) -> SlamResult:
    """Loop closures and pose-graph optimisation (see the module docstring); the loop
    candidates' registrations on ``engine`` (:mod:`.engine`; in process by default)."""
    n = len(frags)
    cache = cache or CloudCache(ocfg.point_sigma_m, num_threads)
    comp0, comp = comp, comp.copy()
    edges = list(odom_edges)
    notes: list[str] = []
    connected = {(e.i, e.j) for e in edges}
    # 1. loop candidates: close in the odometry map (same component), not already joined
    cands = []
    if scfg.enabled:
        pos = T_odom[:, :3, 3]
        for i in range(n):
            near = []
            for j in range(i + 2, n):
                if (i, j) in connected:
                    continue
                same = comp[i] == comp[j]
                d = float(np.linalg.norm(pos[i] - pos[j])) if same else np.inf
                if d < scfg.loop_radius_m or not same:
                    near.append((d, j))
            near.sort()
            cands += [(i, j) for _, j in near[: scfg.max_loops_per_station]]
    if progress is not None:
        progress.total = len(cands)
        progress.refresh()
    # on a distributed engine (or on threads in process) every candidate is registered at
    # once, from its guess of now;
    # a candidate whose stations a loop before it joins needs a guess it did not have: that one
    # is registered again in order (the same results as the plain loop, which this is in process)
    ahead = None
    if cands and ((engine is not None and engine.distributed)
                  or thread_workers(num_threads, len(cands)) > 1):
        ahead = register_pairs(engine, frags, [(j, i) for i, j in cands], ocfg, num_threads,
                               guesses=[_loop_guess(T_odom, comp, i, j) for i, j in cands])
    for k, (i, j) in enumerate(cands):
        guess = _loop_guess(T_odom, comp, i, j)
        if ahead is not None and (guess is None) == (comp0[i] != comp0[j]):
            r = ahead[k]
        else:
            r = register_pairs(None, frags, [(j, i)], ocfg, num_threads, cache, [guess])[0]
        if r.ok:
            edges.append(_edge(i, j, loop_capped(r, ocfg, scfg), "loop"))
            if comp[i] != comp[j]:
                notes.append(f"stations {i} and {j} joined by a loop closure")
                _merge_components(comp, i, j)
        if progress is not None:
            progress.update(1)
    # components joined by loops start where those loops put them; an odometry pair that the
    # loops around it outvote is left out of the start (the graph then rejects it)
    T_init = _chain_initial(n, edges, T_odom, frags)
    if scfg.loop_consensus:
        T_init, dropped = consensus_initial(n, edges, T_init, T_odom, frags,
                                            scfg.consensus_m, scfg.consensus_deg)
        for e, m in dropped:
            notes.append(f"odometry pair {e.i}-{e.j} disagrees with {m} loop closures that agree "
                         "with the rest: the pose graph starts without it")

    # 2. pose graph over the main component (that of station 0, or the largest)
    ids, counts = np.unique(comp, return_counts=True)
    main = comp[0] if counts[list(ids).index(comp[0])] * 2 >= n else ids[np.argmax(counts)]
    members = [k for k in range(n) if comp[k] == main]
    index = {k: m for m, k in enumerate(members)}
    graph = station_graph(frags, members, T_init, edges, scfg)
    T_opt = T_init.copy()
    gres = None
    if graph.edges:
        gres = optimize_graph(graph, scfg, num_threads)
        for k in members:
            T_opt[k] = gres.T_world_node[index[k]]
    disconnected = [k for k in range(n) if comp[k] != main]
    for k in disconnected:
        notes.append(f"station {k} is disconnected from the map (no registration reaches it): "
                     "its fragment is written alone, not merged")
    comp_out = np.where(comp == main, 0, comp + 1)
    return SlamResult(T_odom, T_opt, edges, graph, gres, comp_out, disconnected, len(cands), notes)


def loop_capped(r: PairResult, ocfg: OdometryConfig, scfg: SlamConfig) -> PairResult:
    """A loop closure's pair with its information capped at the loop floors
    (``slam.loop_sigma_floor_m`` / ``_deg``; either 0: the odometry's floor there, both 0:
    ``r`` as it is)."""
    if scfg.loop_sigma_floor_m <= 0 and scfg.loop_sigma_floor_deg <= 0:
        return r
    from .odometry import _cap_whitened

    sm = max(scfg.loop_sigma_floor_m, ocfg.sigma_floor_m)
    sd = np.radians(max(scfg.loop_sigma_floor_deg, ocfg.sigma_floor_deg))
    C = np.diag([1 / sm**2] * 3 + [1 / sd**2] * 3)
    return PairResult(r.T_target_source, r.fitness, r.rmse, _cap_whitened(r.information, C),
                      r.ok, r.seed, r.violation, r.status)


def station_graph(frags: list[Fragment], members: list[int], T_init: np.ndarray,
                  edges: list[pg.Edge], scfg: SlamConfig) -> pg.PoseGraph:
    """The pose graph over stations ``members`` (node m is station members[m], started at
    ``T_init``): the edges between them and a gravity prior on each, at
    ``scfg.gravity_sigma_fitted_deg`` for a station whose anchor tilt is fitted over its IMU
    samples (``Fragment.tilt_fitted``), else ``gravity_sigma_deg``; with ``scfg.tilt_from_imu``
    an edge between two such stations carries no tilt (:func:`tilt_free_information`)."""
    index = {k: m for m, k in enumerate(members)}
    graph = pg.PoseGraph()
    for k in members:
        graph.add_node(T_init[k])
    fitted = {k: scfg.gravity_sigma_fitted_deg > 0 and frags[k].tilt_fitted for k in members}
    for e in edges:
        if e.i in index and e.j in index:
            info = e.information
            if scfg.tilt_from_imu and fitted[e.i] and fitted[e.j]:
                info = tilt_free_information(info, frags[e.j].up_in_lidar)
            graph.add_edge(pg.Edge(index[e.i], index[e.j], e.T_i_j, info, e.kind,
                                   e.fitness, e.rmse))
    for k in members:
        sigma = scfg.gravity_sigma_fitted_deg if fitted[k] else scfg.gravity_sigma_deg
        graph.add_gravity(index[k], frags[k].up_in_lidar, np.radians(sigma))
    return graph


def tilt_free_information(info: np.ndarray, up_in_j: np.ndarray) -> np.ndarray:
    """An edge's information (6, 6; the pose graph's order: translation error in i's frame,
    rotation error in j's) without its two tilt directions: the rotations about the axes
    across ``up_in_j`` (the world's up in j's frame) marginalised out (Schur complement), so the
    edge constrains translation and yaw only, and the translation no more than it is known with
    the tilt left free.

    Why (dev seed 126, a 4 x 4 m room, 9° mount, the whole true calibration given): each
    fragment fitted onto the scene mesh at its true pose moves by 0.01-0.04°, and the stations'
    IMU anchors tilt 0.006° RMS off the truth, but the registrations between the fragments are
    0.1-0.6° off in tilt (yaw 0.04°), with 0.3-3.5 cm of shift along: the same fragments
    projected onto the mesh (their range noise removed) register within 0.05°. With
    information capped at 0.03° such edges outweighed the gravity priors (0.1°).
    """
    up = np.asarray(up_in_j, dtype=np.float64)
    up = up / np.linalg.norm(up)
    a = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    b1 = np.cross(up, a)
    b1 /= np.linalg.norm(b1)
    Q = np.eye(6)
    Q[3:, 3:] = np.stack([b1, np.cross(up, b1), up], axis=1)  # rotation coordinates (b1, b2, up)
    L = Q.T @ (0.5 * (info + info.T)) @ Q
    keep, tilt = [0, 1, 2, 5], [3, 4]
    red = L[np.ix_(keep, keep)] - L[np.ix_(keep, tilt)] @ np.linalg.pinv(
        L[np.ix_(tilt, tilt)]) @ L[np.ix_(tilt, keep)]
    out = np.zeros((6, 6))
    out[np.ix_(keep, keep)] = 0.5 * (red + red.T)
    return Q @ out @ Q.T


def _loop_guess(T_odom: np.ndarray, comp: np.ndarray, i: int, j: int) -> np.ndarray | None:
    """T_i_j from the odometry map when both stations are in the same component, else None."""
    return inv(T_odom[i]) @ T_odom[j] if comp[i] == comp[j] else None


def _agreeing(edges: list[pg.Edge], T: np.ndarray, tol_m: float, tol_deg: float
              ) -> np.ndarray:
    """(M,) bool: each edge's T_i_j within ``tol_m`` / ``tol_deg`` of the poses ``T``."""
    out = np.zeros(len(edges), dtype=bool)
    cos_tol = np.cos(np.radians(tol_deg))
    for k, e in enumerate(edges):
        D = inv(e.T_i_j) @ inv(T[e.i]) @ T[e.j]
        out[k] = (np.linalg.norm(D[:3, 3]) < tol_m
                  and (np.trace(D[:3, :3]) - 1) / 2 > cos_tol)
    return out


def consensus_initial(n: int, edges: list[pg.Edge], T_init: np.ndarray, T_odom: np.ndarray,
                      frags: list[Fragment], tol_m: float = 0.3, tol_deg: float = 3.0,
                      max_rounds: int = 3) -> tuple[np.ndarray, list[tuple[pg.Edge, int]]]:
    """The pose graph's start, checked against the cycles the loop closures close.

    A wrong odometry pair (a room laid beside itself, a corridor slid along its axis) puts every
    station after it off by metres; the loops spanning it then disagree with the chain, and a
    robust pose graph started there keeps the chain and rejects the loops one by one (a Cauchy
    loss hardly pulls at 1000 sigmas). Hypotheses: the chain with one odometry edge left out and
    its two sides joined by one loop that spans it; each is scored by how many edges (odometry
    and loops) agree with its poses within ``tol_m`` / ``tol_deg``. One that more edges agree
    with than the current start replaces it (greedy, up to ``max_rounds`` odometry edges): two
    loops that agree with each other outvote one odometry pair, one loop alone does not.
    Returns (start poses, [(dropped odometry edge, loops agreeing with the new start)]).
    """
    loop_ids = [k for k, e in enumerate(edges) if e.is_loop]
    if not loop_ids:
        return T_init, []
    tree = [k for k, e in enumerate(edges) if not e.is_loop]  # edge indices chaining the start
    side = _sides(n, [edges[k] for k in tree])
    for m in sorted(loop_ids, key=lambda m: (edges[m].i, edges[m].j)):
        if side[edges[m].i] != side[edges[m].j]:  # a loop joining components chains them too
            tree.append(m)
            side = _sides(n, [edges[k] for k in tree])
    T_best = T_init
    agree = _agreeing(edges, T_best, tol_m, tol_deg)
    best_count = int(agree.sum())
    dropped: list[tuple[pg.Edge, int]] = []
    for _ in range(max_rounds):
        found = None
        for k in tree:
            if edges[k].is_loop:
                continue
            side = _sides(n, [edges[t] for t in tree if t != k])
            for m in loop_ids:
                L = edges[m]
                if agree[m] or m in tree or side[L.i] == side[L.j]:
                    continue  # agrees with the start, or does not span edge k
                cand = [edges[t] for t in tree if t != k] + [L]
                T = _chain_initial(n, cand, T_odom, frags)
                a = _agreeing(edges, T, tol_m, tol_deg)
                c = int(a.sum())
                if c > best_count and (found is None or c > found[0]):
                    found = (c, k, m, T, a)
        if found is None:
            break
        best_count, k, m, T_best, agree = found
        tree = [t for t in tree if t != k] + [m]
        dropped.append((edges[k], int(agree[loop_ids].sum())))
    return T_best, dropped


def _sides(n: int, edges: list[pg.Edge]) -> np.ndarray:
    """(n,) component label of every station over ``edges`` (union-find)."""
    parent = list(range(n))

    def root(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    for e in edges:
        parent[root(e.i)] = root(e.j)
    return np.array([root(a) for a in range(n)])


def _chain_initial(n: int, edges: list[pg.Edge], T_odom: np.ndarray,
                   frags: list[Fragment]) -> np.ndarray:
    """Initial poses: a breadth-first chain over all edges from station 0 (odometry first), so
    components joined only by loops start in the right place."""
    T = T_odom.copy()
    seen = {0}
    order = sorted(edges, key=lambda e: (e.kind != "odometry", e.i, e.j))
    changed = True
    while changed:
        changed = False
        for e in order:
            if e.i in seen and e.j not in seen:
                T[e.j] = T[e.i] @ e.T_i_j
                seen.add(e.j)
                changed = True
            elif e.j in seen and e.i not in seen:
                T[e.i] = T[e.j] @ inv(e.T_i_j)
                seen.add(e.i)
                changed = True
    return T
