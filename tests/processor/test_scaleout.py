# SPDX-License-Identifier: BSD-3-Clause
"""A reconstruction's heavy steps on an engine (``reconstruction.engine``,
``reconstruction.scaleout``): the same bytes as in process, on a local Ray instance of 2 workers
with a task's worker process killed mid-run (retried), and inside ``tripod batch``
(``--split-large``); the loop candidates' replay when a loop joins components."""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from sim_fixtures import make_capture
from tripod_processor.cli import main

COMPARED = ("stations.tum", "map.ply", "pose_graph.g2o")


def _sets(capture: Path) -> list[str]:
    return ["--set", "output.write_mcap=false", "--set", "num_threads=1", "--calibration",
            str(capture / "gt" / "calibration.json")]


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    """Four stations in a room (three odometry pairs, loop candidates)."""
    return make_capture(tmp_path_factory.mktemp("scaleout"), "room4", stations=4, seed=21,
                        motion={"pan_s": 4.0})


@pytest.fixture(scope="module")
def direct(capture, tmp_path_factory):
    """``tripod reconstruct`` in process (the default)."""
    out = tmp_path_factory.mktemp("direct")
    assert main(["reconstruct", str(capture), "-o", str(out), "--quiet", *_sets(capture)]) == 0
    return out


class SerialTasks:
    """An engine that runs every call in this process but goes the distributed way (stations'
    packet slices, runs of pairs in their own caches, loop candidates all ahead)."""

    name, distributed, slots = "serial tasks", True, 2

    def __init__(self):
        self.calls: dict[str, int] = {}

    def put(self, obj):
        return obj

    def map(self, fn, calls, progress=None):
        self.calls[fn.__name__] = self.calls.get(fn.__name__, 0) + len(calls)
        return [fn(*a) for a in calls]


def test_chunks_cover_every_item_in_order():
    from tripod_processor.reconstruction.engine import chunks

    for n, slots in ((0, 4), (1, 4), (7, 1), (100, 8), (5, 100)):
        runs = chunks(n, slots)
        assert [k for r in runs for k in r] == list(range(n))
        assert len(runs) <= max(3 * slots, 1)


def test_distributed_path_same_as_in_process_with_components_joined_by_loops(capture,
                                                                            monkeypatch):
    """Fragments from packet slices, odometry and loops as runs of tasks: the same fragments,
    edges and poses as in process, also when a loop joins two components (a later candidate
    between them then needs the odometry guess it did not have when sent ahead)."""
    from tripod_processor.reconstruction.config import ReconstructConfig
    from tripod_processor.reconstruction.fragments import Fragment
    from tripod_processor.reconstruction.inputs import read_recording
    from tripod_processor.reconstruction.placement import (
        Extrinsic,
        ImuOrientation,
        fit_clock_map,
        load_extrinsic_file,
    )
    from tripod_processor.reconstruction.scaleout import build_fragments, register_pairs
    from tripod_processor.reconstruction.slam import run_odometry, run_slam
    from tripod_processor.reconstruction.stations import segment_stations
    from tripod_shared.config_io import load_config

    q, lever = load_extrinsic_file(capture / "gt" / "calibration.json")
    cfg = load_config(ReconstructConfig, overrides={"placement.extrinsic.q_imu_lidar": q,
                                                    "placement.extrinsic.lever_arm_m": lever})
    rec = read_recording(capture)
    ext = Extrinsic.from_config(q, lever)
    orient = ImuOrientation(rec.imu, fit_clock_map(rec.lidar))
    seg = segment_stations(rec.lidar, orient, ext, cfg.stations)
    assert len(seg.stations) == 4
    args = (rec.lidar, seg.stations, orient, ext, cfg.fragments.voxel_m,
            cfg.placement.min_range_m, cfg.placement.max_range_m, 1)
    eng = SerialTasks()
    frags = build_fragments(None, *args)
    frags_t = build_fragments(eng, *args)
    assert eng.calls == {"_fragment_task": 4}
    for a, b in zip(frags, frags_t):
        assert a.station == b.station and a.raw_points == b.raw_points
        assert np.array_equal(a.points, b.points) and np.array_equal(a.R_world_lidar,
                                                                     b.R_world_lidar)
    # three copies of a cavern (a 30 m sphere: no surface of the room's, none near it) break
    # the chain after station 0: stations 1-3 of the room start another component, which a loop
    # from station 0 joins to the first; the candidates after that one between the two need the
    # odometry guess they did not have when sent ahead
    rng = np.random.default_rng(5)
    ball = rng.normal(size=(40000, 3))
    clutter = (30.0 * ball / np.linalg.norm(ball, axis=1, keepdims=True)).astype(np.float32)
    seq = frags[:1] + [Fragment(dataclasses.replace(frags[0].station, index=1 + k), clutter,
                                np.eye(3), len(clutter)) for k in range(3)] + frags[1:]
    oc, sc = cfg.odometry, cfg.slam.model_copy(update={"max_loops_per_station": 4})
    plain = run_odometry(seq, oc, 1)
    eng = SerialTasks()
    tasks = run_odometry(seq, oc, 1, engine=eng)
    assert eng.calls["_register_run"] >= 2  # first-choice pairs, then the retries
    assert np.array_equal(plain[0], tasks[0]) and np.array_equal(plain[2], tasks[2])
    assert plain[3] == tasks[3]
    comp = plain[2]
    assert len(set(comp[:4].tolist())) > 1 and comp[4] not in comp[:4]  # the room split apart
    assert (comp[4:] == comp[4]).all()
    s_plain = run_slam(seq, *plain[:3], oc, sc, 1)
    from tripod_processor.reconstruction import slam as slam_mod

    again: list = []  # candidates registered again, in order, after a loop joined components

    def counted(engine, *a, **kw):
        if engine is None:
            again.append(a[1])
        return register_pairs(engine, *a, **kw)

    monkeypatch.setattr(slam_mod, "register_pairs", counted)
    s_tasks = run_slam(seq, *tasks[:3], oc, sc, 1, engine=eng)
    assert again, "no candidate needed the replay"
    assert any("joined by a loop closure" in n for n in s_plain.notes)
    assert s_plain.notes == s_tasks.notes
    assert [(e.i, e.j, e.kind) for e in s_plain.edges] == [(e.i, e.j, e.kind)
                                                           for e in s_tasks.edges]
    for a, b in zip(s_plain.edges, s_tasks.edges):
        assert np.array_equal(a.T_i_j, b.T_i_j) and np.array_equal(a.information, b.information)
    assert np.array_equal(s_plain.T_optimized, s_tasks.T_optimized)
    assert np.array_equal(s_plain.component, s_tasks.component)


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_local_ray_same_bytes_with_a_task_killed(capture, direct, tmp_path):
    """``tripod reconstruct --workers 2``: fragments and registrations as Ray tasks; a worker
    process running one is killed (SIGKILL) and the task retried: the same outputs."""
    import psutil

    killed: list[int] = []

    def killer():
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline and not killed:
            for p in psutil.process_iter(["pid", "cmdline"]):
                cmd = " ".join(p.info["cmdline"] or [])
                if cmd.startswith(("ray::_register_run", "ray::_fragment_task")):
                    time.sleep(0.3)  # mid-task
                    try:
                        os.kill(p.info["pid"], signal.SIGKILL)
                        killed.append(p.info["pid"])
                    except ProcessLookupError:
                        continue
                    return
            time.sleep(0.1)

    th = threading.Thread(target=killer, daemon=True)
    th.start()
    out = tmp_path / "ray"
    rc = main(["reconstruct", str(capture), "-o", str(out), "--quiet", "--workers", "2",
               *_sets(capture)])
    th.join(timeout=5)
    assert rc == 0
    assert killed, "no worker was seen running a task"
    res = json.loads((out / "result.json").read_text())
    assert res["engine"] == "local Ray, 2 workers" and res["stations"] == 4
    for f in COMPARED:
        assert (out / f).read_bytes() == (direct / f).read_bytes(), f
    assert (out / "config.yaml").read_text() == (direct / "config.yaml").read_text()


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_batch_splits_a_large_recording_over_its_engine(capture, direct, tmp_path):
    """``tripod batch --split-large 3``: the 4-station recording's fragments and registrations
    are tasks on the batch's engine (nested in its recording's task): the same outputs."""
    out = tmp_path / "batch"
    rc = main(["batch", str(capture), "-o", str(out), "--workers", "2", "--split-large", "3",
               "--quiet", *_sets(capture)])
    assert rc == 0
    b = json.loads((out / "batch.json").read_text())
    (o,) = b["recordings"]
    assert o["status"] == "done" and o["summary"]["engine"].startswith("Ray")
    for f in COMPARED:
        assert (out / "room4" / f).read_bytes() == (direct / f).read_bytes(), f
