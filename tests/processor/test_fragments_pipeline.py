# SPDX-License-Identifier: BSD-3-Clause
"""The fragments' shared chunks (issue 12's idle wall time): the stations side by side, a thread
with no station left decoding and placing the chunks of those still running, gives the same
fragments, to the bit, as the stations one after another (and side by side, one a thread)."""

from __future__ import annotations

import numpy as np
import pytest
from sim_fixtures import make_capture


@pytest.fixture(scope="module")
def parts(tmp_path_factory):
    from tripod_processor.reconstruction.config import ReconstructConfig
    from tripod_processor.reconstruction.inputs import read_recording
    from tripod_processor.reconstruction.placement import (Extrinsic, ImuOrientation,
                                                           fit_clock_map, load_extrinsic_file)
    from tripod_processor.reconstruction.stations import segment_stations
    from tripod_shared.config_io import load_config

    cap = make_capture(tmp_path_factory.mktemp("fragpipe"), "room4", stations=3, seed=23,
                       motion={"pan_s": 3.0})
    q, lever = load_extrinsic_file(cap / "gt" / "calibration.json")
    cfg = load_config(ReconstructConfig, overrides={"placement.extrinsic.q_imu_lidar": q,
                                                    "placement.extrinsic.lever_arm_m": lever})
    rec = read_recording(cap)
    ext = Extrinsic.from_config(q, lever)
    orient = ImuOrientation(rec.imu, fit_clock_map(rec.lidar))
    seg = segment_stations(rec.lidar, orient, ext, cfg.stations)
    assert len(seg.stations) == 3
    return rec.lidar, seg.stations, orient, ext, cfg


def _same(a, b):
    assert a.station == b.station and a.raw_points == b.raw_points and a.anchor == b.anchor
    assert a.points.dtype == b.points.dtype and np.array_equal(a.points, b.points)
    assert np.array_equal(a.R_world_lidar, b.R_world_lidar)
    if a.intensity is None:
        assert b.intensity is None
    else:
        assert np.array_equal(a.intensity, b.intensity, equal_nan=True)


def test_shared_chunks_same_fragments_as_one_station_at_a_time(parts, monkeypatch):
    """Small chunks and a small point bound (the half-voxel filter runs several times a
    station) with the intensity sums, on 2 and 3 threads for 3 stations (threads left with no
    station help the others): the same fragments to the bit."""
    import threading
    import time

    from tripod_processor.reconstruction import fragments
    from tripod_processor.reconstruction.fragments import (build_fragment,
                                                           build_fragments_shared)

    lidar, stations, orient, ext, cfg = parts
    fc, pc = cfg.fragments, cfg.placement
    kw = dict(anchor_fit=True, anchor_max_deviation_deg=pc.anchor_max_deviation_deg,
              denoise_firings=fc.range_denoise_firings, denoise_fit=fc.range_denoise_fit,
              denoise_max_step_m=fc.range_denoise_max_step_m)
    serial = [build_fragment(lidar, st, orient, ext, fc.voxel_m, pc.min_range_m,
                             pc.max_range_m, 1, chunk=150, max_points=200_000,
                             with_intensity=True, **kw) for st in stations]
    assert all(f.raw_points > 200_000 for f in serial)  # the bound was crossed
    by: dict = {}  # station -> the threads that decoded its chunks
    chunk_points = fragments.chunk_points

    def counted(lidar, a, b, st, *args, **kwargs):
        by.setdefault(st.index, set()).add(threading.get_ident())
        if st.index == stations[0].index:
            time.sleep(0.2)  # the first station the slowest: the others' threads help it
        return chunk_points(lidar, a, b, st, *args, **kwargs)

    monkeypatch.setattr(fragments, "chunk_points", counted)
    for workers in (2, 3):
        by.clear()
        done = []
        shared = build_fragments_shared(lidar, stations, orient, ext, fc.voxel_m,
                                        pc.min_range_m, pc.max_range_m, workers, workers, True,
                                        done.append, chunk=150, max_points=200_000, **dict(kw))
        assert done == [0, 1, 2]
        # the threads left without a station helped the first
        assert len(by[stations[0].index]) >= 2, (workers, {k: len(v) for k, v in by.items()})
        for a, b in zip(serial, shared, strict=True):
            _same(a, b)


def test_build_fragments_pipeline_knob_same_fragments(parts):
    """``fragments.chunk_pipeline`` on and off (the stations side by side) on two threads."""
    from tripod_processor.reconstruction.scaleout import build_fragments

    lidar, stations, orient, ext, cfg = parts
    fc, pc = cfg.fragments, cfg.placement
    args = (None, lidar, stations, orient, ext, fc.voxel_m, pc.min_range_m, pc.max_range_m, 2)
    kw = dict(denoise_firings=fc.range_denoise_firings, denoise_fit=fc.range_denoise_fit,
              denoise_max_step_m=fc.range_denoise_max_step_m)
    on = build_fragments(*args, chunk_pipeline=True, **kw)
    off = build_fragments(*args, chunk_pipeline=False, **kw)
    for a, b in zip(on, off, strict=True):
        _same(a, b)
