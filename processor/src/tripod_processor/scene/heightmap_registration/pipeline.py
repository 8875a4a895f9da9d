# SPDX-License-Identifier: BSD-3-Clause
"""The heightmap registration pipeline: proposals from the three matchers, refinement,
verification and the decision (see the package docstring)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .correlation import _search
from .height import height_evidence, plane_height_contradicted
from .features import (_footprint_mask, _ij_to_xy, _log_hu, hu_moments, match_binary, match_nearest,
                       orb_keypoints, plan_image, rigid_2d_ransac, shape_blobs)
from .levelling import level_scan
from .verification import _close, _lift, _same_pose, _Verifier


@dataclass
class HeightmapMatch:
    """Result: T_target_source (4, 4) maps source points into the target frame.

    score : normalised image correlation of the plan heightmaps at the match (0..1)
    structure_fitness : share of each scan's wall and non-planar points (10 cm voxels) within
        ``max_distance`` of the other's surface, mean of both directions: the 3-D verification
    ambiguity : best structure fitness among the other (distinct) hypotheses / the winner's
        (1: as good an answer elsewhere, e.g. an empty symmetric room)
    fitness, inlier_rmse : overlap share of all source points and RMSE [m] after the final ICP
    hu_distance : distance of the floor footprints' log Hu moments (0 = same shape)
    proposer : which matcher proposed the answer ("correlation", "keypoints", "shapes")
    hypotheses : number of distinct hypotheses verified
    free_space_violation : share of either scan's structure the other saw through, at the answer
    twin_ambiguity : the choice among near-symmetric candidates (:func:`choose`): the answer,
        its turned twins (180 deg: three shift peaks; 90 and 270 deg: one) and the verification's
        two best runners-up, each searched, refined and polished like the answer and scored by
        their full 3-D consistency (fit less 30 x the free-space violation above 1 %, the walls
        and the rest apart); the best is the answer (``proposer`` then ends in "(chosen)") and
        this is the best other candidate's score over its own: ~1 when another pose explains
        the scans as well (a symmetric hall), and the answer is then not unique (at most 10)
    twins : (turn [deg], T_target_source, score, features) of every candidate of that choice,
        the verification's answer first (turn 0)
    height_observed : the relative height is fixed by the data: both floors or both ceilings,
        or (neither shared, both scans levelled by gravity) the horizontal patches both scans
        saw (:func:`.height.height_evidence`); False: the height is a guess (a vertical lidar's
        band of walls), or the shared planes' height is contradicted by another measure of it
        (:func:`.height.plane_height_contradicted`: a table top taken for a floor), and
        ``success`` is false
    consistent_ratio : the best other candidate that contradicts nothing (free-space violation
        within the 1 % allowance): its fit over the answer's (such a pose is as valid an
        explanation; > ``max_consistent_ratio``: ambiguous)
    success : structure_fitness >= min_fitness, free_space_violation <= max_violation,
        ambiguity <= max_ambiguity, twin_ambiguity <= max_twin_ambiguity and consistent_ratio
        <= max_consistent_ratio and height_observed
    seconds : wall time; stages : per-stage times [s]
    verified : (proposer, verification score, T_target_source, structure fitness, free-space
        violation) of every verified hypothesis, best first (score = fitness - weight x violation)
    """

    T_target_source: np.ndarray
    score: float
    structure_fitness: float
    free_space_violation: float
    ambiguity: float
    fitness: float
    inlier_rmse: float
    hu_distance: float
    proposer: str
    hypotheses: int
    success: bool
    seconds: float
    stages: dict = field(default_factory=dict)
    verified: list = field(default_factory=list)
    twin_ambiguity: float = 0.0
    twins: list = field(default_factory=list)
    consistent_ratio: float = 0.0
    height_observed: bool = True


def register_by_heightmaps(source, target, *, source_labels=None, target_labels=None,
                           coarse_pixel: float = 0.10, coarse_step_deg: float = 2.0,
                           fine_pixel: float = 0.05, fine_step_deg: float = 0.5,
                           feature_pixel: float = 0.05, candidates: int = 40, verify: int = 8,
                           use_keypoints: bool = True, use_shapes: bool = True,
                           max_distance: float = 0.08, min_fitness: float = 0.4,
                           max_ambiguity: float = 0.97, max_violation: float = 0.05,
                           max_twin_ambiguity: float = 0.8, max_consistent_ratio: float = 0.65,
                           twins: bool = True,
                           other_weight: float = 2.0,
                           free_space_weight: float = 10.0, viewpoint_source=(0.0, 0.0, 0.0),
                           viewpoint_target=(0.0, 0.0, 0.0), weights=None, seed: int = 0,
                           num_threads: int = 0, source_up=None, target_up=None,
                           source_gravity: bool = False, target_gravity: bool = False
                           ) -> HeightmapMatch:
    """Rigid transform between two overlapping indoor scans by matching plan heightmaps.

    Parameters
    ----------
    source, target : (N, 3), (M, 3) array_like [m], roughly z up (levelled by an IMU; the floor
        plane absorbs any tilt), in any yaw and position
    source_labels, target_labels : (N,), (M,) class labels (0 ceiling, 1 floor, 2 wall, 3 other),
        or None to run the segmenter
    coarse_pixel, coarse_step_deg : image pixel [m] and yaw step [deg] of the dense search
    fine_pixel, fine_step_deg : of the refinement of every hypothesis
    feature_pixel : pixel [m] of the images the keypoints and shapes are found on
    candidates : best distinct answers (yaws 20 deg or shifts 1 m apart) the dense search
        proposes (five correlation peaks per yaw); all proposals are screened in 3-D as they
        are, the best ``verify`` of them refined, polished by ICP and verified
    use_keypoints, use_shapes : also propose from ORB keypoints / Hu-moment shape matches
    max_distance : inlier distance of the 3-D verification [m]
    min_fitness : verified structure overlap needed to call the match a success
    max_ambiguity : runner-up / winner verification score above which the answer is not unique
    max_violation : share of structure seen through by the other scan above which the answer is
        inconsistent (two different rooms of similar shape overlap well, but not in free space)
    max_twin_ambiguity : best other candidate's score / the chosen one's above which the answer
        is ambiguous (``twin_ambiguity``)
    max_consistent_ratio : fit of a candidate that contradicts nothing over the chosen one's
        above which the answer is ambiguous (``consistent_ratio``)
    twins : choose among the answer, its turned twins and the runners-up (off: the answer as
        verified)
    free_space_weight : weight of that share against the structure fitness when ranking
        hypotheses (a point seen through is a contradiction, a missing overlap is only unseen)
    viewpoint_source, viewpoint_target : (3,) the sensor position in each cloud's frame [m]
        (a fragment's origin): the free-space check and the normals' orientation need it
    other_weight : weight of the non-wall channel in the correlation score
    weights : segmenter weights when labels are None
    source_up, target_up : (3,) the up direction (against gravity) in each cloud's frame, or
        None for a cloud that is already roughly z up. A cloud with one is levelled first (turned
        so that up is +z, :func:`..gravity.R_level_cloud`) and the answer turned back: any mount
        of the lidar, side-mounted included, then registers like a level one
    source_gravity, target_gravity : the cloud's z is already up along gravity: its floor
        plane gives the height, and refines the levelling only within 1 deg (set for a cloud
        levelled by its up)

    Returns
    -------
    :class:`HeightmapMatch` with ``T_target_source`` (4, 4): x_target = T @ x_source.
    """
    if source_up is not None or target_up is not None:
        return _register_levelled(
            source, target, source_up, target_up, viewpoint_source, viewpoint_target,
            dict(source_labels=source_labels, target_labels=target_labels,
                 coarse_pixel=coarse_pixel, coarse_step_deg=coarse_step_deg,
                 fine_pixel=fine_pixel, fine_step_deg=fine_step_deg,
                 feature_pixel=feature_pixel, candidates=candidates, verify=verify,
                 use_keypoints=use_keypoints, use_shapes=use_shapes, max_distance=max_distance,
                 min_fitness=min_fitness, max_ambiguity=max_ambiguity,
                 max_violation=max_violation, max_twin_ambiguity=max_twin_ambiguity,
                 max_consistent_ratio=max_consistent_ratio,
                 twins=twins, other_weight=other_weight,
                 free_space_weight=free_space_weight, weights=weights, seed=seed,
                 num_threads=num_threads))
    t0 = time.perf_counter()
    stages = {}
    S = np.asarray(source, np.float64)
    Tg = np.asarray(target, np.float64)
    if source_labels is None or target_labels is None:
        source_labels, target_labels = _segment(S, Tg, source_labels, target_labels, weights,
                                                num_threads)
        stages["segment"] = time.perf_counter() - t0
    source_labels, target_labels = np.asarray(source_labels), np.asarray(target_labels)

    # 1. level both scans on their floors
    t1 = time.perf_counter()
    ls = level_scan(S, source_labels, seed=seed, gravity=source_gravity)
    lt = level_scan(Tg, target_labels, seed=seed, gravity=target_gravity)
    stages["level"] = time.perf_counter() - t1

    # 2. proposals (yaw, shift) of the levelled source onto the levelled target
    extent = (float(max(np.ptp(lt.xy, 0).max(), np.ptp(ls.xy, 0).max()))
              if len(lt.xy) and len(ls.xy) else 10.0)
    cp = max(coarse_pixel, extent / 150)  # the images stay small for big halls
    fp = max(fine_pixel, extent / 400)
    yaws = np.deg2rad(np.arange(0.0, 360.0, coarse_step_deg))
    proposals = _proposals(ls, lt, stages, yaws, cp, max(feature_pixel, extent / 400), candidates,
                           other_weight, use_keypoints, use_shapes, seed)

    # 3. screen the distinct proposals in 3-D as they are (loose distance, free space), then
    #    refine the best by correlation (fine pixel and yaw) and lift them to 3-D
    t1 = time.perf_counter()
    check = _Verifier(S, source_labels, Tg, target_labels, max_distance, viewpoint_source,
                      viewpoint_target, num_threads)
    height = _level_height(ls, lt)
    if source_gravity and target_gravity:  # both level by gravity: the ICPs keep them level
        check.keep_level(ls.T_level_scan, lt.T_level_scan, height)
    screened = _screen(proposals, ls, lt, check, 3 * cp, free_space_weight)
    hyps = []
    for _, yaw0, shift0, who in screened[:verify]:
        fine = yaw0 + np.deg2rad(np.arange(-coarse_step_deg, coarse_step_deg + 1e-9, fine_step_deg))
        win = (shift0, int(np.ceil(2 * cp / fp)) + 2)
        score, yaw, shift = _search(ls, lt, fine, fp, window=win,
                                    seed=seed, other_weight=other_weight)[0]
        hyps.append((score, who, _lift(ls, lt, yaw, shift)))
    stages["screen+refine"] = time.perf_counter() - t1

    # 4. verify in 3-D: short ICP, then the share of walls and furniture on the other's
    #    surfaces, less what either scan saw through
    t1 = time.perf_counter()
    checked, ambiguity = _verify(hyps, check, free_space_weight)
    best = checked[0]
    stages["verify"] = time.perf_counter() - t1

    # 5. final polish at full density
    t1 = time.perf_counter()
    T, fitness, rmse = check.final(best[3])
    stages["final"] = time.perf_counter() - t1

    # 6. the choice among near-symmetric candidates: the answer, its turned twins and the
    #    runners-up, each searched, refined and polished the same way, scored by their full 3-D
    #    consistency; the best is the answer, one that scores nearly as well makes it ambiguous
    #    (a symmetric room has no unique answer)
    twin_amb, consistent, twin_list, who = 0.0, 0.0, [], best[2]
    if twins:
        t1 = time.perf_counter()
        cands = _candidates(ls, lt, check, T, checked, fp, fine_step_deg, coarse_step_deg,
                            other_weight, seed)
        stages["candidates"] = time.perf_counter() - t1
        t1 = time.perf_counter()
        k, twin_amb, consistent, twin_list = choose(check, cands, max_distance)
        if k:  # a turned twin or a runner-up explains both scans better
            T, fitness, rmse = cands[k][2], cands[k][3], cands[k][4]
            who = f"{cands[k][0]} (chosen)"
        stages["choice"] = time.perf_counter() - t1
    # 7. no shared floor or ceiling: the height from the horizontal patches both scans saw
    height_observed = True
    if check.level is not None and height is None:
        t1 = time.perf_counter()
        T, fitness, rmse, height_observed = _height_from_patches(check, S, Tg, lt, T, fitness,
                                                                 rmse)
        stages["height"] = time.perf_counter() - t1
    elif check.level is not None:  # the shared planes' height, checked against other measures
        t1 = time.perf_counter()
        height_observed = not _plane_height_contradicted(S, Tg, ls, lt, T)[0]
        stages["height"] = time.perf_counter() - t1
    sfit = check.structure_fitness(T)
    viol = check.free_space_violation(T)
    ok = (sfit >= min_fitness and viol <= max_violation and ambiguity <= max_ambiguity
          and twin_amb <= max_twin_ambiguity and consistent <= max_consistent_ratio
          and height_observed)
    return HeightmapMatch(T, float(best[1]), float(sfit), float(viol), float(ambiguity), fitness,
                          rmse, _footprint_distance(ls, lt), who, len(checked), bool(ok),
                          time.perf_counter() - t0, stages,
                          [(c[2], c[0], c[3], c[4], c[5]) for c in checked], float(twin_amb),
                          twin_list, float(consistent), bool(height_observed))


def _height_from_patches(check, S, Tg, lt, T, fitness, rmse, redo_m: float = 0.03):
    """(T, fitness, rmse, observed): the pose's height checked against the horizontal patches
    both scans saw, in the target's level frame; a correction over ``redo_m`` is applied and the
    pose finished again (the level ICP, height free, from there). Not observable: the pose as
    it was, ``observed`` False."""
    L = lt.T_level_scan
    M = L @ T
    ev = height_evidence(S @ M[:3, :3].T + M[:3, 3], Tg @ L[:3, :3].T + L[:3, 3])
    if not ev.observable:
        return T, fitness, rmse, False
    if abs(ev.dz) > redo_m:
        shift = np.eye(4)
        shift[2, 3] = ev.dz
        T1 = np.linalg.inv(L) @ shift @ M
        T2, f2, r2 = check.final(T1)
        return (T2, f2, r2, True) if np.isfinite(f2) else (T1, fitness, rmse, True)
    return T, fitness, rmse, True


def _plane_height_contradicted(S, Tg, ls, lt, T, margin_m: float = 0.10
                                ) -> tuple[bool, str]:
    """:func:`.height.plane_height_contradicted` of the pose ``T`` whose height shared floors
    (or ceilings) gave (:func:`_level_height`), in the target's level frame, the points within
    ``margin_m`` [m] of the planes that gave it left out."""
    L = lt.T_level_scan
    M = L @ T
    floors = ls.floor_trusted and lt.floor_trusted
    Ps, Pt = S @ M[:3, :3].T + M[:3, 3], Tg @ L[:3, :3].T + L[:3, 3]
    # the planes that gave the height are left out (a table top taken for the floor lies on the
    # other's floor at this pose): above the floors, else below the target's ceiling, 10 cm
    if floors:
        Ps, Pt = Ps[Ps[:, 2] > margin_m], Pt[Pt[:, 2] > margin_m]
    else:
        top = lt.height - margin_m
        Ps, Pt = Ps[Ps[:, 2] < top], Pt[Pt[:, 2] < top]
    return plane_height_contradicted(Ps, Pt)


#: turns about the vertical that give the twins of an answer (a rectangle's 180 deg, a square's
#: 90 and 270 deg)
TWIN_TURNS_DEG = (180.0, 90.0, 270.0)


def _candidates(ls, lt, check, T, checked, fp: float, fine_step_deg: float,
                coarse_step_deg: float, other_weight: float, seed: int, peaks: int = 3) -> list:
    """The answer ``T`` and the poses it could be confused with, each finished like it
    (polished, final ICP): its turned twins (:data:`TWIN_TURNS_DEG`; the dense correlation over
    yaws within a coarse step of the answer's yaw + the turn, the ``peaks`` best distinct shifts
    at 180 deg and the best at 90 and 270 deg) and the verification's two best distinct
    runners-up. Returns [(label, turn [deg], T, fitness, rmse)], the answer first, no two the
    same pose."""
    M = lt.T_level_scan @ T @ np.linalg.inv(ls.T_level_scan)
    yaw0 = float(np.arctan2(M[1, 0], M[0, 0]))
    cands = [("answer", 0.0, T, float("nan"), float("nan"))]
    offs = np.deg2rad(np.arange(-coarse_step_deg, coarse_step_deg + 1e-9, fine_step_deg))

    def add(label, turn, T0):
        T1, fit, rmse = check.final(check.polish(T0))
        if not any(_same_pose(T1, c[2]) for c in cands):
            cands.append((label, turn, T1, fit, rmse))

    for turn in TWIN_TURNS_DEG:
        n = peaks if turn == 180.0 else 1  # a rectangle's twin; a square's are rarer
        for _, yaw, shift in _search(ls, lt, yaw0 + np.deg2rad(turn) + offs, fp, seed=seed,
                                     other_weight=other_weight, keep=n, shifts=n):
            add(f"twin {turn:.0f}", turn, _lift(ls, lt, yaw, shift))
    runners = [c for c in checked[1:] if not _same_pose(c[3], T)][:2]
    for c in runners:
        M2 = lt.T_level_scan @ c[3] @ np.linalg.inv(ls.T_level_scan)
        turn = float(np.degrees(np.arctan2(M2[1, 0], M2[0, 0]) - yaw0)) % 360.0
        add("runner-up", turn, c[3])
    return cands


def choose(check, cands: list, distance: float, free_space_weight: float = 30.0,
           noise: float = 0.01) -> tuple[int, float, float, list]:
    """Choose among near-symmetric candidates (:func:`_candidates`, the answer first) by their
    full 3-D consistency (:meth:`_Verifier.consistency`, walls and the rest apart).

    score = fit - ``free_space_weight`` x max(0, violation - ``noise``), where fit is the share
    of the structure (walls and the rest together) within ``distance`` of the other scan's
    surface and violation the mean of the walls' and the rest's shares that the other scan saw
    through (the rest counts as much as the walls: a room's shell fits its turned twin, its
    furniture does not, and a cabinet standing where the other scan saw the wall behind it is
    the contradiction that tells them apart); up to ``noise`` is what a right pose shows (range
    noise, the lever arm's travel), or what the pair's most consistent overlapping candidate
    shows, up to 3 x ``noise`` (thin furniture is seen through between its parts from another
    viewpoint: a synthetic room's chairs gave its true pose 6-10 % of its furniture seen
    through). The best score is chosen. Ambiguity: the best other
    candidate's score over the chosen one's: a pose that contradicts nothing and overlaps about
    as much is an equally good explanation (a symmetric hall's twin: its fit is often *higher*,
    both scans then seeing the columns from the same side), so a fit ratio near 1 there means
    the scans cannot tell; a contradicting twin scores far below.

    A candidate whose violation is within ``noise`` contradicts nothing: it is as valid an
    explanation as the chosen one whatever its fit, so its fit over the chosen one's is
    returned too (``consistent``; the pipeline calls the answer ambiguous above
    ``max_consistent_ratio``): fit depends on where the scans were taken from, and in a
    symmetric hall the true pose fitted 0.8 of its twin's on dev seed 303 (score ratio 0.81,
    just at the 0.8 limit), while the consistent alternatives of the right answers of dev
    pairs with >= 30 % overlap fitted at most 0.57 of it (barely touching placements).

    Returns (index of the chosen candidate, ambiguity: the best other score over the chosen
    one's (0..10), consistent: the best consistent other's fit over the chosen one's (0..10),
    [(turn, T, score, features)] of every candidate in their order (the answer first))."""
    feats = []
    for label, turn, T, _, _ in cands:
        f = check.consistency(T, distance)
        n_w, n_o = f["n_wall"], f["n_other"]
        fit = (n_w * f["fit_wall"] + n_o * f["fit_other"]) / max(n_w + n_o, 1)
        viol = 0.5 * (f["viol_wall"] + f["viol_other"]) if n_o >= 50 else f["viol_wall"]
        feats.append(dict(f, fit=fit, viol=viol))
    # the pair's own noise floor (up to 3 x ``noise``): what the most consistent of the
    # candidates that overlap (fit >= half the best) shows: thin furniture, chair legs, is seen
    # through between its parts from the other viewpoint; a candidate that barely overlaps
    # contradicts nothing and sets no floor
    top = max(f["fit"] for f in feats)
    noise = min(3.0 * noise, max(noise, min(f["viol"] for f in feats if f["fit"] >= 0.5 * top)))
    scored = [(f["fit"] - free_space_weight * max(0.0, f["viol"] - noise), f) for f in feats]
    k = int(np.argmax([s for s, _ in scored]))
    own, fit_own = scored[k][0], scored[k][1]["fit"]
    others = [sc for i, sc in enumerate(scored) if i != k]
    if not others:
        amb = 0.0
    elif own <= 0:
        amb = 1.0
    else:
        amb = max(0.0, max(s for s, _ in others) / own)
    # an alternative that contradicts nothing is a valid explanation whatever its fit: judged
    # by its share of the chosen one's fit (a symmetric hall's true pose fits ~0.8 of its twin's)
    consistent = max((f["fit"] / max(fit_own, 1e-9) for _, f in others if f["viol"] <= noise),
                     default=0.0)
    return (k, float(min(amb, 10.0)), float(min(consistent, 10.0)),
            [(c[1], c[2], sc[0], sc[1]) for c, sc in zip(cands, scored)])


def _register_levelled(source, target, source_up, target_up, viewpoint_source, viewpoint_target,
                       kwargs: dict) -> HeightmapMatch:
    """register_by_heightmaps on the clouds turned so that their up is +z (a cloud without one
    as it is), with the transforms turned back into the clouds' own frames."""
    from ..gravity import R_level_cloud

    L_s, L_t = np.eye(4), np.eye(4)  # T_level_cloud of each (a rotation about the origin)
    if source_up is not None:
        L_s[:3, :3] = R_level_cloud(source_up)
    if target_up is not None:
        L_t[:3, :3] = R_level_cloud(target_up)
    S = np.asarray(source, np.float64) @ L_s[:3, :3].T
    Tg = np.asarray(target, np.float64) @ L_t[:3, :3].T
    r = register_by_heightmaps(
        S, Tg, viewpoint_source=L_s[:3, :3] @ np.asarray(viewpoint_source, float),
        viewpoint_target=L_t[:3, :3] @ np.asarray(viewpoint_target, float),
        source_gravity=source_up is not None, target_gravity=target_up is not None, **kwargs)
    L_t_inv = np.linalg.inv(L_t)

    def back(T):  # T_levelT_levelS -> T_target_source
        return L_t_inv @ T @ L_s

    r.T_target_source = back(r.T_target_source)
    r.verified = [(v[0], v[1], back(v[2]), *v[3:]) for v in r.verified]
    r.twins = [(t[0], back(t[1]), *t[2:]) for t in r.twins]
    return r


def _proposals(ls, lt, stages: dict, yaws, cp: float, fpx: float, candidates: int,
               other_weight: float, use_keypoints: bool, use_shapes: bool, seed: int) -> list:
    """(yaw, shift, proposer, score) from the dense correlation search over ``yaws`` at pixel
    ``cp`` and, at pixel ``fpx``, from keypoints and shapes; each matcher's time in ``stages``."""
    t1 = time.perf_counter()
    proposals = [(yaw, shift, "correlation", score) for score, yaw, shift in
                 _search(ls, lt, yaws, cp, seed=seed, keep=candidates, other_weight=other_weight,
                         shifts=5)]
    stages["correlation"] = time.perf_counter() - t1
    if use_keypoints:
        t1 = time.perf_counter()
        proposals += _keypoint_proposals(ls, lt, fpx, seed)
        stages["keypoints"] = time.perf_counter() - t1
    if use_shapes:
        t1 = time.perf_counter()
        proposals += _shape_proposals(ls, lt, fpx, seed)
        stages["shapes"] = time.perf_counter() - t1
    return proposals


def _level_height(ls, lt) -> float | None:
    """Height [m] of the source's level frame in the target's when two horizontal planes tell it:
    0 when both floors are trusted (both level frames stand on them), else the ceilings'
    difference when both ceilings are; None (the height left to the level ICP) when neither
    pair is seen. A vertical lidar's band sees no floor in a small room: its height then rests
    on furniture and the walls' ends only (``success`` does not check it)."""
    if ls.floor_trusted and lt.floor_trusted:
        return 0.0
    if ls.ceiling_trusted and lt.ceiling_trusted:
        return float(lt.height - ls.height)
    return None


def _footprint_distance(ls, lt) -> float:
    """Distance of the two floor footprints' log Hu moments (0 = same shape)."""
    hu_s = _log_hu(hu_moments(_footprint_mask(ls.floor_xy)))
    hu_t = _log_hu(hu_moments(_footprint_mask(lt.floor_xy)))
    return float(np.abs(hu_s[:4] - hu_t[:4]).sum())


def _segment(S, Tg, source_labels, target_labels, weights, num_threads):
    """Labels of the scans that came without them, by the segmenter."""
    from ..segmentation import Segmenter

    seg = Segmenter(weights, num_threads)
    source_labels = seg(S.astype(np.float32)) if source_labels is None else source_labels
    target_labels = seg(Tg.astype(np.float32)) if target_labels is None else target_labels
    return source_labels, target_labels


def _keypoint_proposals(ls, lt, fpx: float, seed: int) -> list:
    """(yaw, shift, "keypoints", inliers) from ORB keypoints of the two plan images."""
    img_s, lo_s = plan_image(ls, fpx)
    img_t, lo_t = plan_image(lt, fpx)
    ij_s, d_s = orb_keypoints(img_s)
    ij_t, d_t = orb_keypoints(img_t)
    m = match_binary(d_s, d_t)
    if len(m) < 4:
        return []
    a = _ij_to_xy(ij_s[m[:, 0]], lo_s, fpx)
    b = _ij_to_xy(ij_t[m[:, 1]], lo_t, fpx)
    return [(yaw, t, "keypoints", float(len(inl)))
            for inl, yaw, t in rigid_2d_ransac(a, b, inlier_m=3 * fpx, min_inliers=6, seed=seed)]


def _shape_proposals(ls, lt, fpx: float, seed: int) -> list:
    """(yaw, shift, "shapes", inliers) from Hu-moment matches of the plans' blobs."""
    c_s, h_s = shape_blobs(ls, fpx)
    c_t, h_t = shape_blobs(lt, fpx)
    m = match_nearest(h_s, h_t, k=3)
    if len(m) < 3:
        return []
    return [(yaw, t, "shapes", float(len(inl)))
            for inl, yaw, t in rigid_2d_ransac(c_s[m[:, 0]], c_t[m[:, 1]], inlier_m=0.2,
                                               min_inliers=3, seed=seed)]


def _screen(proposals, ls, lt, check, distance: float, free_space_weight: float) -> list:
    """Distinct proposals as (pre-score, yaw, shift, proposer), best first: structure fitness at
    a loose ``distance`` less the weighted free-space violation, of each lifted as it is."""
    screened = []
    for yaw0, shift0, who, _ in proposals:
        yaw0, shift0 = float(yaw0), np.asarray(shift0, np.float64)
        if any(_close(yaw0, shift0, h[1], h[2]) for h in screened):
            continue
        T0 = _lift(ls, lt, yaw0, shift0)
        pre = (check.structure_fitness(T0, distance, screen=True)
               - free_space_weight * check.free_space_violation(T0, screen=True))
        screened.append((pre, yaw0, shift0, who))
    screened.sort(key=lambda h: -h[0])
    return screened


def _verify(hyps, check, free_space_weight: float) -> tuple[list, float]:
    """Each hypothesis polished by ICP and scored; (checked best first, ambiguity)."""
    checked = []
    for score, who, T in hyps:
        T_icp = check.polish(T)
        fit, viol = check.structure_fitness(T_icp), check.free_space_violation(T_icp)
        checked.append((fit - free_space_weight * viol, score, who, T_icp, fit, viol))
    checked.sort(key=lambda c: -c[0])
    best = checked[0]
    others = [c for c in checked[1:] if not _same_pose(c[3], best[3])]
    if best[0] <= 0:  # even the best contradicts free space or barely overlaps: no winner
        ambiguity = 1.0
    else:
        ambiguity = max(0.0, others[0][0] / best[0]) if others else 0.0
    return checked, ambiguity
