# SPDX-License-Identifier: BSD-3-Clause
"""3-D verification of a heightmap hypothesis: structure fitness (walls and furniture of each
scan on the other's surfaces), the free-space test (points placed where the other scan saw
straight through) and the final oriented point-to-plane polish."""

from __future__ import annotations

import numpy as np

from ..planes import OTHER, WALL
from .levelling import LevelledScan


def _close(yaw_a, shift_a, yaw_b, shift_b, yaw_tol=np.deg2rad(3.0), shift_tol=0.3) -> bool:
    dy = abs((yaw_a - yaw_b + np.pi) % (2 * np.pi) - np.pi)
    ds = float(np.linalg.norm(np.asarray(shift_a) - np.asarray(shift_b)))
    return dy < yaw_tol and ds < shift_tol


def _same_pose(A, B, deg: float = 3.0, m: float = 0.2) -> bool:
    E = np.linalg.inv(A) @ B
    ang = np.degrees(np.arccos(np.clip((np.trace(E[:3, :3]) - 1) / 2, -1, 1)))
    return ang < deg and np.linalg.norm(E[:3, 3]) < m


def _lift(ls: "LevelledScan", lt: "LevelledScan", yaw: float, shift) -> np.ndarray:
    """T_target_source from the image transform target_xy = R(yaw) source_xy + shift (levelled)."""
    c, s = np.cos(yaw), np.sin(yaw)
    M = np.eye(4)
    M[:2, :2] = [[c, -s], [s, c]]
    M[:2, 3] = shift
    return np.linalg.inv(lt.T_level_scan) @ M @ ls.T_level_scan


class _RangeImage:
    """Nearest return per direction around a scan's viewpoint (``registration.free_space``'s
    range image about that point, ``step_deg`` bins, eroded over the 3 x 3 neighbourhood so
    that only space seen through in every neighbouring direction counts as free)."""

    def __init__(self, P: np.ndarray, viewpoint, step_deg: float = 0.5) -> None:
        from ...registration import free_space

        self.v = np.asarray(viewpoint, np.float64).reshape(3)
        self.step_deg = step_deg
        self.img = free_space.range_image(np.asarray(P, np.float64) - self.v, step_deg)

    def _bins(self, P):
        from ...registration import free_space

        return free_space.direction_bins(np.asarray(P, np.float64) - self.v, self.step_deg)

    def seen_through(self, P, rel: float = 0.95, margin_m: float = 0.10) -> np.ndarray:
        """(N,) bool: the point lies clearly in front of the nearest return in its direction
        (closer than ``rel`` x that range less ``margin_m``)."""
        i, j, r = self._bins(P)
        lim = self.img[i, j].astype(np.float64)
        return np.isfinite(lim) & (r < rel * lim - margin_m)


def _in_free_space(P: np.ndarray, rimg: _RangeImage) -> float:
    return float(rimg.seen_through(P).mean()) if len(P) else 0.0


class _Verifier:
    """3-D checks of hypotheses on the registration core: a short point-to-plane ICP, and the
    share of the source's structure (walls and non-planar content, 10 cm voxels) that lands
    within ``max_distance`` of a target point. Floor and ceiling are left out of that share:
    they overlap under any yaw once both scans are levelled."""

    def __init__(self, S, labels_s, Tg, labels_t, max_distance: float, viewpoint_s, viewpoint_t,
                 num_threads: int = 0) -> None:
        from scipy.spatial import cKDTree

        from ...preprocess import voxel_downsample
        from ...registration.pairwise import prepare

        self.max_distance = max_distance
        self.threads = num_threads
        self.src = prepare(S.astype(np.float32), 0.10, num_threads=num_threads)
        self.tgt = prepare(Tg.astype(np.float32), 0.10, num_threads=num_threads)
        self._S, self._Tg = S, Tg
        def structure(P, lab):
            st = P[(lab == WALL) | (lab == OTHER)]
            if len(st) < 100:  # a scan of floor and ceiling only: use everything
                st = P
            return np.asarray(voxel_downsample(st.astype(np.float32), 0.10), np.float64)

        self.struct, self.struct_t = structure(S, labels_s), structure(Tg, labels_t)

        def part(P, lab, cls):
            v = np.asarray(voxel_downsample(P[lab == cls].astype(np.float32), 0.10),
                           np.float64).reshape(-1, 3)
            return v[:: max(1, len(v) // 20_000)]  # an even subset: a hall has 140 k voxels

        # the structure by class for the choice among near-symmetric candidates: the walls
        # (a room's shell, symmetric) and the rest (furniture, columns: what breaks it)
        self.parts = {c: (part(S, labels_s, k), part(Tg, labels_t, k))
                      for c, k in (("wall", WALL), ("other", OTHER))}
        self._oriented = None
        # an even subset for screening many hypotheses
        self.few = self.struct[:: max(1, len(self.struct) // 3000)]
        self.few_t = self.struct_t[:: max(1, len(self.struct_t) // 3000)]
        self.range_s = _RangeImage(S, viewpoint_s)
        self.range_t = _RangeImage(Tg, viewpoint_t)
        def surface(P):
            dense = prepare(P.astype(np.float32), 0.04, num_neighbors=12, num_threads=num_threads)
            pts = np.asarray(dense.points, np.float64)
            return cKDTree(pts), pts, dense.normals, dense.normal_valid

        self.surf_s, self.surf_t = surface(S), surface(Tg)
        self.level = None

    def keep_level(self, L_s, L_t, height: float | None) -> None:
        """Both scans are levelled by gravity (T_level_scan ``L_s``, ``L_t``): every ICP result
        is taken back to a yaw and a shift between the level frames and its translation refitted
        with that rotation fixed (a thin band of walls, as a vertical lidar sees, lets a free
        ICP tip over by degrees). ``height``: the source level frame's height in the target's
        [m] when horizontal planes both scans saw tell it (0 on shared floors, the ceilings'
        difference), kept fixed; None: it stays free (such a scan may see no floor)."""
        self.level = (np.asarray(L_s, np.float64), np.asarray(L_t, np.float64),
                      None if height is None else float(height))

    def _levelled(self, T, src, tgt, **kw):
        """``T`` turned to a yaw between the level frames, its translation refitted."""
        from ...registration.pairwise import register

        L_s, L_t, height = self.level
        M = L_t @ T @ np.linalg.inv(L_s)
        if height is not None:
            M[2, 3] = height
        yaw = np.arctan2(M[1, 0], M[0, 0])
        M[:3, :3] = [[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]]
        T1 = np.ascontiguousarray(np.linalg.inv(L_t) @ M @ L_s)
        try:
            r = register(src, tgt, init=T1, rotation_prior=T1[:3, :3], rotation_prior_sigma=0.0,
                         lock_z=height is not None, num_threads=self.threads, **kw)
        except ValueError:
            return T1, None
        return r.T_target_source, r

    def free_space_violation(self, T, screen: bool = False) -> float:
        """Share of each scan's structure that the other scan saw through (points lying in front
        of the other's nearest return in their direction, by more than 5 % + 10 cm), averaged
        over both directions; 0 for a consistent pose."""
        Ti = np.linalg.inv(T)
        a, b = (self.few, self.few_t) if screen else (self.struct, self.struct_t)
        a = _in_free_space(a @ T[:3, :3].T + T[:3, 3], self.range_t)
        b = _in_free_space(b @ Ti[:3, :3].T + Ti[:3, 3], self.range_s)
        return 0.5 * (a + b)

    def structure_fitness(self, T, max_distance: float | None = None,
                          screen: bool = False) -> float:
        """Share of the structure within ``max_distance`` of the other scan's surface, the mean
        of both directions (source on target, target on source): the nearest point within
        30 cm counts, distance measured along its normal (a sparse scan has gaps between its
        lines that a point-to-point test would count as misses)."""
        Ti = np.linalg.inv(T)
        tol = self.max_distance if max_distance is None else max_distance
        a, b = (self.few, self.few_t) if screen else (self.struct, self.struct_t)
        return 0.5 * (self._on_surface(a @ T[:3, :3].T + T[:3, 3], self.surf_t, tol)
                      + self._on_surface(b @ Ti[:3, :3].T + Ti[:3, 3], self.surf_s, tol))

    def consistency(self, T, tight: float, rel: float = 0.98, margin_m: float = 0.10) -> dict:
        """Full 3-D consistency of a pose, by class (walls, other), each the mean of both
        directions (source on target, target on source): ``fit_<class>`` the share within
        ``tight`` of the other's surface, ``viol_<class>`` the share the other scan saw through
        (in front of its nearest return by more than (1 - ``rel``) x range + ``margin_m``), and
        the counts ``n_<class>`` of both; shares of a class with under 50 points are 0."""
        Ti = np.linalg.inv(T)
        out = {}
        for c, (a, b) in self.parts.items():
            a = a @ T[:3, :3].T + T[:3, 3]
            b = b @ Ti[:3, :3].T + Ti[:3, 3]
            n = min(len(a), len(b))
            out[f"n_{c}"] = n
            if n < 50:
                out[f"fit_{c}"] = out[f"viol_{c}"] = 0.0
                continue
            out[f"fit_{c}"] = 0.5 * (self._on_surface(a, self.surf_t, tight)
                                     + self._on_surface(b, self.surf_s, tight))
            out[f"viol_{c}"] = 0.5 * (float(self.range_t.seen_through(a, rel, margin_m).mean())
                                      + float(self.range_s.seen_through(b, rel, margin_m).mean()))
        return out

    def _on_surface(self, p, surf, tol: float) -> float:
        tree, pts, nrm, nok = surf
        d, j = tree.query(p, distance_upper_bound=max(0.3, tol))
        near = np.isfinite(d)
        jj = j[near]
        dist = np.where(nok[jj], np.abs(np.einsum("ij,ij->i", p[near] - pts[jj], nrm[jj])), d[near])
        return float((dist < tol).sum() / max(len(p), 1))

    def polish(self, T) -> np.ndarray:
        from ...registration.pairwise import register

        try:
            r = register(self.src, self.tgt, "plane", init=T,
                         max_correspondence_distance=[0.4, 0.15], max_iterations=15,
                         num_threads=self.threads)
        except ValueError:  # too few correspondences: judge the hypothesis as proposed
            return T
        T2 = r.T_target_source
        if self.level is not None:
            return self._levelled(T2, self.src, self.tgt, method="plane",
                                  max_correspondence_distance=0.15, max_iterations=15)[0]
        # a hypothesis ICP tipped over (tilted) is not one the levelled images proposed
        tilt = np.degrees(np.arccos(np.clip((T2[:3, :3] @ T[:3, :3].T)[2, 2], -1, 1)))
        return T2 if tilt < 3.0 else T

    def final(self, T):
        """Point-to-plane ICP on oriented normals (each facing its scan's viewpoint): a wall
        seen from both of its sides (a partition between two rooms) is two faces, and plain ICP
        would pull them together. Returns (T, fitness, inlier RMSE [m])."""
        from ...preprocess import voxel_downsample
        from ...registration.pairwise import prepare, register

        # level scans: 10 cm voxels and 20 neighbours; 5 cm normals on a noisy band of walls
        # (a vertical lidar's) pull the translation by centimetres even from the true pose
        voxel, nn = (0.10, 20) if self.level is not None else (0.05, 12)

        def oriented(P, v):
            return prepare(voxel_downsample(P.astype(np.float32), voxel), num_neighbors=nn,
                           viewpoint=v, point_sigma=0.03, num_threads=self.threads)

        if self._oriented is None:  # once per pair: every candidate is finished on them
            self._oriented = (oriented(self._S, self.range_s.v), oriented(self._Tg, self.range_t.v))
        src, tgt = self._oriented
        T2 = np.ascontiguousarray(T, dtype=np.float64)
        r = None
        kw = dict(method="plane", max_iterations=15, rotation_eps=1e-6, translation_eps=1e-5,
                  loss="huber", loss_scale=0.06, point_sigma=0.03, oriented=True,
                  max_source=60_000, min_correspondences=100)
        for dist in (0.15, 0.08):
            r = register(src, tgt, init=T2, max_correspondence_distance=dist,
                         num_threads=self.threads, **kw)
            T2 = r.T_target_source
            if self.level is not None and r.status != "too_few_correspondences":
                T2, r2 = self._levelled(T2, src, tgt, max_correspondence_distance=dist, **kw)
                r = r2 if r2 is not None else r
        if r.status == "too_few_correspondences" or not _same_pose(T2, T, 2.0, 0.3):
            return np.asarray(T), float("nan"), float("nan")  # ran away: keep the verified pose
        return T2, float(r.fitness), float(r.residual_rmse)
