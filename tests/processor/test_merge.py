# SPDX-License-Identifier: BSD-3-Clause
"""``tripod batch --merge``: the small simulated building (two recordings sharing the hall, one
alone in a west room) merged into one model, scored against the simulator's truth (station ATE
over both recordings, every true link between them found, none false), the lone recording a
separate component; the pose graph's g2o round trip; a bad merge setting."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from tripod_processor.cli import main
from tripod_processor.reconstruction.evaluation import evaluate_merge
from tripod_processor.reconstruction.merge import read_g2o_edges
from tripod_processor.reconstruction.outputs import read_tum
from tripod_processor.registration import pose_graph as pg
from tripod_processor.sim.survey_building import simulate_survey, survey_plan

#: test seed of the building and its recordings (development used seed 0: bench/batch.py)
SEED = 1
SETS = ["--set", "output.write_mcap=false", "--set", "output.write_pcd=false",
        "--set", "output.smooth_radius_m=0"]


@pytest.fixture(scope="module")
def merged(tmp_path_factory):
    root = tmp_path_factory.mktemp("building")
    dirs = simulate_survey(root / "survey", "small", seed=SEED, pan_s=5.0, nthreads=2)
    out = root / "out"
    rc = main(["batch", str(root / "survey"), "-o", str(out), "--workers", "2", "--quiet",
               "--merge", "--calibration", str(dirs[0] / "gt" / "calibration.json"), *SETS])
    return rc, out, dirs


@pytest.mark.timeout(900)  # the batch and the merge: ~7-10 min at load 20
def test_small_building_merges_with_truth_accuracy_and_a_lone_component(merged):
    rc, out, dirs = merged
    assert rc == 0
    names = [d.name for d in dirs]
    assert [p.name for p in survey_plan("small")] == [n[3:] for n in names]
    hall, hall_east, west = names
    m = out / "merged"
    res = json.loads((m / "result.json").read_text())
    comps = res["components"]
    assert [c["recordings"] for c in comps] == [[hall, hall_east], [west]]
    # stations.tum covers every station of both joined recordings, in lidar time
    t, _ = read_tum(m / "stations.tum")
    own = np.concatenate([read_tum(out / n / "stations.tum")[0] for n in (hall, hall_east)])
    assert sorted(t.tolist()) == sorted(own.tolist()) and len(t) >= 6
    assert (np.diff(t) > 0).all()
    t_west, _ = read_tum(m / "component-1" / "stations.tum")
    assert t_west.tolist() == read_tum(out / west / "stations.tum")[0].tolist()
    for f in ("map.ply", "pose_graph.g2o", "report.md", "config.yaml", "links.csv"):
        assert (m / f).is_file(), f
    assert west in (m / "report.md").read_text()
    n_all = sum(len(read_tum(out / n / "stations.tum")[0]) for n in names)
    assert f"merged model: {len(t)} of {n_all} stations" in (out / "index.md").read_text()
    # links only between the two hall recordings
    with open(m / "links.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert rows and all({r["recording_a"], r["recording_b"]} == {hall, hall_east} for r in rows)
    # scored against the truth of every recording (one building frame)
    ev = evaluate_merge(m, {n: out / n for n in names}, {d.name: d for d in dirs})
    assert ev["stations"] == len(t)
    assert ev["ate_cm"] < 2.0 and ev["ate_deg"] < 0.2, ev
    assert ev["true_links"] >= 3
    assert ev["true_links_found"] == ev["true_links"], ev
    assert ev["false_links"] == 0, ev["false_link_list"]


def test_g2o_edges_round_trip(tmp_path):
    rng = np.random.default_rng(3)
    g = pg.PoseGraph()
    for _ in range(3):
        g.add_node(np.eye(4))
    from scipy.spatial.transform import Rotation

    want = []
    for i, j in ((0, 1), (1, 2), (0, 2)):
        T = np.eye(4)
        T[:3, :3] = Rotation.from_rotvec(rng.normal(0, 0.2, 3)).as_matrix()
        T[:3, 3] = rng.normal(0, 1, 3)
        A = rng.normal(0, 1, (6, 6))
        info = A @ A.T + np.eye(6)
        g.add_edge(pg.Edge(i, j, T, info))
        want.append((i, j, T, info))
    g.save_g2o(tmp_path / "g.g2o")
    got = read_g2o_edges(tmp_path / "g.g2o")
    assert [(e.i, e.j, e.kind) for e in got] == [(0, 1, "odometry"), (1, 2, "odometry"),
                                                 (0, 2, "loop")]
    for e, (_, _, T, info) in zip(got, want):
        assert np.allclose(e.T_i_j, T, atol=1e-8)
        assert np.allclose(e.information, info, rtol=1e-7)


def test_bad_merge_setting_is_one_line(tmp_path, capsys):
    (tmp_path / "x").mkdir()
    (tmp_path / "x" / "capture.pcap").write_bytes(b"")
    assert main(["batch", str(tmp_path / "x"), "-o", str(tmp_path / "o"), "--merge",
                 "--set", "merge.no_such_key=1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no_such_key" in err[0]
    assert main(["batch", str(tmp_path / "x"), "-o", str(tmp_path / "o"),
                 "--set", "merge.min_links=1"]) == 2
    assert "--merge" in capsys.readouterr().err
