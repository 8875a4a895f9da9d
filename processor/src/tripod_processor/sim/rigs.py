# SPDX-License-Identifier: BSD-3-Clause
"""A family of rigs and captures drawn at random from a seed (issue 12's ranges).

``draw_rig(seed)`` gives a :class:`SimConfig`: the mount (spin axis tilted 0-90 deg from the pan
axis), the lever arm (0-20 cm from the pan axis, any direction), the IMU latency (0-10 ms) and
jitter, the pan (a motor or a hand-turned head, a pause or a reversal inside it, 0.9-1.2 turns),
stations of 4-60 s (the pan), carries of 2-30 s (slow and careful or quick), the scene (a small
room, a room, a hall up to 40 m, a straight or L corridor up to 30 m) and single or dual returns.
The same seed always gives the same config.

Seeds are split: **development seeds 0-9999** (``DEV_SEEDS``: look at them, tune on them) and
**test seeds from 10000** (``TEST_SEEDS``: report on them, never tune on them).
``bench/rigs.py`` runs the processor over them.
"""

from __future__ import annotations

import numpy as np

from .config import SimConfig

#: seeds to develop on (look, tune, debug)
DEV_SEEDS = range(0, 10_000)
#: seeds to report on (not looked at while developing)
TEST_SEEDS = range(10_000, 20_000)

#: scene kinds the sampler draws, with their weights
SCENE_KINDS = {"small_room": 0.25, "room": 0.2, "hall": 0.3, "corridor": 0.25}

#: recording time the sampler aims to stay under (simulation and processing cost) [s]
MAX_RECORDING_S = 240.0


def _log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def _scene(rng: np.random.Generator) -> tuple[str, str, dict]:
    """(kind, scene name, scene_size fields)."""
    kinds = list(SCENE_KINDS)
    kind = str(rng.choice(kinds, p=np.array(list(SCENE_KINDS.values()))))
    if kind == "small_room":
        return kind, "room", {"width_m": round(rng.uniform(3.3, 5.0), 3),
                              "depth_m": round(rng.uniform(3.3, 4.5), 3),
                              "height_m": round(rng.uniform(2.3, 2.8), 3)}
    if kind == "room":
        return kind, "room", {}
    if kind == "hall":
        return kind, "hall", {"width_m": round(rng.uniform(12.0, 40.0), 3),
                              "depth_m": round(rng.uniform(10.0, 25.0), 3),
                              "height_m": round(rng.uniform(4.0, 10.0), 3)}
    straight = rng.random() < 0.5
    length = rng.uniform(10.0, 30.0)
    return kind, "corridor", {"length_m": round(length, 3),
                              "leg2_m": 0.0 if straight else round(rng.uniform(8.0, 15.0), 3),
                              "width_m": round(rng.uniform(1.5, 3.0), 3)}


def draw_rig(seed: int, *, max_recording_s: float = MAX_RECORDING_S) -> SimConfig:
    """A random rig and capture, deterministic per ``seed`` (see the module docstring).

    The number of stations (2-8) is the most that keeps the recording under
    ``max_recording_s``; the stations spread over a share of the route that keeps every carry
    under 30 s at the drawn walking speed.
    """
    from .motion import Route
    from .scenes import make_scene

    rng = np.random.default_rng([int(seed), 0x816])
    kind, scene, size = _scene(rng)
    # mount and calibration
    tilt = rng.uniform(0.0, 90.0)
    d = rng.normal(size=3)
    lever = d / np.linalg.norm(d) * rng.uniform(0.0, 0.20)
    latency = rng.uniform(0.0, 10.0)
    jitter = rng.uniform(0.0, 1.0)
    rpy_imu = rng.uniform(-3.0, 3.0, 3)
    # pan: motor or hand, pause and reversal, 0.9-1.2 turns, 4-60 s
    profile = "hand" if rng.random() < 0.6 else "constant"
    pan_s = _log_uniform(rng, 4.0, 60.0)
    turns = rng.uniform(0.9, 1.2)
    pause = rng.uniform(0.5, 3.0) if rng.random() < 0.4 else 0.0
    rev_deg = rng.uniform(10.0, 40.0) if rng.random() < 0.4 else 0.0
    rev_s = rng.uniform(0.6, 1.5)
    ramp = rng.uniform(0.3, 1.0)
    settle = rng.uniform(0.3, 2.0)
    variation = rng.uniform(0.2, 0.6)
    change_s = rng.uniform(0.8, 3.0)
    # a short pan keeps what fits: first the reversal, then the pause go
    while True:
        gaps = [w for w, on in ((pause, pause > 0), (rev_s, rev_deg > 0)) if on]
        need = 2 * min(ramp, pan_s / 4) + sum(w + 2 * min(ramp, 0.5) for w in gaps)
        if not gaps or need <= 0.8 * pan_s:
            break
        if rev_deg > 0:
            rev_deg = 0.0
        else:
            pause = 0.0
    # carries: 2-30 s, slow and careful or quick
    slow = rng.random() < 0.5
    speed = rng.uniform(0.3, 0.7) if slow else rng.uniform(0.9, 1.5)
    carry_s = _log_uniform(rng, 2.0, 30.0)
    dual = rng.random() < 0.5
    single_mode = "strongest" if rng.random() < 0.5 else "last"
    # stations: as many as fit in the recording budget (2..8)
    dwell = pan_s + 2 * settle
    n = int(np.clip((max_recording_s + carry_s) // (dwell + carry_s), 2, 8))
    # spread: every walk (spacing x 1.4 at most, station jitter) within 30 s of carrying
    sc = make_scene(scene, int(seed), size)
    L = Route(sc.route, sc.closed_route).length
    walk_max = 30.0 * speed / 1.875 / 1.4
    span = float(min(1.0, n * walk_max / max(L, 1e-9)))
    cfg = {
        "scene": scene, "stations": n, "seed": int(seed),
        "motion": {"tilt_deg": round(tilt, 4), "lever_arm_m": [round(float(x), 5) for x in lever],
                   "pan_profile": profile, "pan_s": round(pan_s, 4), "pan_turns": round(turns, 4),
                   "pan_turns_jitter": 0.03 if profile == "hand" else 0.0,
                   "pan_speed_variation": round(variation, 4),
                   "pan_speed_change_s": round(change_s, 4), "pan_pause_s": round(pause, 4),
                   "pan_reversal_deg": round(rev_deg, 4), "pan_reversal_s": round(rev_s, 4),
                   "pan_ramp_s": round(ramp, 4), "settle_s": round(settle, 4),
                   "transit_s": round(carry_s, 4), "max_carry_speed_m_s": round(speed, 4),
                   "route_span": round(span, 4)},
        "lidar": {"return_mode": "dual" if dual else single_mode},
        "imu": {"latency_ms": round(latency, 4), "latency_jitter_ms": round(jitter, 4),
                "rpy_lidar_imu_deg": [round(float(x), 4) for x in rpy_imu]},
    }
    if size:
        cfg["scene_size"] = size
    out = SimConfig.model_validate(cfg)
    # long walks make carries longer than transit_s: drop stations until the recording fits
    from .capture import build_rig

    while out.stations > 2 and build_rig(out, sc)[1].duration_s > max_recording_s:
        n = out.stations - 1
        span = float(min(1.0, n * walk_max / max(L, 1e-9)))
        motion = out.motion.model_copy(update={"route_span": round(span, 4)})
        out = out.model_copy(update={"stations": n, "motion": motion})
    return out


def describe(cfg: SimConfig) -> str:
    """One line with the parameters that matter for a rig (for benchmark tables)."""
    m, sz = cfg.motion, cfg.scene_size
    dims = ""
    if sz is not None:
        dims = " " + "x".join(f"{v:.0f}" for v in (sz.length_m, sz.width_m, sz.depth_m)
                              if v is not None) + " m"
        if sz.leg2_m:
            dims += f" + {sz.leg2_m:.0f} m leg"
    lever_cm = 100 * float(np.linalg.norm(m.lever_arm_m))
    extras = "".join([f" pause {m.pan_pause_s:.1f}s" if m.pan_pause_s else "",
                      f" back {m.pan_reversal_deg:.0f}°" if m.pan_reversal_deg else ""])
    return (f"{cfg.scene}{dims}, {cfg.stations} st, tilt {m.tilt_deg:.0f}°, lever "
            f"{lever_cm:.1f} cm, IMU lag {cfg.imu.latency_ms:.1f} ms, {m.pan_profile} "
            f"{m.pan_s:.0f}s x{m.pan_turns or 1:.2f}{extras}, carry {m.transit_s:.0f}s "
            f"@{m.max_carry_speed_m_s:.1f} m/s, {cfg.lidar.return_mode}")


def small_rig(**over) -> SimConfig:
    """A small capture for the processor's tests: a short hall (12 x 10 m), a 10 cm lever arm
    across the pan axis, a hand-turned head with a pause and a reversal, 4 ms IMU latency,
    3 stations of 6 s pans and 3 s carries (about 30 s of recording). ``over``: top-level
    SimConfig fields; ``motion``, ``imu``, ``lidar``, ``scene_size`` dicts are merged."""
    base = {
        "scene": "hall", "stations": 3, "seed": 5,
        "scene_size": {"width_m": 12.0, "depth_m": 10.0, "height_m": 5.0},
        "motion": {"tilt_deg": 60.0, "lever_arm_m": [0.08, 0.06, 0.03], "pan_profile": "hand",
                   "pan_s": 6.0, "pan_turns": 1.05, "pan_pause_s": 0.8, "pan_reversal_deg": 20.0,
                   "pan_reversal_s": 0.8, "pan_ramp_s": 0.4, "settle_s": 0.5, "transit_s": 3.0,
                   "route_span": 0.5},
        "imu": {"latency_ms": 4.0, "latency_jitter_ms": 0.3},
    }
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(base.get(k), dict):
            base[k] = {**base[k], **v}
        else:
            base[k] = v
    return SimConfig.model_validate(base)
