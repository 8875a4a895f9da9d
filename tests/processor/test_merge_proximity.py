# SPDX-License-Identifier: BSD-3-Clause
"""The merge's proximity pass (loop closure by proximity, ``merge.proximity_links``): three
recordings of one room, each in its own frame; the shortlist (k = 1, no capture-time
neighbours) leaves one pair out, so its hypothesis is never verified; once the three are placed
through the other two pairs, the proximity pass links that pair from the merged estimate: every
link it keeps within a few cm / tenths of a degree of the truth, none false, and the pair
counted as joined by proximity in result.json and the report."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from pydantic import ValidationError
from test_twins import _err, _recording, _room

from tripod_processor.sim.station_scan import pose

# each recording: its frame (yaw deg, x, y) and its stations ((x, y), yaw deg) in the room
RECORDINGS = {
    "a": ((35.0, 1.6, 1.5), [((1.6, 1.5), 35.0), ((2.9, 3.0), 120.0)]),
    "b": ((-70.0, 5.6, 2.9), [((5.6, 2.9), -70.0), ((4.6, 1.4), 15.0)]),
    "c": ((160.0, 3.8, 2.2), [((3.8, 2.2), 160.0), ((6.3, 1.2), -140.0)]),
}


@pytest.fixture(scope="module")
def three(tmp_path_factory):
    root = tmp_path_factory.mktemp("proximity")
    scene = _room(False)
    truth = {}
    for k, (name, ((yaw, x, y), stations)) in enumerate(RECORDINGS.items()):
        T_w_rec = pose(yaw_deg=yaw, xyz=(x, y, 1.4))
        T_rec = _recording(root / name, scene, stations, T_w_rec, 11 + 7 * k)
        truth[name] = T_w_rec @ T_rec  # T_world_lidar of each station
    return root, truth


@pytest.mark.timeout(600)
def test_a_pair_left_out_gets_its_links_back_by_proximity(three):
    from tripod_processor.reconstruction.merge import MergeConfig, merge_recordings

    root, truth = three
    names = list(RECORDINGS)
    cfg = MergeConfig(num_threads=2, shortlist_k=1, shortlist_time_neighbours=False)
    res = merge_recordings([root / n for n in names], root / "merged", cfg)
    left = [p for p in res.pairs if not p.shortlisted]
    assert len(left) == 1, [(p.A, p.B, p.score) for p in res.pairs]
    po = left[0]
    assert po.tried == []  # its own hypothesis was never verified
    assert list(res.component) == [0, 0, 0]
    assert po.accepted == "proximity" and po.links >= 1, po
    assert po.proximity["kept"] == po.links and po.proximity["verified"] >= po.links
    prox = [lk for lk in res.links if lk.source == "proximity"]
    assert prox and all((lk.A, lk.B) == (po.A, po.B) for lk in prox)
    # every link kept (its own and the proximity pass'), against the truth: none false
    for lk in res.links:
        if not lk.kept:
            continue
        T_true = np.linalg.inv(truth[names[lk.A]][lk.a]) @ truth[names[lk.B]][lk.b]
        ang, dist = _err(lk.T_a_b, T_true)
        assert ang < 0.5 and dist < 0.05, (lk.source, lk.A, lk.a, lk.B, lk.b, ang, dist)
    # the merged stations of the left-out pair where the truth puts them
    for a in range(2):
        for b in range(2):
            T_m = np.linalg.inv(res.T_world_station[po.A][a]) @ res.T_world_station[po.B][b]
            T_true = np.linalg.inv(truth[names[po.A]][a]) @ truth[names[po.B]][b]
            ang, dist = _err(T_m, T_true)
            assert ang < 0.3 and dist < 0.03, (a, b, ang, dist)
    # recorded: result.json (joined count includes it), links.csv, the report
    summ = json.loads((root / "merged" / "result.json").read_text())
    assert summ["recording_pairs_proximity"] == 1
    assert summ["recording_pairs_joined"] == 3 and summ["recording_pairs_left_out"] == 1
    row = next(p for p in summ["recording_pairs"] if not p["shortlisted"])
    assert row["accepted"] == "proximity" and row["proximity"]["kept"] == po.links
    with open(root / "merged" / "links.csv") as fh:
        rows = [r for r in csv.DictReader(fh) if r["source"] == "proximity"]
    assert len(rows) == len(prox) and {(r["recording_a"], r["recording_b"]) for r in rows} == \
        {(names[po.A], names[po.B])}
    assert "1 of them by proximity" in (root / "merged" / "report.md").read_text()


@pytest.mark.timeout(600)
def test_without_the_proximity_pass_the_left_out_pair_has_no_links(three):
    from tripod_processor.reconstruction.merge import MergeConfig, merge_recordings

    root, _ = three
    cfg = MergeConfig(num_threads=2, shortlist_k=1, shortlist_time_neighbours=False,
                      proximity_links=False)
    res = merge_recordings([root / n for n in RECORDINGS], root / "off", cfg)
    po = next(p for p in res.pairs if not p.shortlisted)
    assert not po.accepted and po.links == 0 and not po.proximity
    assert not any((lk.A, lk.B) == (po.A, po.B) for lk in res.links)
    assert json.loads((root / "off" / "result.json").read_text())[
        "recording_pairs_proximity"] == 0
    with pytest.raises(ValidationError):
        MergeConfig(proximity_links="sometimes")
