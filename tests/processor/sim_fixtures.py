# SPDX-License-Identifier: BSD-3-Clause
"""Small simulated captures shared by the simulator and replay tests (a few seconds each)."""

from __future__ import annotations

from pathlib import Path

from tripod_processor.sim import SimConfig, simulate

SHORT_MOTION = {"pan_s": 2.0, "settle_s": 0.2, "pan_ramp_s": 0.3, "transit_s": 1.0}


def small_config(**over) -> SimConfig:
    base = {"stations": 2, "seed": 7, "motion": dict(SHORT_MOTION)}
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(base.get(k), dict):
            base[k] = {**base[k], **v}
        else:
            base[k] = v
    return SimConfig.model_validate(base)


def make_capture(root: Path, name: str, **over) -> Path:
    out = root / name
    simulate(small_config(**over), out, nthreads=2)
    return out
