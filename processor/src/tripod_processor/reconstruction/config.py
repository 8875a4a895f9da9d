# SPDX-License-Identifier: BSD-3-Clause
"""Typed configuration of ``tripod reconstruct`` (one section per stage).

Every run writes its effective config (``config.yaml``) beside its outputs; ``tripod reconstruct
--print-default-config`` prints the commented defaults. Unknown keys are an error naming the key.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from tripod_shared.config_io import StrictModel


class ExtrinsicConfig(StrictModel):
    """The lidar's mounting on the IMU / tripod head (calibrated from the data when not given)."""

    #: rotation R_imu_lidar as a quaternion w, x, y, z; null: calibrate from the data
    q_imu_lidar: list[float] | None = Field(default=None, min_length=4, max_length=4)
    #: lever arm [m] from the head's pivot to the lidar origin, in the IMU frame; null: calibrate
    lever_arm_m: list[float] | None = Field(default=None, min_length=3, max_length=3)


class PlacementConfig(StrictModel):
    extrinsic: ExtrinsicConfig = ExtrinsicConfig()
    #: IMU-to-lidar time offset [s] added to the IMU's lidar-clock stamps; null: estimate it
    imu_time_offset_s: float | None = None
    #: span [s] of the zero-phase smoothing of the IMU's attitude samples (a quadratic fit
    #: over the window at each sample; 0: raw samples): the IMU's white noise per sample would
    #: otherwise turn each station's fragment (anchored at one moment) and the calibration's
    #: sweep-to-sweep turns. Off by default: on development rigs 0-3 and 19 it took the station
    #: angle error of two from 0.128/0.123° to 0.103/0.097° but left three others worse (see the
    #: README's rig benchmark), so it is not yet shown to help
    imu_smooth_s: float = Field(default=0.0, ge=0, le=1.0)
    #: a station's frame (its fragment's, its pose's) at the IMU attitude fitted over all of
    #: the station's samples (``placement.station_anchor_rotation``: the tilt averaged over the
    #: station, the pan angle fitted around the middle time) instead of the one slerped between
    #: two samples, whose white noise (0.05° per axis) would turn the whole station
    anchor_fit: bool = True
    #: the fitted anchor may differ from the slerped one by at most this [deg] (the slerped
    #: sample's noise is 0.05° per axis): else the station keeps the slerped attitude (counted
    #: in the report's notes)
    anchor_max_deviation_deg: float = Field(default=0.3, gt=0)
    #: search range of the time-offset estimate [s] (± this)
    time_offset_search_s: float = Field(default=0.08, gt=0)
    min_range_m: float = Field(default=0.4, ge=0)
    max_range_m: float = Field(default=100.0, gt=0)


class CalibrationConfig(StrictModel):
    """Calibration from the data (``reconstruction.calibration.self_calibrate``): what the
    config leaves null is estimated from the stations' self-consistency."""

    #: estimate the lever arm (across the pan axis) when placement.extrinsic.lever_arm_m is null
    lever_arm: bool = True
    #: estimate the IMU time offset when placement.imu_time_offset_s is null
    time_offset: bool = True
    #: refine the mount's tilts when placement.extrinsic.q_imu_lidar is null
    mount_rotation: bool = True
    #: stations used (those the head turns most in)
    max_stations: int = Field(default=4, ge=1)
    #: hand-eye's mount (``calibration.calibrate_mount``): where its 45° sweep pairs do not
    #: register (too little shared view), this many more levels of turn, halving each, before
    #: consecutive windows, and the pairs registered at a level given up are kept. A lidar 24°
    #: off the pan axis in a big hall shares under half the view after 45° and its mount came
    #: from ~2° consecutive pairs, 3-11° off per station (dev seed 5621; 0.02-0.2° with 3).
    #: 0: the old ladder (45°, 22.5°, consecutive windows)
    mount_turn_ladder: int = Field(default=3, ge=0, le=6)
    #: hand-eye's mount tilt sigma [deg] (its pairs' axis scatter) from which the run warns
    mount_tilt_warn_deg: float = Field(default=2.0, gt=0)
    #: the calibration's sweeps and station points have their ranges smoothed along the scan
    #: line over this many firings either side (±1° at 600 rpm for 5; a depth edge is not
    #: smoothed across): two sweeps' 3-cm range noise otherwise biases their registration's
    #: rotation, hence hand-eye's mount tilt, by tenths of a degree in a small room. 0: off
    range_denoise_firings: int = Field(default=5, ge=0, le=50)
    #: the calibration's decoded sweeps (0.1-s windows, ranges smoothed, before any de-skew)
    #: are kept for its later registrations: hand-eye, the turns' lever arm and each pass of
    #: the turns' time offset (up to four: its second at the new offset, the re-measure after
    #: the surfaces' fit) de-skew the same windows again; kept up to this many MB, dropped after
    #: the calibration. The same results with any value; 0: every sweep decoded anew (the old
    #: path)
    sweep_cache_mb: float = Field(default=256.0, ge=0)
    #: the surfaces' fit's sample points of each station (decoded, smoothed, drawn) are kept
    #: for its later fits on the same stations with the same draw (the fit again after the
    #: mount tilt is weighed, at the same time offset); up to this many MB, dropped after the
    #: calibration. The same results with any value; 0: every fit decodes anew (the old path)
    station_points_cache_mb: float = Field(default=128.0, ge=0)
    #: a time offset less certain than this [ms, 1 sigma] is not applied (kept at the prior):
    #: the surfaces' sigma is optimistic (a yaw error hides in walls seen head-on)
    max_time_offset_sigma_ms: float = Field(default=0.5, gt=0)
    #: the time offset from sweeps registered against each other across the head's rate changes
    #: (``calibration.time_offset_from_turns``; any pan profile), joined with the stations'
    #: surfaces' when both are sure and agree; off: from the surfaces only
    time_offset_from_turns: bool = True
    #: stations the turns' offset pools (one offset for the recording; those turned most)
    max_turn_stations: int = Field(default=8, ge=1)
    #: the turns' offset also registers sweeps taken while the tripod is carried between
    #: stations (its head turns about every axis, with rate changes of tens of °/s: the
    #: offset shows there even when the pans are slow or at a constant rate)
    time_offset_from_carries: bool = True
    #: sweep pairs the turns' offset registers in each station and each carry (those whose
    #: rate differs most first). Each pair's angle is milliseconds of offset noisy (its
    #: registration, the IMU's attitude noise), so more pairs average it down. A station's 12
    #: pairs (default) reuse its sweeps (``turn_sweep_uses``): 12 and 12 with 12 sweeps each and
    #: ``turn_passes`` 4 cost 5-13 s more CPU a rig and sent dev seed 8399's ATE to 585 cm
    turn_pairs_per_station: int = Field(default=12, ge=0)
    turn_pairs_per_carry: int = Field(default=6, ge=0)
    #: passes of the turns' offset: each de-skews the sweeps and picks the pairs at the offset
    #: the last found, until it moves less than 0.5 ms
    turn_passes: int = Field(default=2, ge=1)
    #: a station's pair weighed by its registration's information about the turn about the pan
    #: axis (a carry's pair is, about all three axes); off: every station pair alike. With
    #: ``turn_sweep_uses`` 2 and 12 pairs a station (defaults) the pipeline's offset error on 14
    #: dev rigs went from median 1.41 ms to 0.99 (README, calibration step 3)
    turn_station_information: bool = True
    #: pairs a station's sweep may join in the turns' offset (1: each sweep in one pair, the
    #: old behaviour). A registration costs less than de-skewing a sweep and its error is the
    #: pair's own, so 2 doubles a station's pairs from the same sweeps for ~1-3 CPU-s a rig
    turn_sweep_uses: int = Field(default=2, ge=1)
    #: how the turns' offset joins the stations' pairs and the carries': "split" (default: each
    #: kind fitted alone, then joined by inverse variance with the carries' sigma floored at
    #: ``turn_carry_floor_ms``, and grown by the Birge ratio when the two disagree) or "joint"
    #: (the old way: one fit, each kind weighed by its residuals' scale). A carry's pairs share
    #: its errors and the mount's, so their scatter understates their sigma (on 13 hard dev
    #: rigs the carries alone were 1.8 ms RMS off, the stations 0.8) and they outvoted the
    #: stations: there the turns' offset went from median 0.56 / RMS 1.01 ms (9/13 within
    #: 1 ms) to 0.33 / 0.82 (10/13), README calibration step 3, stop 36
    turn_combine: Literal["joint", "split"] = "split"
    #: ... the floor [ms, 1 sigma before the turns' inflation, in quadrature] of the carries'
    #: sigma when they join the stations' with "split" (the carries alone keep their own).
    #: 2.0 until stop 38: it held off the carries' +1.5-3 ms bias, which was the de-skew's pull
    #: (``turn_anchor_smooth_s``); with that anchored, 0.5 on 17 dev rigs: offset within 1 ms
    #: 14 -> 15, worst 1.30 -> 1.13 ms, sum of |error| 6.6 -> 4.2 ms (README, calibration)
    turn_carry_floor_ms: float = Field(default=0.5, ge=0)
    #: the turns' offset leaves out the one cluster (a station's pairs, or a carry's) whose own
    #: offset lies more than this many combined sigmas from all the others' pooled one (at
    #: least 3 clusters with an offset of their own), and is the others' fit: one bad station
    #: (a small room's biased registrations) or a span mis-taken for a carry otherwise pulls the
    #: whole offset. 0: every cluster kept (the old fit, to the bit). Issue 12, stop 40
    turn_cluster_outlier_z: float = Field(default=0.0, ge=0)
    #: the carries' rows also fit a small correction of the mount rotation (3 unknowns, the
    #: hand-eye equation's (I − Pᵀ)ε): hand-eye's mount, 1-4° off on hard dev rigs, otherwise
    #: leaks into their offset (83's carries −2.1 → −1.4 ms, 87's 3.8 → 3.4; 40's, 3.9° off,
    #: 0.9 → 1.8). Off: the offset and the yaw drift only
    turn_carry_mount: bool = True
    #: the turns' fit predicts each pair at a trial offset from the IMU attitudes at the offset
    #: its sweeps were de-skewed at (their samples' noise, 0.05° each, is in the registration
    #: too and cancels only there) moved by the change of the attitude smoothed over this span
    #: [s] (zero-phase); 0: slerped afresh at every trial offset, which draws the estimate
    #: toward the offset the sweeps were de-skewed at (dev 40 and 87 de-skewed at 0: the
    #: carries +4.0 / +4.2 ms off, +0.7 / +0.8 with 0.1 s)
    turn_anchor_smooth_s: float = Field(default=0.1, ge=0, le=1.0)
    #: the turns' offset is applied up to this sigma [ms] (their sigma comes from the pairs'
    #: scatter, inflated to be honest; an estimate that sure still beats the prior 0 against IMU
    #: latencies of up to 10 ms, and the station splitter's refit tolerates ±12 ms); above
    #: 0.5 ms it is warned as poorly observable
    max_turns_time_offset_sigma_ms: float = Field(default=4.0, gt=0)
    #: the turns' offset joins the surfaces' fit as a prior (offset and lever arm estimated
    #: together); off: the surfaces fit alone, then an inverse-variance mean when they agree
    joint_time_prior: bool = True
    #: the lever-arm fit's first iterations with split residuals (a voxel's later points to its
    #: earlier points' plane: the whole gap a wrong lever arm opens, ``calibration.
    #: _split_plane_residuals``), then the usual ones; 0 (default): the usual ones only. 4
    #: fixes the lever arm of a lidar on its side in the scan plane (dev seeds 87, 8399) but is
    #: off until a hall's station misplaced with it is traced (dev seed 8399: 5.3 -> 278 cm ATE)
    split_iterations: int = Field(default=0, ge=0)
    #: a lidar's spin axis at least this far from the pan axis [deg] gets a warning that the
    #: lever arm along the spin axis is weakly observable (seen only at vertical edges)
    side_mount_warn_deg: float = Field(default=50.0, ge=0, le=90)
    #: on a lidar at least ``side_mount_warn_deg`` from the pan axis, the lever-arm fit starts
    #: from hand-eye's lever arm over the turns of several stations
    #: (``calibration.lever_arm_from_turns``) instead of one station's: the surfaces hardly
    #: move its component along the spin axis, and a start far off in the scan plane they
    #: close only part way (dev seed 87: one station's 148 mm off, three pooled 11 mm)
    lever_from_turns: bool = True
    #: ... its stations (those turned most) and sweep pairs a station
    lever_turn_stations: int = Field(default=8, ge=1)
    lever_turn_pairs: int = Field(default=32, ge=3)
    #: ... used when its larger 1-sigma across the pan axis is below this [mm] (else one
    #: station's). The one station's is the same equations on a subset of the same kind of
    #: pairs (unweighted): with the calibration's smoothed sweeps it was 100-350 mm off on the
    #: dev halls whose turns' sigma was 32-48 mm (455, 8399, 383: the turns 23-33 mm off, the
    #: fit from them 7-8 mm). 100: half the range of lever arms (0-20 cm), beyond which neither
    #: start says much (15 until stop 34)
    lever_turn_max_sigma_mm: float = Field(default=100.0, gt=0)
    #: the turns' time offset measured again once the lever-arm fit's start comes from the turns
    #: (``lever_from_turns``) and lies more than this [mm] from the lever arm the turns' sweeps
    #: were de-skewed with (one station's hand-eye, often 5-15 cm off): a wrong lever arm leaves
    #: each 0.1-s sweep smeared by the head's swing (pan rate x lever error x 0.1 s, ~1 cm), a
    #: smear that grows with the pan rate and so turns the pair's registration by an angle
    #: proportional to the rate change, as a time offset does (issue 12: dev seeds 40 and 631's
    #: turns 1.8 / 2.1 ms off with hand-eye's lever, 0.1 / 1.5 with the true one). 0 (default):
    #: off, the turns' offset from hand-eye's lever arm only. 20 on 10 dev rigs end to end (40
    #: 83 87 171 631 608 609 612 613 614): median 0.68 -> 0.36 ms but RMS 0.98 -> 0.96, within
    #: 1 ms 7 -> 7, 609 1.02 -> 2.09 (the turns' lever is still cm off along the spin axis, and a
    #: re-measure moves the turns' estimate by their noise), +0-20 CPU-s a rig: opt-in
    turn_relever_mm: float = Field(default=0.0, ge=0)
    #: the turns' time offset measured again after the surfaces' fit, de-skewed with its lever
    #: arm (within ~5 mm; hand-eye's is often 5-15 cm off, whose smear biases the turns on side
    #: mounts, see ``turn_relever_mm``) and mount, and that measurement made the result: alone,
    #: or joined by inverse variance with the surfaces' own estimate when that is sure and agrees
    #: (the surfaces' posterior with the first turns' prior taken out, so the turns count once).
    #: One more turns pass (+0-13 CPU-s a rig). 10 dev rigs end to end (40 87 171 83 631 608 609
    #: 612 613 614): median 0.68 -> 0.25 ms, RMS 0.98 -> 0.83, within 1 ms 7 -> 8, worst 1.88 ->
    #: 1.72 (83 1.88 -> 0.69, 608 0.91 -> 0.10; 609 1.02 -> 1.72), lever arm and ATE unchanged.
    #: On by default (stop 37, i12-offset3; false: the joint fit's offset as before)
    turn_remeasure_after_surfaces: bool = True
    #: the surfaces' own time offset (the joint fit's with the turns' prior taken out, or the
    #: surfaces' alone) weighs in the joins with the turns with at least this sigma [ms]: their
    #: sigma is the residuals' over the fit's information and counts no model error (a yaw
    #: error hides in walls seen head-on). Whether it joins (``max_time_offset_sigma_ms``, the
    #: 3-sigma agreement) is still judged with its own sigma. 0 (default): its own sigma
    #: (stop 40, i12-offset7; opt-in)
    surface_time_sigma_floor_ms: float = Field(default=0.0, ge=0)
    #: ... and, when it disagrees with the turns' by d, its sigma widened to at least
    #: sqrt(d² − σ_turns²) (the two then agree within one combined sigma: a Birge-ratio
    #: inflation), so a sure but wrong surfaces' estimate cannot take ~95 % of the weight a few
    #: milliseconds from the turns'. False (default): as before (opt-in)
    surface_time_consistency: bool = False
    #: ... and then its component along the spin axis joins the surfaces' by inverse variance,
    #: the surfaces' sigma there times this (they see it only at vertical edges: 1-8 sigma off
    #: on seven dev rigs, the turns' 0.2-1.6 sigma)
    lever_spin_sigma_inflation: float = Field(default=3.0, gt=0)
    #: ... and with this [mm] added in quadrature: a model-error floor. The inflated sigma
    #: still shrinks with the sample (``side_points_per_station``) while the fit's error there
    #: does not: the side-room test (4 x 4 m, 83°) came out 3.3 and 3.5 mm off on two sample
    #: seeds with 160,000 points at an inflated sigma of 1.2 mm (80,000: 1.1-3.0 mm off at
    #: 2.4 mm), a bias of the fit, not its sampling noise. On 8 dev side rigs at 160,000
    #: (floor 0) the spin-axis error was 0.0-3.4 of its sigma (455 5.6 mm at 1.9, 8399 8.0 at
    #: 2.3); the floor leaves the estimate within 0.3 mm there but 205 (1.7 -> 2.9 mm: the
    #: turns weigh more). 0: none (until stop 36)
    lever_spin_sigma_floor_mm: float = Field(default=2.0, ge=0)
    #: sample points a station in the surfaces' fit (``self_calibrate``) on a lidar at least
    #: ``side_mount_warn_deg`` from the pan axis (80,000 below that, always). Such a mount sees
    #: the lever arm along its spin axis only at vertical edges, and a hall's walls spread
    #: 80,000 points thinly over the fit's 0.25-m voxels (at least 10 points each): there the
    #: component was mostly sampling noise (dev 8399, 37 x 14 m hall, 86°, 4 sample seeds:
    #: 0.2-17.2 mm off with 80,000, 7.7-9.7 mm with 160,000). 160,000 brought dev 455, 383, 87,
    #: 631 from 6.8, 7.4, 15.3, 5.1 to 3.8, 2.6, 6.1, 0.6 mm (+1-4 CPU s a rig); 8399's bay
    #: alias it exposed is resolved (``odometry.seed_wide_extent_m``). The default since stop 36
    #: (80,000 before, opt-in at stop 35): the side-room test's lever arm 3.1 mm off at sigma
    #: 1.1 mm is answered by ``lever_spin_sigma_floor_mm``; the box room's fragments 180 deg off
    #: were a near tie of global registration (its 180° twin on 2 of 10 RANSAC seeds with
    #: 80,000, 3 of 10 with 160,000; test_gravity_up.py), not the calibration
    side_points_per_station: int = Field(default=160_000, ge=1000)
    #: sample points a station in the surfaces' fit on a lidar less than ``side_mount_warn_deg``
    #: from the pan axis (with ``tilt_range_weight_exp``: dev 722's first fit 0.13-0.16° off at
    #: 80,000 on four sample seeds, 0.005-0.014° at 100,000; i12-tiltbias, stop 39; the default
    #: since stop 40, 80,000 before)
    near_points_per_station: int = Field(default=100_000, ge=1000)
    #: fit the IMU's heading drift [rad/s about the world's vertical] with the lever arm, time
    #: offset and mount in the surfaces' fit (a nuisance parameter, not applied elsewhere).
    #: Held at zero, a drift turns a pan's end against its start, which a lidar on its side's
    #: lever arm along the spin axis takes up in part (a 12 x 10 m hall, 85°, 4°/min over 6-s
    #: pans: 1.8 mm; fitted: 0.1 mm, the drift within 3 %). Off: on the dev halls the drift is
    #: not what leaves them 7 mm off (the fit's sampling noise is; stop 35, README), and fitted
    #: it came out with the wrong sign on 2 of 6 dev rigs and left 383 4 mm further off
    fit_yaw_drift: bool = False
    #: ... with a prior 0 ± this [deg/min] (a guard against a drift the data hardly see)
    yaw_drift_prior_deg_per_min: float = Field(default=10.0, gt=0)
    #: on a lidar at least ``side_mount_warn_deg`` from the pan axis, a lever-arm fit (without
    #: split residuals) whose result is more than this [mm] across the pan axis from its start is
    #: continued from that result with ``lever_refit_split_iterations`` split-residual
    #: iterations: the all-points planes close a start far off in the scan plane only part way
    #: (dev seed 455, a 33 x 23 m hall, 73°, 19-cm lever started from 0: moved 54 mm, ended
    #: 135 mm off; continued: 10 mm). Not lower: from a near start the split fit can drift (dev
    #: seed 383, moved 31 mm: 5 -> 21 mm off if continued); 0: off
    lever_refit_move_mm: float = Field(default=40.0, ge=0)
    #: ... the continuation's split-residual iterations (each a Gauss-Newton step)
    lever_refit_split_iterations: int = Field(default=4, ge=1)
    #: ... then this many of the usual ones (all points' planes)
    lever_refit_usual_iterations: int = Field(default=8, ge=0)
    #: ... and the continuation replaces the first fit only when it moved the lever arm more
    #: than this [mm] further across the pan axis (the first had stopped part way: dev seeds 455
    #: 125 mm, 38 134 mm, 31 110 mm, the side-room test 63 mm); a smaller move means the first
    #: had converged and the split fit drifted from it (dev seed 40, a 27-m corridor at 87°: 32
    #: mm further, 9.1 -> 26.9 mm off, ATE 1.04 -> 2.53 cm; 245 2.9 -> 7.3 mm; 383 16 mm further;
    #: 97, 98 0-1 mm; 30 until a wider dev sweep found 40)
    lever_refit_keep_mm: float = Field(default=50.0, ge=0)
    #: ... and continued whatever its move when its start was not the turns' lever arm (their
    #: sigma over ``lever_turn_max_sigma_mm``, none, or ``lever_from_turns`` off: one station's
    #: hand-eye lever arm, centimetres off on such a mount). The all-points planes hardly see
    #: the lever arm along the spin axis: on dev seed 8399 (37 x 14 m hall, 86°, 14-cm lever,
    #: true mount and offset given) they move a start 75 mm off there 8 mm whichever side it
    #: lies, and its first fit moved 21 mm (85 -> 83 mm off); continued, 55 mm further, kept:
    #: 29 mm). A converged fit is kept by ``lever_refit_keep_mm`` (dev seed 383, also started
    #: from one station: its continuation drifts 16 mm and is dropped, bit-identical). Rigs
    #: started from the turns keep the movement gate alone; off: the movement gate alone
    lever_refit_uncertain_start: bool = True
    #: a mount tilt that ``max_stations`` stations' surfaces do not pin down (sigma over 0.05°:
    #: a spin axis near the pan axis in a small room) is fitted again on up to this many stations
    max_tilt_stations: int = Field(default=8, ge=1)
    #: ... and then taken from the surfaces, mixed with hand-eye's by their variances, when its
    #: sigma times this is below hand-eye's (the pairs' axis scatter); else hand-eye's is kept.
    #: The surfaces' sigma is optimistic (a voxel's points share its plane): 2-3x on dev rigs
    tilt_sigma_inflation: float = Field(default=2.0, gt=0)
    #: off: hand-eye's tilt is kept whenever the surfaces' sigma is over 0.05° (the old rule)
    tilt_from_surfaces: bool = True
    #: on a lidar whose spin axis lies within this angle [deg] of the pan axis, the surfaces'
    #: tilt sigma is at least the spread of the stations' own fits (each station fitted alone
    #: from the joint result; sigma of their mean): the model's sigma counts every voxel as
    #: independent and missed a bias the stations do not share (dev seed 722, a near-vertical
    #: lidar in a corridor: 0.78° off at sigma 0.03°; its stations' own fits 0.06-1.13° off;
    #: with it hand-eye's tilt is kept: 16.1 -> 0.72 cm / 0.77 -> 0.10°; dev 1042, also a
    #: corridor: 3.86 -> 0.57 cm / 0.36 -> 0.02°; the other near-vertical dev rigs 0, 2, 694,
    #: 721 within 0.1 mm / better in angle; side mounts skip it). Cost: the stations fitted
    #: again (+5-15 CPU-s a capture on those rigs). 0: off (the model's sigma alone, the old rule)
    tilt_spread_max_deg: float = Field(default=30.0, ge=0, le=90)
    #: on a lidar less than ``side_mount_warn_deg`` from the pan axis, the surfaces' fit draws its
    #: sample points max(1, r / 3 m) ** this times as densely at range r (the same number of
    #: points). Such a lidar sees its mount tilt mostly at the floor and ceiling (73-92 % of the
    #: tilt information on dev 722 / 1351), the far parts of which, with a uniform 80,000 points
    #: a station, rarely fill the 0.25-m voxels' 10-point minimum: the fit then rests on the
    #: near ones and its tilt was biased toward the pan axis (722 0.78°, 1351 0.35°; 240,000
    #: points: 0.03 / 0.02°). 2: 722 0.12°, 1351 0.007° at the same cost (i12-tiltbias, stop 39).
    #: 0: a uniform sample (the default until stop 40; 2 since, with ``near_points_per_station``
    #: 100,000, ``odometry.height_seed_gate_m`` and ``slam.loop_sigma_floor_deg``: the 20 dev
    #: rigs of stop 40 19 -> 20 within 1 cm and 0.1°, lever arm 17 -> 19 within 5 mm)
    tilt_range_weight_exp: float = Field(default=2.0, ge=0, le=6)
    #: Gauss-Newton iterations of each station's own fit for ``tilt_spread_max_deg`` (started
    #: from the joint result; the first ones on coarser voxels, as every surfaces' fit). Dev
    #: seeds 0, 2, 721, 722, 1042, 1465: 5 gives every accuracy field of 8 to the bit at ~3 CPU-s
    #: less a capture (the calibration 19.2 -> 16.2 on 722); 3 does not (722 0.10 -> 0.41°)
    tilt_spread_iterations: int = Field(default=5, ge=1, le=32)
    #: the mount's turn about the pan axis from the carries' sweep pairs
    #: (``calibration.mount_yaw_from_carries``): no station sees it (the head turns about that
    #: axis only), so hand-eye's noise stayed in it (dev seeds 83, 87, 40, 609: 1.2-2.2°) and
    #: a lever arm read in the IMU frame turned with it (87: 20-cm lever, 5.9 mm off, 0.9 mm in
    #: the lidar frame). The carried tripod turns about every axis: the mount and, when
    #: estimated, the lever arm are turned together by the carries' angle (every station's
    #: geometry unchanged). Off: hand-eye's turn about the pan axis, as before
    mount_yaw_from_carries: bool = True
    #: carry sweep pairs a carry for it (up to 8 carries, the longest)
    mount_yaw_pairs_per_carry: int = Field(default=16, ge=1)
    #: ... applied only when its sigma is within this [deg]
    mount_yaw_max_sigma_deg: float = Field(default=1.0, gt=0)


class StationConfig(StrictModel):
    #: lidar stationarity test: a 0.1 s window of points, rotated by the IMU about the head's
    #: pivot, is "still" when the pivot shift fitted to the range changes along the directions
    #: it shares with the window ``still_gap_s`` earlier (less the lever arm's own apparent
    #: shift) is below this [m]
    still_threshold: float = Field(default=0.02, gt=0)
    still_gap_s: float = Field(default=0.5, gt=0)
    #: ... and the head swings off its pan axis (IMU) by less than this [deg] in that time
    still_tilt_deg: float = Field(default=0.25, gt=0)
    #: largest IMU time offset error [ms] the lidar test tolerates where the pan rate changes (a
    #: reversal, a pause): such windows are refitted with a turn about the pan axis of up to
    #: this times the rate change free (0: off)
    max_time_offset_error_ms: float = Field(default=12.0, ge=0)
    #: shortest station [s] (the still period, before trimming); shorter still periods are
    #: reported and not used
    min_station_s: float = Field(default=2.5, gt=0)
    #: seconds trimmed from both ends of a station (the tripod settling)
    trim_s: float = Field(default=0.5, ge=0)
    #: use the daemon's ``mark`` events when present (each station is matched to its mark)
    use_marks: bool = True


class FragmentConfig(StrictModel):
    #: voxel [m] of a fragment as kept for registration and output
    voxel_m: float = Field(default=0.02, gt=0)
    #: ranges smoothed along each laser's scan line over this many firings either side before
    #: placement (``decode.scanline``; ±1° at 600 rpm for 5; a neighbour far away in range
    #: is left out: depth edges kept): the VLP-16's ~3 cm range noise otherwise leaves every
    #: surface a layer as thick as the noise, which the map's smoothing does not take out. On
    #: the 11 development rigs of bench/rigs.py (2 126 171 205 5 0 1 3 8 82 91) 5 took the
    #: map-to-mesh median from 8.0 to 1.6 mm (small rooms 10-16 mm to 1.2-1.6) and the station
    #: ATE from 0.24 cm / 0.056° to 0.19 cm / 0.034° (medians), for ~0.04 s of CPU per second
    #: of station. 0: off (the decoder's points as they are)
    range_denoise_firings: int = Field(default=5, ge=0, le=50)
    #: the scan line's local fit: ``mean`` (least noise; biased outward where the range curves
    #: along the line, and by the slope where the window is cut short: a far or oblique wall),
    #: ``linear`` (no slope bias; the mean on a full window) or ``quadratic`` (no curvature
    #: bias either, ~2x the mean's noise variance). The mean, as the calibration's: on the 11
    #: dev rigs map-to-mesh median 1.5 mm (linear 1.6; a hall and a corridor, dev 8 and 82, 3.2 /
    #: 1.9 mm against linear's 2.2 / 1.5), and global registration of the side-mounted test
    #: capture's fragments (tests/processor/test_gravity_up.py's rig, 12 pairs over three mounts)
    #: took the 180° twin on 1 pair with the mean, 3 with the line, 2 unsmoothed
    range_denoise_fit: Literal["mean", "linear", "quadratic"] = "mean"
    #: a neighbour farther than this [m] in range from the point is left out of its fit (a
    #: depth edge); 0.15 is 5 sigma of the noise: a tighter test cuts the window short at
    #: random where the range climbs along the line (a wall seen at 30°+ incidence)
    range_denoise_max_step_m: float = Field(default=0.15, gt=0)
    #: in process on more than one thread: every station's chunks (decode, smoothing,
    #: placement) on one pool while each station is voxel-filtered as its chunks come in,
    #: instead of the stations side by side, one a thread (whose longest station finishes
    #: alone); the same fragments to the bit (``reconstruction.fragments``)
    chunk_pipeline: bool = True


class OdometryConfig(StrictModel):
    #: registration method of the core (gicp, plane, icp, symmetric, lm)
    method: Literal["gicp", "plane", "icp", "symmetric", "lm"] = "gicp"
    #: range noise [m] assumed by the registration (whitening, information)
    point_sigma_m: float = Field(default=0.03, gt=0)
    #: weight of the IMU rotation prior [deg] (its yaw drifts during a carry)
    rotation_prior_sigma_deg: float = Field(default=3.0, gt=0)
    #: coarse-to-fine voxels [m] of the core's registration (the max correspondence distance is
    #: 3x the voxel); every start runs the first two, the best one the rest
    voxels_m: list[float] = Field(default_factory=lambda: [0.6, 0.3], min_length=1)
    #: hold z of the translation at the prior (the original system's z-lock); off by default
    lock_z: bool = False
    #: grid cell [m] of the top-down correlation that seeds the translation
    seed_cell_m: float = Field(default=0.1, gt=0)
    #: half-width [m] of the top-down images that seed the translation (about each fragment's
    #: origin): a carry much longer than this puts the true shift outside what they can find
    seed_extent_m: float = Field(default=16.0, gt=0)
    #: when the best start from those seeds does not respect free space (``free_space_check``),
    #: the seeds again from images this wide [m] (0: never): dev seed 8399 (37 x 14 m hall of repeating
    #: bays, 16.2-m carry) had no seed near the truth in the 16-m images and took an alias 5.2 m
    #: off (overlap 79 %, 4.9 % of its points in the other station's free space); from 32-m
    #: images the truth is the first seed (99.6 %, 0.01 %)
    seed_wide_extent_m: float = Field(default=32.0, ge=0)
    #: floor of the edge standard deviations [m], [deg] (registration information is capped)
    sigma_floor_m: float = Field(default=0.003, gt=0)
    sigma_floor_deg: float = Field(default=0.03, gt=0)
    #: cap the oriented refine's translation information by its surface support counted per
    #: patch, not per point (``odometry.patch_support_information``): each ``patch_cell_m``
    #: cell of the overlap is one measurement of ``patch_sigma_m`` along the normals it holds
    #: (a share of at least ``patch_normal_share``; a wall's noisy normals add nothing
    #: vertical). 0: off (the per-point information, capped only at ``sigma_floor_m``). Dev
    #: seed 722's pair round a corridor's corner (0.6 % of its points on horizontal surfaces)
    #: claimed sigma_z 2.7 mm and slipped 5.7-6.4 cm
    patch_sigma_m: float = Field(default=0.0, ge=0)
    patch_cell_m: float = Field(default=0.5, gt=0)
    patch_normal_share: float = Field(default=0.1, ge=0, lt=1)
    #: the largest sigma [m] the patch cap gives a direction no patch supports
    patch_sigma_max_m: float = Field(default=0.2, gt=0)
    #: probe a pair's translation direction with the least patch support (the smallest
    #: eigenvalue of ``odometry.patch_support`` under ``flat_probe_support`` cells): the
    #: oriented refine again from the result moved +-``flat_probe_m`` along it (rotation
    #: held); how far a start stays is that direction's sigma (``cap_flat_direction``). 0: off
    flat_probe_m: float = Field(default=0.0, ge=0)
    flat_probe_support: float = Field(default=8.0, ge=0)
    #: a pair whose registration (the GICP stages' information) leaves its height (along the
    #: world's up) less determined than this sigma [m] takes the height of its fragments'
    #: horizontal surfaces (``odometry.horizontal_height_shift``: floor and ceiling wherever
    #: each fragment sees them), held through the last stages, and claims
    #: ``height_seed_sigma_m`` along up in the pose graph. 0: off. Dev seed 722's pair round a
    #: corridor's corner (near-vertical lidar): sigma_up 4.1 cm, the coarse GICP pulled the
    #: seed's 0.3-cm height error to 6.9 cm (0.1 cm with this at 0.01; the default since stop
    #: 40, 0 before)
    height_seed_gate_m: float = Field(default=0.01, ge=0)
    height_seed_sigma_m: float = Field(default=0.01, gt=0)
    #: finish every pair with point-to-plane ICP on oriented normals (6 cm voxels): surfaces
    #: seen from opposite sides (a wall between two rooms) are never paired
    oriented_refine: bool = True
    #: a loop closure registered from the map's guess is kept when it moves less than this [m]
    guess_radius_m: float = Field(default=0.5, gt=0)
    #: ... and overlaps at least this much; a weaker one competes with the top-down seeds, which
    #: must beat its overlap by ``guess_margin`` (a guess from a map that a wrong odometry pair
    #: put wrong converges near itself at a low overlap)
    guess_min_fitness: float = Field(default=0.5, ge=0, le=1)
    guess_margin: float = Field(default=0.2, ge=0)
    #: below this overlap (fitness) a pair is taken as not registered
    min_fitness: float = Field(default=0.3, ge=0, le=1)
    #: check each pair's candidate poses against free space (``free_space``): a candidate that
    #: puts more than ``max_free_space_violation`` of either fragment's points where the other
    #: station saw through loses to one that does not, whatever their overlap (a corridor slid
    #: along its axis overlaps well and is wrong)
    free_space_check: bool = True
    max_free_space_violation: float = Field(default=0.005, ge=0, le=1)
    #: a pair of stations whose anchor tilts are fitted over their IMU samples
    #: (``placement.anchor_fit``) is finished at the IMU's relative tilt, its translation
    #: refitted with the rotation held (``odometry.tilt_refit``): in a small room the
    #: fragments' range noise tilts a registration by 0.1-0.6° (the IMU's: 0.006°)
    tilt_from_imu: bool = True
    #: a pair that respects free space is registered down to this overlap (a station round a
    #: corridor's corner shares little with the one before it)
    min_fitness_free_space: float = Field(default=0.15, ge=0, le=1)
    #: when no candidate respects free space, the one with the best overlap less this x its
    #: violation beyond ``max_free_space_violation`` wins (0: the best overlap)
    free_space_weight: float = Field(default=10.0, ge=0)


class SlamConfig(StrictModel):
    enabled: bool = True
    #: loop candidates: station pairs closer than this [m] (after odometry), not consecutive
    loop_radius_m: float = Field(default=8.0, gt=0)
    max_loops_per_station: int = Field(default=2, ge=0)
    loss: Literal["none", "huber", "cauchy", "soft_l1"] = "cauchy"
    loss_scale: float = Field(default=4.74, gt=0)
    outlier_chi2: float = Field(default=22.46, gt=0)
    #: odometry edges are robust and rejectable too (when the graph stays connected without
    #: them): loops around a wrong odometry edge outvote it
    robust_odometry: bool = True
    #: start the pose graph from the chain that most edges agree with (``slam.consensus_initial``):
    #: an odometry pair that loops agreeing with each other contradict is left out of the start
    #: (a robust graph started from a chain metres off keeps the chain and drops the loops)
    loop_consensus: bool = True
    #: an edge agrees with a start when within this [m] and [deg] of it
    consensus_m: float = Field(default=0.3, gt=0)
    consensus_deg: float = Field(default=3.0, gt=0)
    #: tilt sigma of the IMU's gravity priors [deg] (a station whose anchor attitude is one
    #: slerped IMU sample: 0.05° of white noise per axis)
    gravity_sigma_deg: float = Field(default=0.1, gt=0)
    #: ... of a station whose anchor tilt is fitted over all of its IMU samples
    #: (``placement.anchor_fit``: ``Fragment.anchor`` "fit" or "fit, pan slerped") [deg]: 0.006°
    #: RMS off the truth on dev seed 126's eight stations, where the registrations' tilts were
    #: 0.1-0.6° off (``slam.tilt_free_information``); 0: ``gravity_sigma_deg`` for every station
    gravity_sigma_fitted_deg: float = Field(default=0.01, ge=0)
    #: an edge between two stations with fitted anchors carries no tilt: its information's two
    #: tilt directions (about the world's horizontal axes) are marginalised out, so the
    #: stations' tilts come from the IMU and the registrations give yaw and position only (in a
    #: small room the fragments' range noise tilts a registration by 0.1-0.6°, which the capped
    #: information claimed at 0.03°); off: every edge's full information
    tilt_from_imu: bool = True
    #: floors of a loop closure's standard deviations [m], [deg] (its information capped there,
    #: as ``odometry.sigma_floor_*`` caps every pair's); 0: the odometry's floors. A loop joins
    #: stations farther apart over a smaller overlap than an odometry pair: dev seed 722's loop
    #: 1->3 (round a corridor's corner, the overlap one corner 4-5 m from both) was 1.9 cm and
    #: 0.27° off in yaw at the odometry's 3 mm / 0.03°, where its odometry pairs were 0.02°
    #: (0.1° is the default since stop 40: 722 0.72 cm / 0.100° -> 0.56 / 0.061° with the
    #: height gate and the range-weighted tilt sample; 1 cm as well moved rooms, dev 2 0.125 ->
    #: 0.147 cm, so the metres' floor stays the odometry's)
    loop_sigma_floor_m: float = Field(default=0.0, ge=0)
    loop_sigma_floor_deg: float = Field(default=0.1, ge=0)


class OutputConfig(StrictModel):
    map_voxel_m: float = Field(default=0.03, gt=0)
    #: moving-least-squares smoothing radius of the merged map [m] (0: off). Range noise of a
    #: VLP-16 (~3 cm) leaves a layer as thick as the noise; MLS projects it onto the surface.
    smooth_radius_m: float = Field(default=0.15, ge=0)
    #: MLS surfaces are fitted at the centroids of voxels this size [m] and each point is
    #: projected onto its nearest one (0: a fit per point, ~6x slower on a 3 cm map)
    smooth_fit_voxel_m: float = Field(default=0.075, ge=0)
    write_pcd: bool = True
    write_fragments: bool = True
    write_mcap: bool = True
    trajectory_hz: float = Field(default=20.0, ge=10.0)
    report: bool = True
    #: survey deliverables (``reconstruction.survey``; ``tripod reconstruct --survey`` turns
    #: both on): stations.e57, one scan per station with its pose; the map as LAS 1.4 (``las``),
    #: LAZ (``laz``) or not at all (``none``). Off by default: the per-voxel intensity, station
    #: and labels cost about half the CPU time of a reconstruction again (bench/survey.py)
    write_e57: bool = False
    write_las: Literal["laz", "las", "none"] = "none"
    #: segmentation labels (ceiling/floor/wall/other) in the survey files (LAS classification,
    #: E57 ``tripod:label``); off: every point "never classified"
    survey_labels: bool = True


class ReconstructConfig(StrictModel):
    """Root config of ``tripod reconstruct``."""

    num_threads: int = Field(default=0, ge=0)  # 0 = all cores
    placement: PlacementConfig = PlacementConfig()
    stations: StationConfig = StationConfig()
    calibration: CalibrationConfig = CalibrationConfig()
    fragments: FragmentConfig = FragmentConfig()
    odometry: OdometryConfig = OdometryConfig()
    slam: SlamConfig = SlamConfig()
    output: OutputConfig = OutputConfig()
