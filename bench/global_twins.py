# SPDX-License-Identifier: BSD-3-Clause
"""Global registration in symmetric-ish rooms: how often the 180 deg twin is picked.

Station pairs of simulated (digital-twin) rooms, ray-cast with the VLP-16 beam model
(:func:`tripod_processor.sim.station_scan.station_scan`), two stations on the scene's route
1.5-4 m apart with uniformly random yaws, registered with gravity (``register_global(...,
gravity_aligned=True)``) on several RANSAC seeds, then refined with point-to-plane ICP as
``tripod register --global --gravity --method plane`` does. Printed per scene family: success
(within 1 deg / 5 cm of the truth after refinement), the 180 deg twin picked (rotation error
within 10 deg of 180), other failures, pairs flagged ambiguous, and the mean time of the global
step.

Scene families (scene seeds are development seeds, 0-9999):

- ``column_room``: a box room with one column and two pieces of furniture against the walls
  (the shape of the tests' capture room, dimensions and positions drawn);
- ``room``: the simulator's furnished room (``make_scene("room", seed)``);
- ``office``: the simulator's office.

    .venv/bin/python bench/global_twins.py --scene-seeds 0 1 2 3 --ransac-seeds 0 1 2
    .venv/bin/python bench/global_twins.py --set twin_check=False   # the old pick
    .venv/bin/python bench/global_twins.py --diagnose                # truth vs twin metrics
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

#: head tilts about the lidar x axis [deg]: six revolutions whose 30 deg bands cover the sphere
#: (a tripod fragment is a full panorama; ±20 deg tilts alone leave floor and ceiling unseen)
TILTS = (0, 30, 60, 90, 120, 150)


def column_room(seed: int):
    """A box room (5-9 x 4-7 x 2.5-3.0 m) with a 0.4 m column off-centre, a cabinet and a
    shelf against the walls."""
    from tripod_processor.sim.scenes import OTHER, MeshBuilder

    rng = np.random.default_rng([seed, 0xC01])
    w, d, h = rng.uniform(5.0, 9.0), rng.uniform(4.0, 7.0), rng.uniform(2.5, 3.0)
    mb = MeshBuilder()
    mb.floor_plan([(0, 0, w, d)], h)
    cx, cy = rng.uniform(1.5, w - 1.9), rng.uniform(1.5, d - 1.9)
    mb.box((cx, cy, 0.0), (cx + 0.4, cy + 0.4, h), OTHER)
    bx = rng.uniform(0.3, w - 1.6)
    mb.box((bx, d - 0.8, 0.0), (bx + 1.2, d - 0.02, 0.75), OTHER)
    sy = rng.uniform(0.3, d - 1.7)
    mb.box((0.02, sy, 0.0), (0.6, sy + 1.4, 1.9), OTHER)
    m = 1.0
    route = [(m, m), (w - m, m), (w - m, d - m), (m, d - m)]
    return mb.build("column_room", route, True, {"width_m": w, "depth_m": d, "height_m": h,
                                                  "column_xy": (cx, cy)}, rng)


def make(family: str, seed: int):
    from tripod_processor.sim.scenes import make_scene

    return column_room(seed) if family == "column_room" else make_scene(family, seed)


def _inside(scene, xy, margin=0.0) -> bool:
    """Within the route's bounding box (grown by margin): clear of the walls and furniture."""
    r = scene.route
    lo, hi = r.min(axis=0), r.max(axis=0)
    return bool(np.all(xy >= lo - margin) and np.all(xy <= hi + margin))


def station_pair(family: str, seed: int):
    """(source points, target points, T_target_source truth, scene) of one pair."""
    from tripod_processor.sim.station_scan import pose, station_scan

    scene = make(family, seed)
    rng = np.random.default_rng([seed, 0x7A1])
    r = scene.route
    lo, hi = r.min(axis=0), r.max(axis=0)
    for _ in range(100):
        a = rng.uniform(lo, hi)
        ang = rng.uniform(0, 2 * np.pi)
        b = a + rng.uniform(1.5, 4.0) * np.array([np.cos(ang), np.sin(ang)])
        if _inside(scene, b, 0.0):
            break
    T_t = pose(rng.uniform(-180, 180), (a[0], a[1], 1.3))
    T_s = pose(rng.uniform(-180, 180), (b[0], b[1], 1.3))
    tgt = station_scan(scene, T_t, TILTS, azimuth_step_deg=0.4, seed=2 * seed + 1)
    src = station_scan(scene, T_s, TILTS, azimuth_step_deg=0.4, seed=2 * seed + 2)
    return src, tgt, np.linalg.inv(T_t) @ T_s, scene


def errors(T, G):
    E = np.linalg.inv(G) @ T
    rot = float(np.degrees(np.arccos(np.clip((np.trace(E[:3, :3]) - 1) / 2, -1, 1))))
    return rot, float(np.linalg.norm(E[:3, 3]))


def refine(reg, src, tgt, T0, voxel):
    return reg.register(src, tgt, method="plane", init=T0, voxel_size=voxel, num_threads=1)


def parse_set(items):
    out = {}
    for it in items or []:
        k, v = it.split("=", 1)
        if v in ("True", "False"):
            out[k] = v == "True"
        elif "," in v:
            out[k] = tuple(float(x) for x in v.split(",") if x)
        else:
            try:
                out[k] = int(v)
            except ValueError:
                out[k] = float(v)
    return out


def _old_pick(reg) -> dict:
    import inspect

    return ({"twin_check": False}
            if "twin_check" in inspect.signature(reg.register_global).parameters else {})


def diagnose(reg, src, tgt, G, voxel):
    """Truth and its 180 deg twin, each found by a restricted global registration and refined:
    the metrics a pick could use."""
    from tripod_processor.sim.station_scan import pose

    rows = {}
    for name, turn in (("truth", 0.0), ("twin", 180.0)):
        Rp = pose(turn)[:3, :3] @ G[:3, :3]
        g = reg.register_global(src, tgt, voxel_size=voxel, gravity_aligned=True, seed=0,
                                rotation_prior=Rp, rotation_tolerance=np.radians(20),
                                num_threads=1, **_old_pick(reg))
        if not g.success:
            rows[name] = None
            continue
        r = refine(reg, src, tgt, g.T_target_source, voxel)
        rows[name] = {"fit": round(g.fitness, 4), "feat_inl": g.num_inlier_correspondences,
                      "ref_fit": round(r.fitness, 4), "ref_rmse": round(r.inlier_rmse, 4),
                      "err": [round(x, 2) for x in errors(r.T_target_source, G)]}
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--families", nargs="+", default=["column_room", "room", "office"])
    ap.add_argument("--scene-seeds", nargs="+", type=int, default=[0, 1, 2, 3, 4, 5])
    ap.add_argument("--ransac-seeds", nargs="+", type=int, default=[0, 1, 2])
    ap.add_argument("--voxel", type=float, default=0.1)
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE",
                    help="extra register_global options (e.g. twin_check=False, "
                         "twin_turns_deg=90,180,270)")
    ap.add_argument("--diagnose", action="store_true")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    if any(s >= 10000 for s in args.scene_seeds):
        ap.error("development scene seeds only (0-9999)")
    from tripod_processor.registration import pairwise as reg

    extra = parse_set(args.set)
    trials = []
    for fam in args.families:
        stats = {"n": 0, "ok": 0, "twin": 0, "other": 0, "ambiguous": 0, "checked": 0, "ms": []}
        for s in args.scene_seeds:
            src, tgt, G, _ = station_pair(fam, s)
            if args.diagnose:
                print(fam, s, json.dumps(diagnose(reg, src, tgt, G, args.voxel)), flush=True)
            for rs in args.ransac_seeds:
                t0 = time.perf_counter()
                g = reg.register_global(src, tgt, voxel_size=args.voxel, gravity_aligned=True,
                                        seed=rs, num_threads=1, **extra)
                ms = (time.perf_counter() - t0) * 1e3
                r = refine(reg, src, tgt, g.T_target_source, args.voxel)
                rot, tr = errors(r.T_target_source, G)
                ok = rot < 1.0 and tr < 0.05
                twin = abs(rot - 180) < 10
                amb = bool(getattr(g, "ambiguous", False))
                checked = bool(getattr(g, "twins", ()))
                stats["n"] += 1
                stats["ok"] += ok
                stats["twin"] += twin
                stats["other"] += not ok and not twin
                stats["ambiguous"] += amb
                stats["checked"] += checked
                stats["ms"].append(ms)
                trials.append({"family": fam, "scene_seed": s, "ransac_seed": rs, "ok": ok,
                               "twin": twin, "rot_deg": rot, "trans_m": tr, "ambiguous": amb,
                               "checked": checked, "fitness": g.fitness, "feat_inl": g.num_inlier_correspondences,
                               "ms": ms})
                if args.diagnose or not ok:
                    print(f"  {fam} scene {s} ransac {rs}: rot {rot:.2f} deg, {tr:.3f} m, "
                          f"fit {g.fitness:.3f}, feat {g.num_inlier_correspondences}, "
                          f"ambiguous {amb}, checked {checked}", flush=True)
        print(f"{fam:12s} n {stats['n']:3d}  ok {stats['ok']:3d} ({100 * stats['ok'] / max(1, stats['n']):.0f} %)"
              f"  twin {stats['twin']:3d}  other {stats['other']:3d}  ambiguous "
              f"{stats['ambiguous']:3d}  twin-checked {stats['checked']:3d}  global "
              f"{np.mean(stats['ms']):.0f} ms", flush=True)
    n = len(trials)
    print(f"{'all':12s} n {n:3d}  ok {sum(t['ok'] for t in trials):3d}  twin "
          f"{sum(t['twin'] for t in trials):3d}  other "
          f"{sum(not t['ok'] and not t['twin'] for t in trials):3d}  ambiguous "
          f"{sum(t['ambiguous'] for t in trials):3d}  twin-checked "
          f"{sum(t['checked'] for t in trials):3d}  global "
          f"{np.mean([t['ms'] for t in trials]):.0f} ms")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"args": vars(args), "trials": trials}, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
