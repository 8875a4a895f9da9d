# SPDX-License-Identifier: BSD-3-Clause
"""Pose graph (SLAM back end): nodes T_world_node, relative-pose edges with 6x6 information,
IMU gravity priors; optimised in Ceres (native core) under a robust loss with outlier-edge
rejection.

Conventions
-----------
* Poses are 4x4 float64 homogeneous matrices. An edge ``(i, j, T_ij)`` measures T_i_j, the pose
  of node j in node i's frame (for registration: ``T_target_source`` with target = i, source = j).
* Edge information is 6x6 ordered (tx, ty, tz, rx, ry, rz): translation error [m] in i's frame,
  rotation error [rad] (small-angle vector) in j's frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .. import _ext

LOSSES = ("none", "huber", "cauchy", "soft_l1")


@dataclass
class Edge:
    """A relative-pose measurement T_i_j with its information and kind."""

    i: int
    j: int
    T_i_j: np.ndarray  # (4, 4)
    information: np.ndarray  # (6, 6), order (tx, ty, tz, rx, ry, rz)
    kind: str = "odometry"  # odometry | loop
    fitness: float = float("nan")  # registration overlap, for reports
    rmse: float = float("nan")  # registration inlier RMSE [m], for reports

    @property
    def is_loop(self) -> bool:
        return self.kind != "odometry"


@dataclass
class GraphResult:
    """Result of :func:`optimize`."""

    T_world_node: np.ndarray  # (N, 4, 4)
    edge_chi2: np.ndarray  # (M,) whitened squared error after the solve
    edge_inlier: np.ndarray  # (M,) bool; False for rejected loop edges
    initial_cost: float
    final_cost: float
    iterations: int
    rejected: int
    converged: bool
    message: str


@dataclass
class PoseGraph:
    """Nodes, edges and gravity priors; :meth:`optimize` runs the native solver."""

    T_world_node: list[np.ndarray] = field(default_factory=list)
    edges: list[Edge] = field(default_factory=list)
    gravity: list[tuple[int, np.ndarray, float]] = field(default_factory=list)  # node, up, sigma

    def add_node(self, T_world_node: np.ndarray) -> int:
        self.T_world_node.append(np.asarray(T_world_node, dtype=np.float64).reshape(4, 4))
        return len(self.T_world_node) - 1

    def add_edge(self, edge: Edge) -> None:
        self.edges.append(edge)

    def add_gravity(self, node: int, up_in_node: np.ndarray, sigma_rad: float) -> None:
        self.gravity.append((int(node), np.asarray(up_in_node, dtype=np.float64), float(sigma_rad)))

    def optimize(self, **kwargs) -> GraphResult:
        return optimize(self.T_world_node, self.edges, self.gravity, **kwargs)

    # ---- file I/O: g2o's EDGE_SE3:QUAT / VERTEX_SE3:QUAT text, which g2o_viewer and evo read
    def save_g2o(self, path, T_world_node: np.ndarray | None = None) -> None:
        """Write the graph as g2o text (``VERTEX_SE3:QUAT`` / ``EDGE_SE3:QUAT``).

        g2o orders its information (translation, rotation) like ours, with rotation as twice the
        quaternion vector, which equals our small-angle vector to first order.
        """
        poses = self.T_world_node if T_world_node is None else list(T_world_node)
        with open(path, "w", encoding="utf-8") as fh:
            for k, T in enumerate(poses):
                fh.write(f"VERTEX_SE3:QUAT {k} {_pose_text(T)}\n")
            if poses:
                fh.write("FIX 0\n")
            for e in self.edges:
                info = 0.5 * (e.information + e.information.T)
                upper = " ".join(f"{info[r, c]:.9g}" for r in range(6) for c in range(r, 6))
                fh.write(f"EDGE_SE3:QUAT {e.i} {e.j} {_pose_text(e.T_i_j)} {upper}\n")


def _pose_text(T: np.ndarray) -> str:
    from scipy.spatial.transform import Rotation

    qx, qy, qz, qw = Rotation.from_matrix(T[:3, :3]).as_quat()
    x, y, z = T[:3, 3]
    return f"{x:.9f} {y:.9f} {z:.9f} {qx:.12f} {qy:.12f} {qz:.12f} {qw:.12f}"


def optimize(
    T_world_node,
    edges: list[Edge],
    gravity: list[tuple[int, np.ndarray, float]] | None = None,
    *,
    loss: str = "cauchy",
    loss_scale: float = 4.74,
    robust_odometry: bool = False,
    max_iterations: int = 200,
    num_threads: int = 0,
    fixed_node: int = 0,
    outlier_chi2: float = 22.46,
    max_rejection_rounds: int = 20,
    reject_odometry: bool = False,
) -> GraphResult:
    """Optimise a pose graph.

    Parameters
    ----------
    T_world_node : (N, 4, 4) array_like of float
        Initial node poses (e.g. chained odometry) [m].
    edges : list of Edge
        Relative measurements; loop edges (``kind != "odometry"``) go through the robust loss and
        may be rejected.
    gravity : list of (node, up_in_node (3,), sigma [rad]), optional
        Tilt priors: the world's +z (against gravity) as the IMU sees it in the node's frame.
    loss, loss_scale :
        Robust loss on loop edges (``none``, ``huber``, ``cauchy``, ``soft_l1``); the scale is in
        whitened units (sigmas).
    fixed_node : int
        Node held constant (gauge freedom); -1 for none.
    outlier_chi2 : float
        A loop edge whose chi2 (6 dof) exceeds this after a solve is rejected (worst first, one
        per round) and the graph solved again; 22.46 is chi2(6)'s 99.9 % quantile.
    robust_odometry, reject_odometry : bool
        Odometry edges through the robust loss too; and rejectable like loops when the graph
        stays connected without them (a wrong odometry edge outvoted by the loops around it).

    Returns
    -------
    GraphResult
    """
    if loss not in LOSSES:
        raise ValueError(f"unknown loss {loss!r} ({', '.join(LOSSES)})")
    poses = np.ascontiguousarray(np.asarray(T_world_node, dtype=np.float64).reshape(-1, 4, 4))
    m = len(edges)
    pairs = np.ascontiguousarray([[e.i, e.j] for e in edges], dtype=np.int64).reshape(m, 2)
    rel = np.ascontiguousarray([e.T_i_j for e in edges], dtype=np.float64).reshape(m, 4, 4)
    info = np.ascontiguousarray([e.information for e in edges], dtype=np.float64).reshape(m, 6, 6)
    loops = np.ascontiguousarray([e.is_loop for e in edges], dtype=bool).reshape(m)
    gravity = gravity or []
    g_nodes = np.ascontiguousarray([g[0] for g in gravity], dtype=np.int64).reshape(-1)
    g_up = np.ascontiguousarray([g[1] for g in gravity], dtype=np.float64).reshape(-1, 3)
    g_sigma = np.ascontiguousarray([g[2] for g in gravity], dtype=np.float64).reshape(-1)
    opt = _ext._PoseGraphOptions()
    opt.loss, opt.loss_scale, opt.robust_odometry = loss, float(loss_scale), bool(robust_odometry)
    opt.max_iterations, opt.num_threads = int(max_iterations), int(num_threads)
    opt.fixed_node, opt.outlier_chi2 = int(fixed_node), float(outlier_chi2)
    opt.max_rejection_rounds, opt.reject_odometry = int(max_rejection_rounds), bool(reject_odometry)
    out = _ext.optimize_pose_graph(poses, pairs, rel, info, loops, g_nodes, g_up, g_sigma, opt)
    return GraphResult(
        T_world_node=out.T_world_node,
        edge_chi2=out.edge_chi2,
        edge_inlier=out.edge_inlier.astype(bool),
        initial_cost=float(out.initial_cost),
        final_cost=float(out.final_cost),
        iterations=int(out.iterations),
        rejected=int(out.rejected),
        converged=bool(out.converged),
        message=str(out.message),
    )
