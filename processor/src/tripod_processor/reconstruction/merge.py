# SPDX-License-Identifier: BSD-3-Clause
"""One model from many recordings (``tripod batch --merge``): join the recordings' station
graphs into one pose graph, one map, one report.

Input: the output folders of ``tripod reconstruct`` (one per recording: ``stations.tum``,
``fragments/``, ``pose_graph.g2o``, ``result.json``, ``config.yaml``). Each recording lives in
its own map frame (z up along gravity; its yaw is the IMU's heading reference at power-on, its
origin the first station), so between recordings only gravity is shared.

Steps, for every pair of recordings (A, B):

1. **hypotheses** T_A_B from the two recordings' maps (their stations' fragments at
   ``submap_voxel_m``): gravity-constrained global registration (FPFH + RANSAC over yaw and
   translation, :func:`registration.pairwise.register_global`), and when its hypothesis does
   not verify, plan-heightmap registration (:mod:`scene.heightmap_registration`; ~20x the
   cost);
1a. **the shortlist**: the global hypotheses of every pair come first; each recording keeps
   its ``shortlist_k`` best partners by the pair's overlap score (:func:`pair_score`), plus
   the recordings before and after it in capture time, and only those pairs go on to the
   steps below (they cost ~90 % of the merge and grow with the square of the recordings);
   a pair left out is counted in ``result.json`` and the report, never joined by its
   hypothesis (the proximity pass, 3a, may still link it);
2. **verification, like loop closures**: B's stations placed by a hypothesis; the station pairs
   whose fragments would overlap there (share of coarse points within ``overlap_distance_m``
   of the other, at least ``min_overlap``) are registered from that guess (coarse-to-fine
   GICP, then oriented point-to-plane), and a pair is a verified *link* when its fitness passes
   the odometry's ``min_fitness``, it stays within ``guess_radius_m`` / 5° of the guess
   (consistency) and neither station's points lie where the other saw through (free space,
   ``max_violation``). The best ``probe_links`` pairs are tried first; a hypothesis with fewer than
   ``min_links`` verified links is dropped (the recordings are not joined by it); the accepted
   one is then searched for every link (up to ``max_links_per_station`` per station and other
   recording);
2a. **turned twins**: a point-symmetric space (a rectangular hall with a grid of columns) fits
   its 180-deg-turned placement about as well, and the links of that twin verify too. So the
   accepted hypothesis is scored against its twins (turned 180, 90 and 270 deg about gravity,
   each found by a global registration restricted to that yaw, refined on the maps and verified
   the same way; score: the mean over the ``probe_links`` best candidate pairs of fitness -
   ``free_space_weight`` x free-space violation, 0 for a pair that does not verify): the best
   wins, and when the runner-up scores more than ``max_twin_ratio`` of it the pair is
   *ambiguous* and does not join the recordings (they may still join through other pairs).
   **Shifted twins** likewise: a repeated structure (doors along a corridor at a regular
   spacing) fits the hypothesis shifted by its period; the other optima of the maps' structure
   overlap along the overlap's principal horizontal axes are probed and scored the same way;
2b. **cycle consistency**: three joined recordings' hypotheses must compose to the identity;
   the pair in the most broken cycles (the weakest on a tie) is unjoined until none is broken;
3. **one pose graph** per group of joined recordings: every station a node (starting where the
   links put its recording), the recordings' own edges (their ``pose_graph.g2o``), the links
   (robust, rejectable like loops), IMU gravity priors; links the graph rejects are dropped;
3a. **the proximity pass** (loop closure by proximity, ``proximity_links``): every pair of
   recordings of one group without a kept link (left out by the shortlist, unjoined by the
   cycle check, ambiguous, no hypothesis) is searched from the T_A_B the optimised graph
   implies, with the same candidates and verification as step 2, each link also within
   ``guess_radius_m`` / 5 deg of the stations' merged relative pose; the links found are added
   and the group's graph optimised once more (``accepted == "proximity"``). Only pairs inside
   one group: two groups are never joined this way;
4. **outputs**: the largest group is the merged model (map, ``stations.tum`` with every
   station of it in lidar time, ``stations.csv``, ``links.csv``, ``pose_graph.g2o``,
   ``report.md``, ``result.json``, ``config.yaml``); a recording that links to nothing, or a
   group apart from the largest, is a separate component (``component-<k>/``), never forced in.
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pydantic import Field

from tripod_shared.config_io import StrictModel, dump_config

from ..registration import pose_graph as pg
from .config import ReconstructConfig
from .odometry import CloudCache, icp_refine, oriented_refine
from .outputs import read_tum, write_tum
from .slam import inv, optimize_graph


class MergeConfig(StrictModel):
    """How recordings are joined (``tripod batch --merge``; ``merge.*`` keys of ``--set``)."""

    #: voxel [m] of each recording's map for the hypotheses (global and heightmap registration)
    submap_voxel_m: float = Field(default=0.1, gt=0)
    #: voxel [m] of the gravity-constrained global registration (FPFH radius 5x, inliers 1.5x)
    global_voxel_m: float = Field(default=0.3, gt=0)
    #: hypotheses from plan-heightmap registration when the global one does not verify
    heightmaps: bool = True
    #: coarse voxel [m] of the predicted overlap between two stations' fragments
    overlap_voxel_m: float = Field(default=0.2, gt=0)
    #: a point overlaps when the other fragment has a point this close [m]
    overlap_distance_m: float = Field(default=0.2, gt=0)
    #: station pairs predicted to share at least this much (mean of both directions) are
    #: registered as link candidates
    min_overlap: float = Field(default=0.25, ge=0, le=1)
    #: station pairs farther apart than this [m] are never candidates
    max_link_distance_m: float = Field(default=20.0, gt=0)
    #: candidate pairs registered first to verify a hypothesis
    probe_links: int = Field(default=4, ge=1)
    #: verified links a hypothesis needs to join two recordings
    min_links: int = Field(default=2, ge=1)
    #: links kept per station and other recording at most (the best predicted overlaps)
    max_links_per_station: int = Field(default=4, ge=1)
    #: a link registered from the hypothesis' guess is consistent when it moves less than this
    #: [m] (and 5 deg)
    guess_radius_m: float = Field(default=0.3, gt=0)
    #: a link is rejected when more than this share of either station's points lies where the
    #: other saw through (free space; a room placed inside a bigger room fits its floor and
    #: ceiling, but its walls stand in the bigger room's free space)
    max_violation: float = Field(default=0.05, ge=0, le=1)
    #: check every accepted hypothesis against its turned twins (the hypothesis turned 180, 90
    #: and 270 deg about gravity, each found by a global registration restricted to that yaw
    #: and verified the same way): the best-scoring one wins, and the recordings are left
    #: unjoined by this pair when the runner-up scores more than ``max_twin_ratio`` of it
    twins: bool = True
    #: runner-up's score / the winner's above which a pair's hypothesis is ambiguous
    max_twin_ratio: float = Field(default=0.8, ge=0, le=1)
    #: a twin whose maps fit (the restricted global registration's fitness) below this share of
    #: the hypothesis' own is not probed (it cannot compete; saves its link registrations)
    twin_min_map_fit: float = Field(default=0.7, ge=0, le=1)
    #: translational twins: shifts of the hypothesis along its overlap's two principal
    #: horizontal axes to the other local optima of the maps' structure overlap (a corridor
    #: with doors at a regular spacing fits a placement shifted by that spacing); the
    #: ``twin_shifts`` best of those that fit at least ``twin_min_map_fit`` of the hypothesis'
    #: own are probed and scored like the turned twins (0: none)
    twin_shifts: int = Field(default=2, ge=0)
    #: the shifts searched: up to this far [m] either way along each axis
    twin_shift_max_m: float = Field(default=12.0, gt=0)
    #: weight of the free-space violation against the fitness in a link's score (fitness -
    #: weight x violation; a hypothesis scores the mean over its ``probe_links`` best candidates)
    free_space_weight: float = Field(default=10.0, ge=0)
    #: unjoin pairs whose hypotheses break cycles of three joined recordings (the composition
    #: off the identity by more than ``cycle_m`` [m] or ``cycle_deg`` [deg])
    cycle_check: bool = True
    cycle_m: float = Field(default=0.5, gt=0)
    cycle_deg: float = Field(default=3.0, gt=0)
    #: the shortlist of recording pairs: after the global hypotheses of every pair (the cheap
    #: step), each recording keeps its ``shortlist_k`` best partners by the pair's overlap
    #: score (:func:`pair_score`; a pair stays when either of its recordings keeps it), and
    #: only those pairs are verified, linked and twin-checked (the steps that cost ~90 % and
    #: grow with the square of the recordings). Buildings of <= k + 1 recordings keep every
    #: pair; 0: every pair. A pair left out is counted in result.json and the report (the
    #: proximity pass may still link it)
    shortlist_k: int = Field(default=4, ge=0)
    #: also keep the pairs of recordings adjacent in capture time (by their first station):
    #: a recording usually starts where the one before stopped; these may get the heightmap
    #: hypothesis when the global one found nothing (N - 1 pairs)
    shortlist_time_neighbours: bool = True
    #: the proximity pass (loop closure by proximity): once each component is placed and
    #: optimised, every pair of its recordings without a kept link (left out by the shortlist,
    #: unjoined by the cycle check, ambiguous, or no hypothesis) is searched for links from the
    #: transform the merged estimate implies between them (the same candidates, verification
    #: and free-space checks as a hypothesis'; a link must also agree with the merged estimate
    #: within ``guess_radius_m`` / 5 deg); the links found are added and the component's pose
    #: graph optimised once more. Never joins two components
    proximity_links: bool = True
    num_threads: int = Field(default=0, ge=0)


# ---- inputs -------------------------------------------------------------------------------------
@dataclass
class RecordingModel:
    """A reconstructed recording as the merge reads it back.

    t_ns : (N,) station times (lidar time); T : (N, 4, 4) T_rec_lidar (the recording's map);
    points : fragments, (M_k, 3) float32 in each station's lidar frame; edges : its own pose
    graph's edges (node = row of ``t_ns``); index : station index in the recording.
    """

    name: str
    outdir: Path
    t_ns: np.ndarray
    T: np.ndarray
    index: list[int]
    points: list[np.ndarray]
    edges: list[pg.Edge]
    config: ReconstructConfig
    notes: list[str] = field(default_factory=list)

    @property
    def up_in_lidar(self) -> np.ndarray:
        """(N, 3): the map's +z (gravity, from the recording's graph) in each station frame."""
        return self.T[:, 2, :3]


def read_g2o_edges(path: Path) -> list[pg.Edge]:
    """Edges of a pose graph written by :meth:`PoseGraph.save_g2o` (consecutive nodes are taken
    as odometry, others as loops)."""
    from scipy.spatial.transform import Rotation

    edges = []
    iu = np.triu_indices(6)
    for ln in path.read_text().splitlines():
        f = ln.split()
        if not f or f[0] != "EDGE_SE3:QUAT":
            continue
        i, j = int(f[1]), int(f[2])
        v = [float(x) for x in f[3:]]
        T = np.eye(4)
        T[:3, 3] = v[0:3]
        T[:3, :3] = Rotation.from_quat(v[3:7]).as_matrix()
        info = np.zeros((6, 6))
        info[iu] = v[7:28]
        info = info + np.triu(info, 1).T
        edges.append(pg.Edge(i, j, T, info, "odometry" if j == i + 1 else "loop"))
    return edges


def load_recording(outdir: str | os.PathLike, name: str | None = None,
                   fragment_voxel_m: float = 0.03) -> RecordingModel:
    """Read one ``tripod reconstruct`` output folder (the stations of its map; fragments
    voxel-filtered at ``fragment_voxel_m``). Raises ValueError (one line) when it is not one."""
    from tripod_shared.config_io import load_config

    from ..io import clouds as cloud_io
    from ..preprocess import voxel_downsample

    out = Path(outdir)
    name = name or out.name
    for f in ("result.json", "stations.tum", "pose_graph.g2o", "config.yaml"):
        if not (out / f).is_file():
            raise ValueError(f"{out}: no {f} (not a finished reconstruction)")
    res = json.loads((out / "result.json").read_text())
    t, T = read_tum(out / "stations.tum")
    off = set(int(k) for k in res.get("disconnected_stations", []))
    index = [k for k in range(int(res["stations"])) if k not in off]
    if len(index) != len(t):
        raise ValueError(f"{out}: stations.tum has {len(t)} stations, result.json {len(index)}")
    pts = []
    for k in index:
        f = out / "fragments" / f"station_{k:03d}.ply"
        if not f.is_file():
            raise ValueError(f"{out}: no fragment {f.name} (write_fragments was off?)")
        p = cloud_io.xyz(cloud_io.read_ply(f), dtype=np.float32)
        pts.append(voxel_downsample(np.ascontiguousarray(p), fragment_voxel_m, 1))
    cfg = load_config(ReconstructConfig, out / "config.yaml")
    notes = [f"{len(off)} station(s) disconnected inside the recording, left out"] if off else []
    return RecordingModel(name, out, t, T, index, pts, read_g2o_edges(out / "pose_graph.g2o"),
                          cfg, notes)


# ---- station pairs ------------------------------------------------------------------------------
class _Coarse:
    """Each station's fragment at the overlap voxel, with its k-d tree (built once), and its
    range image for the free-space test (built when first needed)."""

    def __init__(self, recs: list[RecordingModel], voxel: float):
        from scipy.spatial import cKDTree

        from ..preprocess import voxel_downsample

        self.recs = recs
        self.pts = [[voxel_downsample(p, voxel, 1).astype(np.float64) for p in r.points]
                    for r in recs]
        self.tree = [[cKDTree(p) for p in rp] for rp in self.pts]
        self._range: dict[tuple[int, int], np.ndarray] = {}
        # structure: the points off the floor and the ceiling (those overlap under any wrong
        # pose that keeps the heights), 25 cm from the 1st and 99th height percentiles
        self.struct = []
        for r, rp in zip(recs, self.pts):
            out = []
            for up, p in zip(r.up_in_lidar, rp):
                z = p @ up
                lo, hi = np.percentile(z, [1, 99]) if len(z) else (0.0, 0.0)
                out.append(p[(z > lo + 0.25) & (z < hi - 0.25)])
            self.struct.append(out)

    def overlap(self, a: tuple[int, int], b: tuple[int, int], T_a_b: np.ndarray,
                dist: float) -> float:
        """Mean of the shares of each fragment's points within ``dist`` of the other, with b
        placed in a's frame by ``T_a_b``."""
        pa, pb = self.pts[a[0]][a[1]], self.pts[b[0]][b[1]]
        if not len(pa) or not len(pb):
            return 0.0
        pb_a = pb @ T_a_b[:3, :3].T + T_a_b[:3, 3]
        da, _ = self.tree[a[0]][a[1]].query(pb_a, distance_upper_bound=dist)
        Ti = inv(T_a_b)
        pa_b = pa @ Ti[:3, :3].T + Ti[:3, 3]
        db, _ = self.tree[b[0]][b[1]].query(pa_b, distance_upper_bound=dist)
        return 0.5 * (float(np.isfinite(da).mean()) + float(np.isfinite(db).mean()))

    # -- free space: a station's nearest return per direction (1 deg bins around its origin)
    STEP_DEG = 1.0

    def _bins(self, P: np.ndarray):
        r = np.linalg.norm(P, axis=1)
        az = np.arctan2(P[:, 1], P[:, 0]) + np.pi
        el = np.arcsin(np.clip(P[:, 2] / np.maximum(r, 1e-9), -1, 1)) + np.pi / 2
        step = np.radians(self.STEP_DEG)
        i = np.minimum((az / step).astype(np.int64), int(round(360 / self.STEP_DEG)) - 1)
        j = np.minimum((el / step).astype(np.int64), int(round(180 / self.STEP_DEG)))
        return i, j, r

    def range_image(self, a: tuple[int, int]) -> np.ndarray:
        """(360, 181) float32: the nearest return [m] per 1° direction of station ``a``, eroded
        over the 3 x 3 neighbourhood (only space seen through in every neighbouring direction
        is free); inf where nothing returned."""
        if a not in self._range:
            from scipy import ndimage

            from ..preprocess import voxel_downsample

            P = voxel_downsample(self.recs[a[0]].points[a[1]], 0.05, 1).astype(np.float64)
            i, j, r = self._bins(P)
            img = np.full((int(round(360 / self.STEP_DEG)), int(round(180 / self.STEP_DEG)) + 1),
                          np.inf)
            np.minimum.at(img, (i, j), r)
            self._range[a] = ndimage.minimum_filter(img, size=3, mode="wrap").astype(np.float32)
        return self._range[a]

    def violation(self, a: tuple[int, int], b: tuple[int, int], T_a_b: np.ndarray) -> float:
        """Share of each fragment's structure (points off floor and ceiling) lying where the
        other station saw through (in front of its nearest return in that direction by more
        than 5 % + 10 cm), the mean of both directions: ~0 for a right pose; the walls of a
        room placed inside a bigger one stand in its free space."""
        def share(P, img):
            if not len(P):
                return 0.0
            i, j, r = self._bins(P)
            lim = img[i, j]
            return float((np.isfinite(lim) & (r < 0.95 * lim - 0.10)).mean())

        pb_a = self.struct[b[0]][b[1]] @ T_a_b[:3, :3].T + T_a_b[:3, 3]
        Ti = inv(T_a_b)
        pa_b = self.struct[a[0]][a[1]] @ Ti[:3, :3].T + Ti[:3, 3]
        return 0.5 * (share(pb_a, self.range_image(a)) + share(pa_b, self.range_image(b)))


def candidate_pairs(recs, coarse: _Coarse, A: int, B: int, T_A_B: np.ndarray,
                    cfg: MergeConfig) -> list[tuple[float, int, int]]:
    """(predicted overlap, a, b) of the station pairs of recordings A and B that overlap with
    B placed by ``T_A_B``, best first, at most ``max_links_per_station`` per station."""
    TA = recs[A].T
    TB = T_A_B @ recs[B].T
    d = np.linalg.norm(TA[:, None, :3, 3] - TB[None, :, :3, 3], axis=2)
    out = []
    for a, b in zip(*np.nonzero(d < cfg.max_link_distance_m)):
        ov = coarse.overlap((A, int(a)), (B, int(b)), inv(TA[a]) @ TB[b], cfg.overlap_distance_m)
        if ov >= cfg.min_overlap:
            out.append((ov, int(a), int(b)))
    out.sort(reverse=True)
    per_a: dict[int, int] = {}
    per_b: dict[int, int] = {}
    kept = []
    for ov, a, b in out:
        if per_a.get(a, 0) < cfg.max_links_per_station and per_b.get(b, 0) < \
                cfg.max_links_per_station:
            kept.append((ov, a, b))
            per_a[a] = per_a.get(a, 0) + 1
            per_b[b] = per_b.get(b, 0) + 1
    return kept


@dataclass
class Link:
    """A verified link between station ``a`` of recording ``A`` and station ``b`` of ``B``:
    T_a_b (b's lidar frame in a's), with the registration's information and quality."""

    A: int
    a: int
    B: int
    b: int
    T_a_b: np.ndarray
    information: np.ndarray
    fitness: float
    rmse: float
    predicted_overlap: float
    source: str = ""
    kept: bool = True


def verify_link(recs, cache: CloudCache, coarse: _Coarse, A: int, a: int, B: int, b: int,
                T_A_B: np.ndarray, mcfg: MergeConfig
                ) -> tuple[bool, np.ndarray, np.ndarray, float, float, float]:
    """Register station b onto station a from the hypothesis' guess; (verified, T_a_b,
    information, fitness, rmse, free-space violation (1 when not computed)): fit
    (``min_fitness``), consistent with the guess, and free space respected
    (``max_violation``)."""
    ocfg = recs[A].config.odometry
    TA, TB = recs[A].T[a], T_A_B @ recs[B].T[b]
    guess = inv(TA) @ TB
    R_prior = guess[:3, :3]
    src, tgt = recs[B].points[b], recs[A].points[a]
    keys = ((B, b), (A, a))
    r = icp_refine(src, tgt, guess, ocfg, mcfg.num_threads, None, cache, keys, R_prior)
    if not r.ok or not _close(guess, r.T_target_source, mcfg.guess_radius_m, 5.0):
        return False, r.T_target_source, r.information, r.fitness, r.rmse, 1.0
    T, info, fit, rmse = r.T_target_source, r.information, r.fitness, r.rmse
    if ocfg.oriented_refine:
        T2, info2, fit2, rmse2 = oriented_refine(src, tgt, T, ocfg, mcfg.num_threads,
                                                 cache=cache, keys=keys)
        if np.linalg.norm((inv(T) @ T2)[:3, 3]) < 0.3 and fit2 > 0.5 * fit:
            from .odometry import _cap_information

            T, info, rmse = T2, _cap_information(info2, ocfg), rmse2
    viol = coarse.violation((A, a), (B, b), T)
    ok = _close(guess, T, mcfg.guess_radius_m, 5.0) and viol <= mcfg.max_violation
    return ok, T, info, fit, rmse, viol


def _close(A: np.ndarray, B: np.ndarray, m: float, deg: float) -> bool:
    D = inv(A) @ B
    ang = np.degrees(np.arccos(np.clip((np.trace(D[:3, :3]) - 1) / 2, -1, 1)))
    return bool(np.linalg.norm(D[:3, 3]) < m and ang < deg)


# ---- hypotheses ---------------------------------------------------------------------------------
def submap(rec: RecordingModel, voxel: float, num_threads: int = 0) -> np.ndarray:
    """The recording's stations' fragments in its map frame, voxel-filtered (float32 (N, 3))."""
    from ..preprocess import voxel_downsample

    parts = []
    for T, p in zip(rec.T, rec.points):
        q = voxel_downsample(p, voxel, num_threads)
        parts.append((q @ T[:3, :3].T.astype(np.float32)) + T[:3, 3].astype(np.float32))
    allp = np.concatenate(parts) if parts else np.zeros((0, 3), np.float32)
    return voxel_downsample(allp, voxel, num_threads) if len(allp) else allp


def global_hypothesis(map_A: np.ndarray, map_B: np.ndarray, cfg: MergeConfig
                      ) -> tuple[str, np.ndarray, float] | None:
    """(source, T_A_B, fitness) from gravity-constrained global registration of map B onto
    map A (both z up): FPFH features and RANSAC over yaw and translation; None without one."""
    from ..registration import pairwise as reg

    if len(map_A) < 100 or len(map_B) < 100:
        return None
    # twin_check off: the merge judges a hypothesis' turned twins on its own, by verified
    # station links (resolve_twins), stronger evidence than the maps' refined fit
    g = reg.register_global(map_B, map_A, voxel_size=cfg.global_voxel_m, gravity_aligned=True,
                            seed=0, num_threads=cfg.num_threads, twin_check=False)
    return ("global", g.T_target_source, float(g.fitness)) if g.success else None


def heightmap_hypothesis(map_A: np.ndarray, map_B: np.ndarray, labels_A, labels_B,
                         cfg: MergeConfig) -> tuple[str, np.ndarray, float] | None:
    """(source, T_A_B, structure fitness) from plan-heightmap registration of map B onto map A
    (a lighter search than ``tripod register``'s: 12 candidates, 3 verified); None when the
    maps cannot be levelled or matched."""
    from ..scene.heightmap_registration import register_by_heightmaps

    if labels_A is None or labels_B is None or len(map_A) < 100 or len(map_B) < 100:
        return None
    try:
        h = register_by_heightmaps(map_B, map_A, source_labels=labels_B, target_labels=labels_A,
                                   candidates=12, verify=3, num_threads=cfg.num_threads,
                                   twins=False)  # the merge checks the twins of its own
    except ValueError:
        return None  # too little structure to level or match
    return ("heightmap", h.T_target_source, float(h.structure_fitness))


# ---- the shortlist of recording pairs ----------------------------------------------------------
def pair_score(hyp: tuple[str, np.ndarray, float] | None, n_A: int, n_B: int) -> float:
    """How much two recordings share, from their global hypothesis (map B onto map A): the
    matched share of B's map (the registration's fitness) x |B| / min(|A|, |B|), i.e. the
    share of the smaller map that overlaps the other (in [0, 1]; 0 without a hypothesis).
    Symmetric in the sense that matters: a small recording inside a large one scores high
    whichever is the source."""
    if hyp is None or n_A <= 0 or n_B <= 0:
        return 0.0
    return float(min(1.0, max(0.0, hyp[2]) * n_B / min(n_A, n_B)))


def shortlist_pairs(n: int, scores: dict[tuple[int, int], float], k: int,
                    start_ns: list[int] | None = None) -> set[tuple[int, int]]:
    """The recording pairs (A < B) kept for verification: every recording's ``k`` best partners
    by ``scores[(A, B)]`` (a pair is kept when either of its recordings ranks it among its k;
    ties broken by the partners' distance in capture order, then by index, so the result does
    not depend on the order of ``scores``), plus, when ``start_ns`` (each recording's start,
    ns) is given, the pairs of recordings adjacent in capture time. Pairs missing from
    ``scores`` score 0. ``k`` = 0, or ``k`` >= n - 1: every pair."""
    every = {(A, B) for A in range(n) for B in range(A + 1, n)}
    if k <= 0 or k >= n - 1:
        return every
    order = (sorted(range(n), key=lambda r: (start_ns[r], r)) if start_ns is not None
             else list(range(n)))
    rank = {r: i for i, r in enumerate(order)}
    keep: set[tuple[int, int]] = set()
    for A in range(n):
        partners = [B for B in range(n) if B != A]
        partners.sort(key=lambda B: (-scores.get((min(A, B), max(A, B)), 0.0),
                                     abs(rank[A] - rank[B]), B))
        keep |= {(min(A, B), max(A, B)) for B in partners[:k]}
    if start_ns is not None:
        keep |= {(min(a, b), max(a, b)) for a, b in zip(order, order[1:])}
    return keep


# ---- links of a hypothesis, and its turned twins ---------------------------------------------
def all_links(recs, cache, coarse, A: int, B: int, H: np.ndarray, src: str, cfg: MergeConfig,
              limit: int | None = None) -> tuple[list[Link], list[float]]:
    """Every candidate station pair of ``H`` registered (the ``limit`` best only, when given):
    (verified links, quality of each candidate in order (best predicted overlap first):
    fitness - ``free_space_weight`` x violation when verified, else 0)."""
    found, quality = [], []
    for ov, a, b in candidate_pairs(recs, coarse, A, B, H, cfg)[:limit]:
        ok, T, info, fit, rmse, viol = verify_link(recs, cache, coarse, A, a, B, b, H, cfg)
        quality.append(fit - cfg.free_space_weight * viol if ok else 0.0)
        if ok:
            found.append(Link(A, a, B, b, T, info, fit, rmse, ov, src))
    return found, quality


def hypothesis_score(quality: list[float], cfg: MergeConfig) -> float:
    """A hypothesis' score: the mean quality of its ``probe_links`` best candidates (a missing
    or unverified candidate counts 0)."""
    q = list(quality[: cfg.probe_links]) + [0.0] * max(0, cfg.probe_links - len(quality))
    return float(np.mean(q))


#: turns about gravity that give a hypothesis' twins (a rectangle's 180 deg, a square's 90/270)
TWIN_TURNS_DEG = (180.0, 90.0, 270.0)


def _about_z(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def refine_on_maps(map_A: np.ndarray, map_B: np.ndarray, H: np.ndarray, cfg: MergeConfig
                   ) -> np.ndarray:
    """A global registration's T_A_B refined by point-to-plane ICP of map B onto map A
    (correspondences 0.6 -> 0.3 -> 0.15 m; the global guess is only as good as its 0.3 m voxel);
    kept as it was when ICP fails or tips it over by more than 2 deg."""
    from ..registration import pairwise as reg

    try:
        r = reg.register(map_B, map_A, "plane", init=np.ascontiguousarray(H),
                         voxel_size=cfg.submap_voxel_m,
                         max_correspondence_distance=[0.6, 0.3, 0.15], max_iterations=20,
                         num_threads=cfg.num_threads)
    except ValueError:
        return H
    T = r.T_target_source
    tilt = np.degrees(np.arccos(np.clip((T[:3, :3] @ H[:3, :3].T)[2, 2], -1, 1)))
    return T if tilt < 2.0 else H


#: the grid [m] of the structure overlap that finds translational twins, and its shift step [m]
SHIFT_VOXEL_M = 0.2
SHIFT_STEP_M = 0.1


def _structure(P: np.ndarray) -> np.ndarray:
    """The points of a z-up map off its floor and ceiling (25 cm from the 1st and 99th height
    percentiles): a floor and a ceiling overlap under any horizontal shift."""
    if not len(P):
        return P
    lo, hi = np.percentile(P[:, 2], [1, 99])
    return P[(P[:, 2] > lo + 0.25) & (P[:, 2] < hi - 0.25)]


def shift_twins(map_A: np.ndarray, map_B: np.ndarray, H: np.ndarray, cfg: MergeConfig
                ) -> list[tuple[str, np.ndarray, float]]:
    """Translational twins of the hypothesis ``H`` (T_A_B; both maps z up, (N, 3) [m]): a
    repeated structure (doors along a corridor at a regular spacing) fits B shifted by its
    period about as well. B's structure (off floor and ceiling) placed by H is shifted along
    each principal horizontal axis of its overlap with A's, in ``SHIFT_STEP_M`` steps up to
    ``twin_shift_max_m`` either way; the score of a shift is the share of B's structure points
    in a cell of A's (a ``SHIFT_VOXEL_M`` grid dilated by one cell). Its local maxima (over
    ±0.5 m) at least 1 m from H, parted from H's peak by a dip (below 0.95 of their score) and
    scoring at least ``twin_min_map_fit`` of H's own, best first, at most ``twin_shifts``:
    [(label "+4.1 m@87°" (shift along the axis of that yaw in A's frame), H shifted, score /
    H's score)]."""
    from scipy import ndimage

    from ..preprocess import voxel_downsample

    v = SHIFT_VOXEL_M
    if cfg.twin_shifts <= 0 or len(map_A) < 100 or len(map_B) < 100:
        return []
    a = _structure(voxel_downsample(np.ascontiguousarray(map_A, dtype=np.float32), v, 1)
                   .astype(np.float64))
    b = _structure(voxel_downsample(np.ascontiguousarray(map_B, dtype=np.float32), v, 1)
                   .astype(np.float64))
    if len(a) < 100 or len(b) < 100:
        return []
    b = b @ H[:3, :3].T + H[:3, 3]
    lo = a.min(axis=0) - 2 * v
    k = np.floor((a - lo) / v).astype(np.int64)
    shape = k.max(axis=0) + 3
    grid = np.zeros(shape, dtype=bool)
    grid[tuple(k.T)] = True
    grid = ndimage.binary_dilation(grid, np.ones((3, 3, 3), dtype=bool))

    def hits(P: np.ndarray) -> np.ndarray:
        q = np.floor((P - lo) / v).astype(np.int64)
        inside = ((q >= 0) & (q < shape)).all(axis=1)
        out = np.zeros(len(P), dtype=bool)
        out[inside] = grid[tuple(q[inside].T)]
        return out

    h0 = hits(b)
    if h0.sum() < 50:
        return []
    ov = b[h0, :2]
    _, V = np.linalg.eigh(np.cov((ov - ov.mean(axis=0)).T))
    s = np.arange(-cfg.twin_shift_max_m, cfg.twin_shift_max_m + 1e-9, SHIFT_STEP_M)
    w = int(round(0.5 / SHIFT_STEP_M))
    found = []
    for u in (V[:, 1], V[:, 0]):  # the major axis first (along a corridor)
        f = np.array([hits(b + np.array([x * u[0], x * u[1], 0.0])).mean() for x in s])
        near = np.abs(s) < 0.5
        f0 = float(f[near].max())
        if f0 <= 0:
            continue
        i0 = int(np.flatnonzero(near)[np.argmax(f[near])])
        for i in range(len(s)):
            if abs(s[i]) < 1.0 or f[i] < cfg.twin_min_map_fit * f0:
                continue
            if f[i] < f[max(0, i - w): i + w + 1].max():
                continue  # not a local maximum
            between = f[min(i, i0): max(i, i0) + 1]
            if between.min() >= 0.95 * f[i]:
                continue  # H's own peak, widened: no dip between them
            H2 = H.copy()
            H2[:2, 3] += s[i] * u
            yaw = np.degrees(np.arctan2(u[1], u[0]))
            found.append((f"{s[i]:+.1f} m@{yaw:.0f}°", H2, float(f[i] / f0)))
    found.sort(key=lambda c: -c[2])
    return found[: cfg.twin_shifts]


def resolve_twins(recs, cache, coarse, maps, A: int, B: int, H: np.ndarray, src: str,
                  found: list[Link], quality: list[float], cfg: MergeConfig):
    """The accepted hypothesis ``H`` (its links ``found``, candidate ``quality``) against its
    turned twins: for each turn of :data:`TWIN_TURNS_DEG`, the gravity-constrained global
    registration of the two maps restricted to yaws within 30 deg of H's turned by it; a twin
    whose maps fit at least ``twin_min_map_fit`` of H's own (the same restricted registration
    about H's yaw) and distinct from H is refined by ICP on the maps, its ``probe_links`` best
    candidates registered like H's, and scored by :func:`hypothesis_score`; then its
    translational twins (:func:`shift_twins`: H shifted along a repeated structure), refined,
    probed and scored the same way. Returns (T_A_B, links, info): the best-scoring hypothesis
    and its links (a twin that wins is refined by its best link and all its links searched);
    ``info["scores"]``: {"0" (H), turn deg, or shift label: score}; ``info["ambiguous"]``
    when the runner-up scores more than ``max_twin_ratio`` of the winner (or the winner scores
    <= 0)."""
    from ..registration import pairwise as reg

    cands = [("0", H, found, hypothesis_score(quality, cfg))]
    if len(maps[A]) >= 100 and len(maps[B]) >= 100:
        def restricted(turn: float):
            return reg.register_global(maps[B], maps[A], voxel_size=cfg.global_voxel_m,
                                       gravity_aligned=True, seed=0, num_threads=cfg.num_threads,
                                       twin_check=False,
                                       rotation_prior=_about_z(turn) @ H[:3, :3],
                                       rotation_tolerance=np.radians(30.0))

        ref = restricted(0.0)  # the hypothesis' own fit of the maps: its twins' yardstick
        ref_fit = float(ref.fitness) if ref.success else 0.0
        for turn in TWIN_TURNS_DEG:
            g = restricted(turn)
            if not g.success or g.fitness < cfg.twin_min_map_fit * ref_fit:
                continue  # its maps fit much worse than the hypothesis': no contender
            H2 = refine_on_maps(maps[A], maps[B], g.T_target_source, cfg)
            if any(_close(c[1], H2, 1.0, 20.0) for c in cands):
                continue
            # probed and scored on its best candidates; all its links searched if it wins
            probes, q2 = all_links(recs, cache, coarse, A, B, H2, src, cfg, cfg.probe_links)
            cands.append((f"{turn:.0f}", H2, probes, hypothesis_score(q2, cfg)))
        # translational twins: H shifted along a repeated structure to its other optima
        for label, H2, _fit in shift_twins(maps[A], maps[B], H, cfg):
            H2 = refine_on_maps(maps[A], maps[B], H2, cfg)
            if any(_close(c[1], H2, 1.0, 20.0) for c in cands):
                continue
            probes, q2 = all_links(recs, cache, coarse, A, B, H2, src, cfg, cfg.probe_links)
            cands.append((label, H2, probes, hypothesis_score(q2, cfg)))
    order = sorted(range(len(cands)), key=lambda k: -cands[k][3])
    win = cands[order[0]]
    runner = max((cands[k][3] for k in order[1:]), default=0.0)
    ratio = 1.0 if win[3] <= 0 else max(0.0, runner) / win[3]
    info = {"scores": {c[0]: round(c[3], 4) for c in cands},
            "winner": win[0], "ratio": round(float(ratio), 4),
            "ambiguous": bool(ratio > cfg.max_twin_ratio)}
    H_win, links = win[1], win[2]
    if order[0] != 0 and not info["ambiguous"] and links:
        # a twin won: refined by its best link, then every link searched, as for a hypothesis
        top = max(links, key=lambda lk: lk.fitness)
        H_win = recs[A].T[top.a] @ top.T_a_b @ inv(recs[B].T[top.b])
        links = all_links(recs, cache, coarse, A, B, H_win, src, cfg)[0]
    return H_win, links, info


def check_hypothesis(recs, cache, coarse, maps, A: int, B: int, H: np.ndarray, src: str,
                     cfg: MergeConfig, times: dict | None = None
                     ) -> tuple[np.ndarray, list[Link], dict]:
    """A verified hypothesis ``H`` (T_A_B) of recordings A and B: every link searched from it,
    then (``cfg.twins``) judged against its turned and shifted twins (:func:`resolve_twins`).
    Returns (T_A_B, links, twin info); no links when the pair is ambiguous."""
    times = {} if times is None else times
    with _Timer(times, "links"):
        found, quality = all_links(recs, cache, coarse, A, B, H, src, cfg)
    info: dict = {}
    if len(found) >= cfg.min_links and cfg.twins:
        # the hypothesis against its twins: the best wins by a clear margin, or the pair
        # stays unjoined (a symmetric or repeated space seen from both recordings)
        with _Timer(times, "twins"):
            H, found, info = resolve_twins(recs, cache, coarse, maps, A, B, H, src, found,
                                           quality, cfg)
        if info.get("ambiguous"):
            found = []
    return H, found, info


def drop_inconsistent(accepted: dict, outcomes: dict, cfg: MergeConfig) -> list:
    """Pairs to unjoin so that every cycle of three joined recordings composes to the identity
    (within ``cycle_m`` and ``cycle_deg``): greedily, the pair in the most broken cycles, on a
    tie the lowest-scoring one (its twin check's winning score, else its link count)."""
    acc = dict(accepted)
    nodes = sorted({r for ab in acc for r in ab})

    def H(a, b):
        return acc[(a, b)] if (a, b) in acc else inv(acc[(b, a)]) if (b, a) in acc else None

    def score(ab):
        po = outcomes.get(ab)
        if po is None:
            return 0.0
        sc = po.twin.get("scores", {}).get(po.twin.get("winner", ""), None)
        return float(sc) if sc is not None else float(po.links)

    dropped = []
    while True:
        broken: dict[tuple[int, int], int] = {}
        for i, a in enumerate(nodes):
            for j, b in enumerate(nodes[i + 1:], i + 1):
                for c in nodes[j + 1:]:
                    hab, hbc, hac = H(a, b), H(b, c), H(a, c)
                    if hab is None or hbc is None or hac is None:
                        continue
                    if not _close(hab @ hbc, hac, cfg.cycle_m, cfg.cycle_deg):
                        for ab in ((a, b), (b, c), (a, c)):
                            broken[ab] = broken.get(ab, 0) + 1
        if not broken:
            return dropped
        worst = max(broken, key=lambda ab: (broken[ab], -score(ab)))
        dropped.append(worst)
        del acc[worst]


# ---- the merge ----------------------------------------------------------------------------------
@dataclass
class PairOutcome:
    """What was tried between two recordings."""

    A: int
    B: int
    tried: list[tuple[str, int, int]]  # (source, candidates, verified probes) per hypothesis
    accepted: str = ""  # the hypothesis that joined them ("" none)
    links: int = 0
    #: the twin check: {"scores": {turn deg: score}, "winner": turn, "ratio": runner-up /
    #: winner, "ambiguous": bool}
    twin: dict = field(default_factory=dict)
    #: the hypothesis T_A_B that came out of the pair's checks (None when none verified)
    T_A_B: np.ndarray | None = None
    #: the shortlist: the pair's score (:func:`pair_score`) and whether it was kept (a pair
    #: left out is neither verified nor joined)
    score: float = 0.0
    shortlisted: bool = True
    #: the proximity pass, when it searched the pair: {"candidates": station pairs,
    #: "verified": links verified and agreeing with the merged estimate, "kept": those the
    #: re-optimised graph kept}; a pair it joined has ``accepted == "proximity"``
    proximity: dict = field(default_factory=dict)


@dataclass
class MergeResult:
    outdir: Path
    recordings: list[RecordingModel]
    component: np.ndarray  # (R,) component of each recording; 0 the merged model
    T_world_station: list[np.ndarray]  # per recording (N_r, 4, 4), in its component's frame
    links: list[Link]
    pairs: list[PairOutcome]
    graph_converged: dict[int, bool]
    stage_s: dict[str, float]
    notes: list[str]
    files: dict[str, str] = field(default_factory=dict)

    def stations_of(self, comp: int) -> list[tuple[int, int]]:
        """(recording, station row) of every station of a component."""
        return [(r, k) for r in np.flatnonzero(self.component == comp)
                for k in range(len(self.recordings[r].t_ns))]


class _Timer:
    """Wall time of a stage into ``times[name]``, CPU time (all threads) into
    ``times["_cpu"][name]``."""

    def __init__(self, times: dict, name: str):
        self.times, self.name = times, name

    def __enter__(self):
        self.t0, self.c0 = time.perf_counter(), time.process_time()

    def __exit__(self, *exc):
        self.times[self.name] = self.times.get(self.name, 0.0) + time.perf_counter() - self.t0
        cpu = self.times.setdefault("_cpu", {})
        cpu[self.name] = cpu.get(self.name, 0.0) + time.process_time() - self.c0


def merge_recordings(outdirs: list, outdir: str | os.PathLike, cfg: MergeConfig | None = None,
                     names: list[str] | None = None, progress=None) -> MergeResult:
    """Join reconstructed recordings into one model in ``outdir`` (see the module docstring).

    ``outdirs``: ``tripod reconstruct`` output folders; ``progress(step, done, total)`` is
    called as the pairs and links are worked through.
    """
    cfg = cfg or MergeConfig()
    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    times: dict[str, float] = {}
    notes: list[str] = []
    with _Timer(times, "read"):
        recs = [load_recording(d, (names or [None] * len(outdirs))[i])
                for i, d in enumerate(outdirs)]
    for r in recs:
        notes += [f"{r.name}: {n}" for n in r.notes]
    nrec = len(recs)
    ocfg = recs[0].config.odometry if recs else ReconstructConfig().odometry
    cache = CloudCache(ocfg.point_sigma_m, cfg.num_threads)
    with _Timer(times, "submaps"):
        coarse = _Coarse(recs, cfg.overlap_voxel_m)
        maps = [submap(r, cfg.submap_voxel_m, cfg.num_threads) for r in recs]
        labels: list = [None] * nrec  # segmented when a heightmap registration needs them

    # 1. the global hypothesis of every pair of recordings (the cheap step), then the shortlist
    #    of the pairs that go on to verification, links and twins
    pairs: list[PairOutcome] = []
    links: list[Link] = []
    accepted: dict[tuple[int, int], np.ndarray] = {}
    todo = [(A, B) for A in range(nrec) for B in range(A + 1, nrec)]
    glob: dict[tuple[int, int], tuple | None] = {}
    for n_done, (A, B) in enumerate(todo):
        with _Timer(times, "hypotheses"):
            glob[(A, B)] = global_hypothesis(maps[A], maps[B], cfg)
        if progress is not None:
            progress("hypotheses", n_done + 1, len(todo))
    scores = {(A, B): pair_score(glob[(A, B)], len(maps[A]), len(maps[B])) for A, B in todo}
    start_ns = [int(r.t_ns.min()) if len(r.t_ns) else 0 for r in recs]
    keep = shortlist_pairs(nrec, scores, cfg.shortlist_k,
                           start_ns if cfg.shortlist_time_neighbours else None)
    if len(keep) < len(todo):
        notes.append(f"shortlist (k = {cfg.shortlist_k}): {len(todo) - len(keep)} of "
                     f"{len(todo)} recording pairs left out (not verified, not joined)")

    # 2. the shortlisted pairs' hypotheses verified, linked, twin-checked
    for n_done, (A, B) in enumerate(todo):
        po = PairOutcome(A, B, [], score=scores[(A, B)], shortlisted=(A, B) in keep)
        if not po.shortlisted:
            pairs.append(po)
            if progress is not None:
                progress("pairs", n_done + 1, len(todo))
            continue
        best = None
        # global registration first; the heightmaps only when it joins nothing (they cost ~20x)
        for source in ("global", "heightmap"):
            if best is not None or (source == "heightmap" and not cfg.heightmaps):
                break
            if source == "global":
                hyp = glob[(A, B)]
            else:
                with _Timer(times, "hypotheses"):
                    for r in (A, B):
                        if labels[r] is None and len(maps[r]):
                            labels[r] = _labels([maps[r]], cfg.num_threads)[0]
                    hyp = heightmap_hypothesis(maps[A], maps[B], labels[A], labels[B], cfg)
            if hyp is None:
                po.tried.append((source, 0, 0))
                continue
            src, H, _score = hyp
            with _Timer(times, "verify"):
                cands = candidate_pairs(recs, coarse, A, B, H, cfg)
                got = []
                for ov, a, b in cands[: cfg.probe_links]:
                    ok, T, info, fit, rmse, _ = verify_link(recs, cache, coarse, A, a, B, b, H,
                                                            cfg)
                    if ok:
                        got.append(Link(A, a, B, b, T, info, fit, rmse, ov, src))
            po.tried.append((src, len(cands), len(got)))
            if len(got) >= min(cfg.min_links, cfg.probe_links):
                best = (src, H, got, cands)
        if best is not None:
            src, H, got, cands = best
            # the hypothesis refined by its best link, then every link searched from it
            top = max(got, key=lambda lk: lk.fitness)
            H = recs[A].T[top.a] @ top.T_a_b @ inv(recs[B].T[top.b])
            H, found, po.twin = check_hypothesis(recs, cache, coarse, maps, A, B, H, src, cfg,
                                                 times)
            po.T_A_B = H
            if len(found) >= cfg.min_links:
                po.accepted, po.links = src, len(found)
                accepted[(A, B)] = H
                links += found
        pairs.append(po)
        if progress is not None:
            progress("pairs", n_done + 1, len(todo))

    # 2b. cycle consistency: three joined recordings must compose to the identity; the pair in
    #     the most broken cycles (the weakest on a tie) is unjoined until none is left
    if cfg.cycle_check:
        for (A, B) in drop_inconsistent(accepted, {(p.A, p.B): p for p in pairs}, cfg):
            del accepted[(A, B)]
            links = [lk for lk in links if (lk.A, lk.B) != (A, B)]
            po = next(p for p in pairs if (p.A, p.B) == (A, B))
            po.accepted, po.links = "", 0
            po.twin["cycle"] = "inconsistent"
            notes.append(f"{recs[A].name} - {recs[B].name}: joined by a hypothesis that breaks "
                         f"cycles with other recordings: left unjoined")

    # 3. components (union of joined recordings) and one pose graph each
    comp_raw = _components(nrec, accepted)
    sizes = {c: sum(len(recs[r].t_ns) for r in range(nrec) if comp_raw[r] == c)
             for c in set(comp_raw)}
    order = sorted(sizes, key=lambda c: (-sizes[c], min(np.flatnonzero(comp_raw == c))))
    component = np.array([order.index(c) for c in comp_raw], dtype=int)
    T_ws: list[np.ndarray] = [r.T.copy() for r in recs]
    converged: dict[int, bool] = {}
    graphs: dict[int, tuple] = {}
    scfg = recs[0].config.slam if recs else ReconstructConfig().slam
    with _Timer(times, "pose graph"):
        for c in range(len(order)):
            members = [int(r) for r in np.flatnonzero(component == c)]
            T_rec = _place_recordings(members, accepted)
            res = _optimize(recs, members, T_rec, [lk for lk in links if lk.A in members],
                            scfg, cfg.num_threads)
            for r in members:
                T_ws[r] = res[0][r]
            converged[c] = res[1]
            graphs[c] = res[2]
    # 3a. the proximity pass: pairs of recordings inside one component without a kept link,
    #     searched from the transform the merged estimate implies between them
    if cfg.proximity_links:
        with _Timer(times, "proximity"):
            for c in range(len(order)):
                members = [int(r) for r in np.flatnonzero(component == c)]
                if len(members) < 2:
                    continue
                found = proximity_pass(recs, cache, coarse, members, T_ws, links, pairs, cfg)
                if not found:
                    continue
                links += found
                res = _optimize(recs, members, None, [lk for lk in links if lk.A in members],
                                scfg, cfg.num_threads, init={r: T_ws[r] for r in members})
                for r in members:
                    T_ws[r] = res[0][r]
                converged[c] = res[1]
                graphs[c] = res[2]
            for po in pairs:
                if not po.proximity:
                    continue
                po.proximity["kept"] = sum(lk.kept for lk in links if (lk.A, lk.B) ==
                                           (po.A, po.B) and lk.source == "proximity")
                if po.proximity["kept"]:
                    po.accepted = "proximity"
                    notes.append(f"{recs[po.A].name} - {recs[po.B].name}: joined by proximity "
                                 f"({po.proximity['kept']} links from the merged estimate)")
    for po in pairs:
        if not po.accepted:
            continue
        po.links = sum(lk.kept for lk in links if (lk.A, lk.B) == (po.A, po.B))
    for r in range(nrec):
        if component[r] != 0 and sum(component == component[r]) == 1:
            notes.append(f"{recs[r].name} links to no other recording: a separate component")
    mres = MergeResult(out, recs, component, T_ws, links, pairs, converged, times, notes)

    # 4. outputs
    with _Timer(times, "outputs"):
        _write_outputs(mres, graphs, cfg)
    return mres


def implied_transform(T_rec: np.ndarray, T_comp: np.ndarray) -> np.ndarray:
    """T_component_recording that best maps a recording's stations (``T_rec``, (N, 4, 4) in its
    own map) onto where the merged graph put them (``T_comp``, (N, 4, 4)): the rotation the mean
    of the stations' (projected onto SO(3)), the translation the least-squares one of their
    positions under it."""
    M = np.einsum("nij,nkj->ik", T_comp[:, :3, :3], T_rec[:, :3, :3])  # sum R_comp R_rec^T
    U, _, Vt = np.linalg.svd(M)
    R = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    out = np.eye(4)
    out[:3, :3] = R
    out[:3, 3] = (T_comp[:, :3, 3] - T_rec[:, :3, 3] @ R.T).mean(axis=0)
    return out


def proximity_pass(recs, cache, coarse, members: list[int], T_ws: list[np.ndarray],
                   links: list[Link], pairs: list[PairOutcome], cfg: MergeConfig
                   ) -> list[Link]:
    """Loop closure by proximity inside one placed, optimised component (its ``members``,
    their stations at ``T_ws[r]`` in the component's frame): for every pair of members without
    a kept link, H = the T_A_B the merged estimate implies (:func:`implied_transform` of each);
    its candidate station pairs (:func:`candidate_pairs`) registered and verified like a
    hypothesis' (:func:`verify_link`: fitness, within ``guess_radius_m`` / 5 deg of H's guess,
    free space), the ``probe_links`` best first (none verified: the pair is left); a link is
    kept only when it also agrees with the two stations' merged relative pose (the same
    tolerance). Returns the new links (source ``"proximity"``); records each searched pair's
    counts in ``PairOutcome.proximity``."""
    by_pair = {(p.A, p.B): p for p in pairs}
    T_c = {r: implied_transform(recs[r].T, T_ws[r]) for r in members}
    out: list[Link] = []
    for i, A in enumerate(members):
        for B in members[i + 1:]:
            if any(lk.kept and (lk.A, lk.B) == (A, B) for lk in links):
                continue
            H = inv(T_c[A]) @ T_c[B]
            cands = candidate_pairs(recs, coarse, A, B, H, cfg)
            got = []
            for n, (ov, a, b) in enumerate(cands):
                if n == cfg.probe_links and not got:
                    break  # none of the best candidates verifies: the estimate is off here
                ok, T, info, fit, rmse, _ = verify_link(recs, cache, coarse, A, a, B, b, H, cfg)
                merged = inv(T_ws[A][a]) @ T_ws[B][b]
                if ok and _close(merged, T, cfg.guess_radius_m, 5.0):
                    got.append(Link(A, a, B, b, T, info, fit, rmse, ov, "proximity"))
            po = by_pair.get((A, B))
            if po is not None:
                po.proximity = {"candidates": len(cands), "verified": len(got), "kept": 0}
            out += got
    return out


def _labels(maps, num_threads):
    """Segmentation labels of each map for the heightmap registration (None where it fails)."""
    try:
        from ..scene.segmentation import Segmenter

        seg = Segmenter(None, num_threads)
    except (ImportError, OSError, ValueError):
        return [None] * len(maps)
    return [seg(m.astype(np.float32)) if len(m) else None for m in maps]


def _components(n: int, accepted: dict) -> np.ndarray:
    comp = np.arange(n)
    changed = True
    while changed:
        changed = False
        for A, B in accepted:
            lo = min(comp[A], comp[B])
            if comp[A] != lo or comp[B] != lo:
                comp[comp == comp[A]] = lo
                comp[comp == comp[B]] = lo
                changed = True
    return comp


def _place_recordings(members: list[int], accepted: dict) -> dict[int, np.ndarray]:
    """T_component_recording of each member: the first member's frame, others chained through
    the accepted hypotheses (breadth first)."""
    T = {members[0]: np.eye(4)}
    changed = True
    while changed:
        changed = False
        for (A, B), H in accepted.items():
            if A in T and B not in T and B in members:
                T[B] = T[A] @ H
                changed = True
            elif B in T and A not in T and A in members:
                T[A] = T[B] @ inv(H)
                changed = True
    return T


def _optimize(recs, members, T_rec, links, scfg, num_threads, init=None):
    """One pose graph over the members' stations, each node starting at its recording's
    station placed by ``T_rec[r]`` (T_component_recording), or at ``init[r][k]`` when given;
    returns ({rec: T (N, 4, 4)}, converged, (graph, result, node table)). Links the graph
    rejects are marked ``kept = False``."""
    graph = pg.PoseGraph()
    base = {}
    table = []
    for r in members:
        base[r] = len(graph.T_world_node)
        for k in range(len(recs[r].t_ns)):
            graph.add_node(init[r][k] if init is not None else T_rec[r] @ recs[r].T[k])
            table.append((r, k))
        for e in recs[r].edges:
            graph.add_edge(pg.Edge(base[r] + e.i, base[r] + e.j, e.T_i_j, e.information, e.kind))
    first_link = len(graph.edges)
    for lk in links:
        graph.add_edge(pg.Edge(base[lk.A] + lk.a, base[lk.B] + lk.b, lk.T_a_b, lk.information,
                               "link", lk.fitness, lk.rmse))
    sigma = np.radians(scfg.gravity_sigma_deg)
    for r in members:
        for k, up in enumerate(recs[r].up_in_lidar):
            graph.add_gravity(base[r] + k, up, sigma)
    poses = np.asarray(graph.T_world_node)
    gres = None
    converged = True
    if graph.edges:
        gres = optimize_graph(graph, scfg, num_threads)
        poses = gres.T_world_node
        converged = bool(gres.converged)
        for lk, ok in zip(links, gres.edge_inlier[first_link:]):
            lk.kept = bool(ok)
    out = {r: poses[base[r]: base[r] + len(recs[r].t_ns)] for r in members}
    return out, converged, (graph, gres, table)


# ---- outputs ------------------------------------------------------------------------------------
def _write_component(folder: Path, mres: MergeResult, comp: int, graph_info,
                     rcfg: ReconstructConfig, write_map: bool = True) -> dict[str, str]:
    from ..io import clouds as cloud_io
    from ..preprocess import mls_smooth, voxel_downsample

    folder.mkdir(parents=True, exist_ok=True)
    st = mres.stations_of(comp)
    recs = mres.recordings
    t = np.array([recs[r].t_ns[k] for r, k in st], dtype=np.int64)
    T = np.array([mres.T_world_station[r][k] for r, k in st]).reshape(-1, 4, 4)
    order = np.argsort(t, kind="stable")
    files = {}
    write_tum(folder / "stations.tum", t[order], T[order],
              "tripod merged stations: T_map_lidar at each station's middle time; lidar time, "
              "UNIX s; map frame z up (the first recording's)")
    with open(folder / "stations.csv", "w") as fh:
        fh.write("t_ns,recording,station_index\n")
        for i in order:
            r, k = st[i]
            fh.write(f"{t[i]},{recs[r].name},{recs[r].index[k]}\n")
    files.update(stations=str(folder / "stations.tum"), stations_csv=str(folder / "stations.csv"))
    graph, gres, _ = graph_info
    graph.save_g2o(folder / "pose_graph.g2o", gres.T_world_node if gres else None)
    files["pose_graph"] = str(folder / "pose_graph.g2o")
    if write_map:
        oc = rcfg.output
        merged = np.zeros((0, 3), np.float32)
        chunk: list[np.ndarray] = []
        gathered = 0
        for r, k in st:  # streamed: voxel-filter whenever 5 M points have gathered
            Tk = mres.T_world_station[r][k]
            p = recs[r].points[k] @ Tk[:3, :3].T.astype(np.float32) + Tk[:3, 3].astype(np.float32)
            chunk.append(p)
            gathered += len(p)
            if gathered > 5_000_000:
                merged = voxel_downsample(np.concatenate([merged] + chunk), oc.map_voxel_m, 0)
                chunk, gathered = [], len(merged)
        if chunk:
            merged = voxel_downsample(np.concatenate([merged] + chunk), oc.map_voxel_m, 0)
        if oc.smooth_radius_m > 0 and len(merged) > 10:
            merged = mls_smooth(merged, oc.smooth_radius_m, 0, oc.smooth_fit_voxel_m)
        cloud_io.write_ply(folder / "map.ply", cloud_io.make_cloud(merged))
        files["map_ply"] = str(folder / "map.ply")
        files["_map_points"] = str(len(merged))
    return files


def _write_outputs(mres: MergeResult, graphs: dict, cfg: MergeConfig) -> None:
    out = mres.outdir
    recs = mres.recordings
    rcfg = recs[0].config if recs else ReconstructConfig()
    ncomp = int(mres.component.max()) + 1 if len(recs) else 0
    for c in range(ncomp):
        folder = out if c == 0 else out / f"component-{c}"
        files = _write_component(folder, mres, c, graphs[c], rcfg)
        if c == 0:
            mres.files.update(files)
        else:
            mres.files[f"component-{c}"] = str(folder)
    with open(out / "links.csv", "w") as fh:
        fh.write("recording_a,station_a,recording_b,station_b,source,predicted_overlap,fitness,"
                 "rmse_m,kept\n")
        for lk in mres.links:
            fh.write(f"{recs[lk.A].name},{recs[lk.A].index[lk.a]},{recs[lk.B].name},"
                     f"{recs[lk.B].index[lk.b]},{lk.source},{lk.predicted_overlap:.3f},"
                     f"{lk.fitness:.3f},{lk.rmse:.4f},{int(lk.kept)}\n")
    mres.files["links"] = str(out / "links.csv")
    dump_config(cfg, out / "config.yaml")
    dump_config(rcfg, out / "reconstruct_config.yaml")
    mres.files.update(config=str(out / "config.yaml"),
                      reconstruct_config=str(out / "reconstruct_config.yaml"))
    summ = merge_summary(mres)
    (out / "report.md").write_text(merge_report(mres, summ))
    mres.files["report"] = str(out / "report.md")
    summ["files"] = {k: v for k, v in mres.files.items() if not k.startswith("_")}
    (out / "result.json").write_text(json.dumps(summ, indent=1))
    mres.files["result"] = str(out / "result.json")


def merge_summary(mres: MergeResult) -> dict:
    """Numbers of a merge (result.json, the batch table)."""
    recs = mres.recordings
    comps = []
    for c in range(int(mres.component.max()) + 1 if len(recs) else 0):
        members = [recs[r].name for r in np.flatnonzero(mres.component == c)]
        comps.append({"component": c, "recordings": members,
                      "stations": len(mres.stations_of(c)),
                      "graph_converged": mres.graph_converged.get(c)})
    return {
        "recordings": [r.name for r in recs],
        "stations": int(sum(len(r.t_ns) for r in recs)),
        "merged_stations": len(mres.stations_of(0)) if len(recs) else 0,
        "components": comps,
        "links_verified": len(mres.links),
        "links_kept": int(sum(lk.kept for lk in mres.links)),
        "recording_pairs_joined": int(sum(bool(p.accepted) for p in mres.pairs)),
        "recording_pairs_shortlisted": int(sum(p.shortlisted for p in mres.pairs)),
        "recording_pairs_left_out": int(sum(not p.shortlisted for p in mres.pairs)),
        "recording_pairs_proximity": int(sum(p.accepted == "proximity" for p in mres.pairs)),
        "recording_pairs": [{"a": recs[p.A].name, "b": recs[p.B].name,
                             "score": round(p.score, 4), "shortlisted": p.shortlisted,
                             "tried": p.tried,
                             "accepted": p.accepted, "links": p.links, "twin": p.twin,
                             "proximity": p.proximity,
                             "T_a_b": None if p.T_A_B is None else
                             np.round(p.T_A_B, 6).tolist()}
                            for p in mres.pairs],
        "recording_pairs_ambiguous": int(sum(bool(p.twin.get("ambiguous")) for p in mres.pairs)),
        "map_points": int(mres.files.get("_map_points", 0)),
        "stage_s": {k: v for k, v in mres.stage_s.items() if k != "_cpu"},
        "stage_cpu_s": mres.stage_s.get("_cpu", {}),
        "processing_s": float(sum(v for k, v in mres.stage_s.items() if k != "_cpu")),
        "processing_cpu_s": float(sum(mres.stage_s.get("_cpu", {}).values())),
        "notes": mres.notes,
    }


def merge_report(mres: MergeResult, summ: dict) -> str:
    """The merged model's report (Markdown)."""
    recs = mres.recordings
    ln = ["# tripod merged model", "",
          f"{len(recs)} recordings, {summ['stations']} stations; merged model: "
          f"{summ['merged_stations']} stations of "
          f"{len(summ['components'][0]['recordings']) if summ['components'] else 0} recordings; "
          f"{summ['links_kept']} links between recordings kept "
          f"({summ['links_verified']} verified); {len(summ['components'])} component(s); "
          f"{summ['processing_s']:.1f} s; {summ['recording_pairs_shortlisted']} of "
          f"{len(mres.pairs)} recording pairs shortlisted, "
          f"{summ['recording_pairs_left_out']} left out; "
          f"{summ['recording_pairs_joined']} joined, {summ['recording_pairs_proximity']} of "
          f"them by proximity", "",
          "## Components", "", "| component | recordings | stations | folder |", "|---|---|---|---|"]
    for c in summ["components"]:
        folder = "." if c["component"] == 0 else f"component-{c['component']}/"
        ln.append(f"| {c['component']} | {', '.join(c['recordings'])} | {c['stations']} | "
                  f"{folder} |")
    ln += ["", "## Recordings", "", "| recording | stations | component | links |",
           "|---|---|---|---|"]
    for r, rec in enumerate(recs):
        nl = sum(lk.kept and r in (lk.A, lk.B) for lk in mres.links)
        ln.append(f"| {rec.name} | {len(rec.t_ns)} | {mres.component[r]} | {nl} |")
    ln += ["", "## Recording pairs", "",
           "The pair's score (the overlap share of its global hypothesis; the shortlist keeps "
           "each recording's best partners), hypotheses (source: candidate station pairs, "
           "verified probes); the accepted one and "
           "its kept links; the twin check (score of the hypothesis and of its twins turned by "
           "180/90/270 deg or shifted along a repeated structure (m@axis yaw); runner-up / "
           "winner; ambiguous pairs are not joined by their hypothesis). *proximity*: a pair "
           "without links of its own, linked from the merged estimate (candidates / verified / "
           "kept).", "",
           "| a | b | score | hypotheses | accepted | links | twins |",
           "|---|---|---|---|---|---|---|"]
    for p in mres.pairs:
        tried = ("; ".join(f"{s}: {n}, {v} ok" for s, n, v in p.tried) or "none"
                 if p.shortlisted else "not shortlisted")
        tw = []
        if "scores" in p.twin:
            tw.append(", ".join(f"{k}{'°' if k.isdigit() else ''}: {v:.2f}"
                                for k, v in p.twin["scores"].items())
                      + f"; ratio {p.twin['ratio']:.2f}"
                      + (" **ambiguous**" if p.twin["ambiguous"] else ""))
        if p.twin.get("cycle"):
            tw.append("**breaks cycles**")
        tw = "; ".join(tw) or "–"
        acc = p.accepted or "–"
        if p.proximity:
            acc = (f"{acc} ({p.proximity['candidates']} / {p.proximity['verified']} / "
                   f"{p.proximity['kept']})")
        ln.append(f"| {recs[p.A].name} | {recs[p.B].name} | {p.score:.2f} | {tried} | "
                  f"{acc} | {p.links} | {tw} |")
    cpu = summ["stage_cpu_s"]
    ln += ["", "## Stages", "", "| stage | wall s | CPU s |", "|---|---|---|"]
    ln += [f"| {k} | {v:.1f} | {cpu.get(k, 0.0):.1f} |" for k, v in summ["stage_s"].items()]
    if mres.notes:
        ln += ["", "## Notes", ""] + [f"- {n}" for n in mres.notes]
    return "\n".join(ln) + "\n"
