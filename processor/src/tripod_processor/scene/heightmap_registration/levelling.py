# SPDX-License-Identifier: BSD-3-Clause
"""Levelling a labelled scan on its floor plane: the frame where only yaw and an x-y shift
remain between two scans."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..planes import CEILING, FLOOR, WALL, extract_planes


def _rot_to_z(n: np.ndarray) -> np.ndarray:
    """Smallest rotation taking unit n onto +z."""
    n = n / np.linalg.norm(n)
    v = np.cross(n, [0.0, 0.0, 1.0])
    s, c = np.linalg.norm(v), n[2]
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    K = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]]) / s
    ang = np.arctan2(s, c)
    return np.eye(3) + np.sin(ang) * K + (1 - np.cos(ang)) * K @ K


@dataclass
class LevelledScan:
    """A scan on its floor: T_level_scan (4, 4) puts the floor at z = 0 with +z up; ``xy``/``z``
    are the points standing between floor and ceiling in that frame, ``floor_xy`` the floor's."""

    T_level_scan: np.ndarray
    xy: np.ndarray
    z: np.ndarray
    floor_xy: np.ndarray
    height: float
    labels: np.ndarray
    #: the floor is a plane with (almost) nothing below it: its height can be trusted (a
    #: table top taken for the floor by a scan that saw no floor has walls below it)
    floor_trusted: bool = True
    #: the ceiling (at z = ``height``) is a plane with (almost) nothing above it: two scans that
    #: both see it share its height when a floor is missing (a vertical lidar's narrow band may
    #: see the ceiling of a low room but not the floor)
    ceiling_trusted: bool = False


def structure_up(planes, *, prior_sigma_deg: float = 0.25, min_sigma_deg: float = 0.1,
                 max_tilt_deg: float = 1.5, outlier_deg: float = 1.0,
                 parts: bool = True) -> np.ndarray:
    """The up direction (unit (3,), in the planes' frame) that makes the walls vertical and the
    floors and ceilings horizontal, near +z: the frame's +z is the prior (an IMU's gravity).

    Each wall (normal within 10 deg of horizontal) asks n . u = 0, each floor or ceiling (within
    10 deg of vertical) u parallel to n; with u = (a, b, 1) these are linear in (a, b). Each
    plane counts as one measurement, weighted by its points (at most 20 000; weights of mean
    1); planes more than ``outlier_deg`` off the prior, then off the structure's own fit, are
    dropped and the fit repeated. The structure's tilt is
    then **fused with the prior by their uncertainties**: the structure's from the scatter of
    its planes about the fit (``s``, at least ``min_sigma_deg``: what the planes disagree by is
    what they are worth), the prior's ``prior_sigma_deg`` (a station's static IMU gravity,
    within ~0.1 deg of the truth on the dev captures). Walls that agree to a small fraction of
    a degree correct an up that is off by ~1 deg; a thin noisy band of walls and mislabelled
    planes that scatter by a degree barely move a good prior (the equal-weight version moved
    dev fragments with a 0.05 deg IMU up by up to 1.1 deg), and a direction no wall constrains
    (a corridor's) stays at the prior. The structure is uncertain by at least half the
    disagreement of its two independent parts (``parts``, :func:`_parts_disagreement`): the
    walls' tilt and the floors' and ceilings', each solved alone. A vertical lidar sees the
    floor only as a ring 6-13 m away, whose plane can lean by ~1 deg; on the dev vertical
    fragments (seed 302) the joint fit then moved an IMU up 0.01 deg off by up to 0.60 deg (the
    floor height 6 cm off at 12 m), by at most 0.14 deg with this bound (off: the fit as
    before). When the structure alone says a tilt over ``max_tilt_deg`` it is not trusted (+z
    is returned): on the dev fragments such fits came from a few mislabelled or one-sided planes
    (1.9 and 7.5 deg off at a 0.05 deg IMU up)."""
    rows, rhs, w, is_wall = [], [], [], []
    for p in planes:
        n = np.asarray(p.normal, np.float64)
        k = float(min(len(p.indices), 20_000)) / 20_000
        if p.label == WALL and abs(n[2]) < np.sin(np.radians(10.0)):
            rows.append([n[0], n[1]]), rhs.append(-n[2]), w.append(k), is_wall.append(True)
        elif p.label in (FLOOR, CEILING) and abs(n[2]) > np.cos(np.radians(10.0)):
            rows += [[1.0, 0.0], [0.0, 1.0]]
            rhs += [n[0] / n[2], n[1] / n[2]]
            w += [k, k]
            is_wall += [False, False]
    if not rows:
        return np.array([0.0, 0.0, 1.0])
    A, y, wt = np.asarray(rows), np.asarray(rhs), np.asarray(w)
    is_wall = np.asarray(is_wall)
    # the prior is right to ~1 deg (a static IMU's gravity): a plane that says more is no level
    # wall, floor or ceiling (furniture sides, sloped or mislabelled surfaces)
    keep = np.abs(y) < np.radians(outlier_deg)
    if not keep.any():
        return np.array([0.0, 0.0, 1.0])
    prior_info = 1.0 / np.radians(prior_sigma_deg) ** 2
    ab = np.zeros(2)
    for _ in range(2):
        Ak, yk, wk = A[keep], y[keep], wt[keep] / wt[keep].mean()  # a plane counts ~1
        N = Ak.T @ (Ak * wk[:, None])
        # the structure alone (a weak pull to the prior keeps an unconstrained direction there)
        ab_s = np.linalg.solve(N + 1e-6 * np.eye(2), Ak.T @ (wk * yk))
        dof = len(yk) - 2  # planes (rows) beyond the two unknowns; weights of mean 1
        if dof > 0:
            r2 = float((wk * (Ak @ ab_s - yk) ** 2).sum() / dof)
            s2 = max(r2, np.radians(min_sigma_deg) ** 2)
        else:  # too few planes to tell how far they agree: the prior wins
            s2 = np.radians(1.0) ** 2
        if parts:
            s2 = max(s2, _parts_disagreement(Ak, yk, wk, is_wall[keep], ab_s, N))
        ab = np.linalg.solve(N / s2 + prior_info * np.eye(2), Ak.T @ (wk * yk) / s2)
        keep = np.abs(A @ ab_s - y) < np.radians(outlier_deg)
        if not keep.any():
            break
    if np.degrees(np.arctan(np.linalg.norm(ab_s))) > max_tilt_deg:
        return np.array([0.0, 0.0, 1.0])  # the structure alone says a tilt the prior rules out
    u = np.array([ab[0], ab[1], 1.0])
    return u / np.linalg.norm(u)


def _parts_disagreement(A, y, w, is_wall, ab_s, N) -> float:
    """Smallest per-plane variance [rad^2] of :func:`structure_up`'s fit that the disagreement
    of its two independent parts allows: the walls' tilt and the floors' and ceilings' tilt,
    each solved alone (a direction a part does not constrain held at the joint fit ``ab_s``),
    differ by D; the joint fit is then uncertain by at least D / 2, i.e. a plane by D / 2 x
    sqrt(planes). 0 when either part is missing."""
    if is_wall.all() or not is_wall.any():
        return 0.0
    sols = []
    for part in (is_wall, ~is_wall):
        Ap, yp, wp = A[part], y[part], w[part]
        Np = Ap.T @ (Ap * wp[:, None])
        eps = 1e-3 * max(float(np.trace(N)), 1e-9)  # a weak pull to the joint fit
        sols.append(np.linalg.solve(Np + eps * np.eye(2), Ap.T @ (wp * yp) + eps * ab_s))
    d = float(np.linalg.norm(sols[0] - sols[1]))
    return (d / 2.0) ** 2 * float(np.trace(N)) / 2.0


#: [m^2] smallest ceiling plane whose height two scans may share when a floor is missing: a
#: vertical lidar's narrow band sees a strip of a soffit, beam or lower ceiling as "the" ceiling
#: (dev heightmap pairs, vertical room of seed 301: planes of 1.0 and 1.3 m^2 there put
#: the height 10-20 cm off; the room's whole ceilings seen were 2.4-3.2 m^2)
MIN_TRUSTED_CEILING_M2 = 2.0

#: [deg] most a gravity-levelled scan's floor or ceiling plane may lean from horizontal (the up
#: it carries is right to ~1 deg, :func:`structure_up` trusts no more than 1.5): a plane that
#: leans more is a sloped surface, not the floor (dev heightmap pairs, vertical room of seed
#: 301: a vertical lidar that saw no floor took a 9 deg slope 30 cm above it for the floor,
#: trusted it as nothing lay below, and a pair came back 19 cm / 1.3 deg off with success =
#: true; the true floors and ceilings seen there leant 0.0-0.3 deg)
MAX_LEVEL_PLANE_TILT_DEG = 3.0


def level_scan(points, labels, *, seed: int = 0, max_points: int = 200_000,
               gravity: bool = False, max_tilt_deg: float = 1.5) -> LevelledScan:
    """Level a labelled scan on its largest floor plane (and measure the ceiling height).

    ``gravity``: the scan's z is already up along gravity (levelled by its IMU up): the level is
    then refined by the structure (:func:`structure_up`: walls vertical, floors and ceilings
    horizontal, fused with the prior by their uncertainties; a structure that says over
    ``max_tilt_deg`` is not trusted), the floor is the lowest sizeable floor plane within
    :data:`MAX_LEVEL_PLANE_TILT_DEG` of horizontal (the ceiling likewise) and gives the height only, and without one
    the height comes from the lowest floor-labelled (else lowest) points: a lidar with its spin
    axis vertical sees little floor in a small room, but gravity and its walls still level it.
    ``floor_trusted``: the floor is a plane with under 1 % of the points below it;
    ``ceiling_trusted`` (gravity only): the ceiling is a level plane of at
    least :data:`MIN_TRUSTED_CEILING_M2` with under 1 % of the points above it."""
    P = np.asarray(points, np.float64)
    labels = np.asarray(labels)
    ok = np.isfinite(P).all(1)
    P, labels = P[ok], labels[ok]
    if len(P) > max_points:  # planes and images need no more
        idx = np.random.default_rng(seed).choice(len(P), max_points, replace=False)
        P, labels = P[idx], labels[idx]
    planes = extract_planes(P, labels, classes=(FLOOR, CEILING), min_points=200, seed=seed)
    if gravity:  # the walls' normals, on a subset (they only level)
        few = slice(None, None, max(1, len(P) // 60_000))
        planes += extract_planes(P[few], labels[few], classes=(WALL,), min_points=100, seed=seed)
    level_cos = np.cos(np.radians(MAX_LEVEL_PLANE_TILT_DEG))
    floors = [p for p in planes if p.label == FLOOR
              and (not gravity or abs(p.normal[2]) > level_cos)]
    T = np.eye(4)
    if gravity:  # gravity, refined by the walls, floors and ceilings; the floor gives the height
        R = _rot_to_z(structure_up(planes, max_tilt_deg=max_tilt_deg))
        T[:3, :3] = R
        if floors:  # the lowest sizeable one: a sparse floor can be smaller than a table top
            fl = max(floors, key=lambda p: len(p.indices))
            big = [p for p in floors if len(p.indices) >= 0.2 * len(fl.indices)]
            fl = min(big, key=lambda p: float(np.median(P[p.indices, 2])))
            floor_idx = fl.indices
            T[2, 3] = -float(np.median(P[floor_idx] @ R[2]))
        else:
            z = P @ R[2]
            on_floor = labels == FLOOR
            zf = z[on_floor] if on_floor.sum() >= 50 else z
            T[2, 3] = -float(np.percentile(zf, 1.0 if on_floor.sum() >= 50 else 0.5))
            floor_idx = np.flatnonzero(np.abs(z + T[2, 3]) < 0.05)
    elif floors:
        fl = max(floors, key=lambda p: len(p.indices))
        floor_idx = fl.indices
        T[:3, :3] = _rot_to_z(fl.normal)
        T[2, 3] = fl.offset  # n.x + d = 0 on the floor -> z' = n.x + d
    else:
        raise ValueError("no floor plane found: cannot level the scan")
    R = T[:3, :3]
    Q = P @ R.T + T[:3, 3]
    ceilings = [p for p in planes if p.label == CEILING
                and (not gravity or abs(p.normal[2]) > level_cos)]
    ceiling_trusted = False
    if ceilings:
        cl = max(ceilings, key=lambda p: len(p.indices))
        height = float(np.median(Q[cl.indices, 2]))
        ceiling_trusted = bool(gravity and cl.area >= MIN_TRUSTED_CEILING_M2
                               and float((Q[:, 2] > height + 0.10).mean()) < 0.01)
    else:
        height = float(np.percentile(Q[:, 2], 99.5))
    band = (Q[:, 2] > 0.10) & (Q[:, 2] < height - 0.10)
    trusted = bool(floors) and float((Q[:, 2] < -0.10).mean()) < 0.01
    return LevelledScan(T, Q[band, :2], Q[band, 2], Q[floor_idx, :2], height, labels[band],
                        trusted, ceiling_trusted)
