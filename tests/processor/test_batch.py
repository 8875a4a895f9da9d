# SPDX-License-Identifier: BSD-3-Clause
"""``tripod batch``: discovery (daemon split naming, pcap + IMU pairs, simulator folders), a
batch on a local Ray instance equal to ``tripod reconstruct`` per recording, a corrupt recording
failing alone, re-runs skipping what is up to date, and a loopback Ray cluster (head + worker
node, as a user starts them with ``ray start``) giving byte-identical station poses with a
worker process killed mid-batch."""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import pytest

from sim_fixtures import make_capture
from tripod_processor.batch import discover
from tripod_processor.batch.discovery import group_mcap
from tripod_processor.batch.manifest import config_hash
from tripod_processor.batch.runner import plan
from tripod_processor.cli import main
from tripod_shared.messages import Event
from tripod_shared.recording import RecordingWriter

# the compared outputs: station poses (lidar time), the map, the pose graph
COMPARED = ("stations.tum", "map.ply", "pose_graph.g2o")
SETS = ["--set", "output.write_mcap=false", "--set", "output.report=true"]


def _sets(survey: Path) -> list[str]:
    """The simulator's mount (the same for every capture) and the outputs compared."""
    return [*SETS, "--calibration", str(survey / "room_a" / "gt" / "calibration.json")]


# ---- discovery ---------------------------------------------------------------------------------
def _mcap(path: Path, reason: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as fh, RecordingWriter(fh) as w:
        w.write_event(Event(1, "start", reason))
    return path


def test_discovery_groups_daemon_splits_pairs_pcaps_and_finds_sim_folders(tmp_path):
    d = tmp_path / "survey"
    a1 = _mcap(d / "tripod_20260101T100000Z.mcap", "start")
    a2 = _mcap(d / "tripod_20260101T100500Z.mcap", "split")
    a3 = _mcap(d / "tripod_20260101T100500Z_1.mcap", "rotate")  # name collision suffix
    b1 = _mcap(d / "tripod_20260101T110000Z.mcap", "start")  # a new recording
    c1 = _mcap(d / "other_20260101T100600Z.mcap", "split")  # another prefix: not continued
    loose = _mcap(d / "floor2.mcap", "split")  # not the daemon's naming: its own recording
    assert group_mcap([b1, a3, c1, a1, loose, a2]) == [[loose], [c1], [a1, a2, a3], [b1]]

    (d / "wing.pcap").write_bytes(b"x")
    (d / "wing.tripimu").write_bytes(b"x")
    (d / "noimu.pcap").write_bytes(b"x")
    sim = d / "sims" / "room1"
    sim.mkdir(parents=True)
    (sim / "capture.pcap").write_bytes(b"x")
    (sim / "imu.tripimu").write_bytes(b"x")
    (sim / "inner").mkdir()  # a simulate folder is not searched further
    _mcap(sim / "inner" / "x.mcap", "start")
    (d / "notes.txt").write_text("not a recording")
    recs, notes = discover([d, tmp_path / "missing"])
    by = {r.name: r for r in recs}
    assert sorted(by) == ["floor2", "noimu", "other_20260101T100600Z", "room1",
                          "tripod_20260101T100000Z", "tripod_20260101T110000Z", "wing"]
    assert by["tripod_20260101T100000Z"].inputs == [a1, a2, a3]
    assert by["wing"].kind == "pcap" and by["wing"].imu == d / "wing.tripimu"
    assert by["noimu"].imu is None and "no IMU log" in by["noimu"].notes[0]
    assert by["room1"].kind == "sim" and by["room1"].inputs == [sim]
    assert set(by["room1"].files) == {sim / "capture.pcap", sim / "imu.tripimu"}
    assert len(notes) == 1 and "missing" in notes[0]
    # the same recording twice, by folder and by file: once; equal names get made unique
    recs2, _ = discover([d / "floor2.mcap", d, tmp_path / "survey"])
    assert sum(r.name == "floor2" for r in recs2) == 1
    other = tmp_path / "b" / "floor2.mcap"
    _mcap(other, "start")
    names = [r.name for r in discover([d / "floor2.mcap", other])[0]]
    assert names == ["floor2", "floor2-2"]


# ---- a batch on the local engine ---------------------------------------------------------------
@pytest.fixture(scope="module")
def survey(tmp_path_factory):
    """Two tiny simulator captures and a corrupt MCAP recording."""
    root = tmp_path_factory.mktemp("survey")
    # stations long enough to be found (3 s still), as short as that allows
    for name, seed in (("room_a", 7), ("room_b", 8)):
        make_capture(root, name, seed=seed, motion={"pan_s": 4.0})
    bad = root / "broken_20260101T100000Z.mcap"
    bad.write_bytes(b"\x89MCAP0\r\n" + os.urandom(4096))
    return root


@pytest.fixture(scope="module")
def local_batch(survey, tmp_path_factory):
    out = tmp_path_factory.mktemp("batch")
    t0 = time.perf_counter()
    rc = main(["batch", str(survey), "-o", str(out), "--workers", "1", "--quiet", *_sets(survey)])
    return rc, out, time.perf_counter() - t0


@pytest.mark.timeout(600)
def test_batch_equals_reconstruct_per_recording(survey, local_batch, tmp_path):
    rc, out, _ = local_batch
    assert rc == 1  # one recording failed
    for name in ("room_a", "room_b"):
        direct = tmp_path / name
        assert main(["reconstruct", str(survey / name), "-o", str(direct), "--quiet",
                     "--set", "num_threads=1", *_sets(survey)]) == 0
        for f in COMPARED:
            assert (out / name / f).read_bytes() == (direct / f).read_bytes(), (name, f)
        assert (out / name / "config.yaml").read_text() == (direct / "config.yaml").read_text()
        res = json.loads((out / name / "result.json").read_text())
        assert res["stations"] == 2


def test_corrupt_recording_fails_alone_and_index_links_reports(local_batch):
    rc, out, _ = local_batch
    b = json.loads((out / "batch.json").read_text())
    status = {o["name"]: o for o in b["recordings"]}
    assert {k: o["status"] for k, o in status.items()} == {
        "broken_20260101T100000Z": "failed", "room_a": "done", "room_b": "done"}
    assert status["broken_20260101T100000Z"]["error"]  # one line, with the reason
    assert "\n" not in status["broken_20260101T100000Z"]["error"]
    assert not (out / "broken_20260101T100000Z" / "batch-manifest.json").exists()
    md = (out / "index.md").read_text()
    html = (out / "index.html").read_text()
    for name in ("room_a", "room_b"):
        assert f"[report]({name}/report.md)" in md
        assert f'href="{name}/report.md"' in html
        assert (out / name / "batch-manifest.json").is_file()
    assert status["broken_20260101T100000Z"]["error"].split(":")[0] in md


def test_rerun_skips_up_to_date_and_redoes_changed(survey, local_batch, capsys):
    rc, out, _ = local_batch
    good = [survey / "room_a", survey / "room_b"]
    t0 = time.perf_counter()
    assert main(["batch", *map(str, good), "-o", str(out), "--quiet", *_sets(survey)]) == 0
    b = json.loads((out / "batch.json").read_text())
    assert [o["status"] for o in b["recordings"]] == ["skipped", "skipped"]
    assert b["engine"].startswith("none")  # no Ray instance started at all
    assert time.perf_counter() - t0 < 30
    assert "skipped" in capsys.readouterr().out
    # what would run after a change: input touched, config changed, output deleted
    from tripod_shared.config_io import dump_config, load_config

    from tripod_processor.reconstruction.config import ReconstructConfig

    cfg = load_config(ReconstructConfig, out / "room_a" / "config.yaml")  # the effective one
    recs, _ = discover(good)
    h = config_hash(dump_config(cfg))
    d = cfg.model_dump(mode="json")
    assert [len(x) for x in plan(recs, out, d, h)] == [0, 2]
    assert [len(x) for x in plan(recs, out, d, config_hash("other"))] == [2, 0]
    imu = survey / "room_b" / "imu.tripimu"
    st = imu.stat()
    os.utime(imu, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000_000))
    try:
        jobs, skipped = plan(recs, out, d, h)
        assert [j["name"] for j in jobs] == ["room_b"] and len(skipped) == 1
    finally:
        os.utime(imu, ns=(st.st_atime_ns, st.st_mtime_ns))
    (out / "room_a" / "map.ply").rename(out / "room_a" / "map.ply.bak")
    try:
        assert [j["name"] for j in plan(recs, out, d, h)[0]] == ["room_a"]
    finally:
        (out / "room_a" / "map.ply.bak").rename(out / "room_a" / "map.ply")


# ---- a loopback Ray cluster --------------------------------------------------------------------
def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _session_pids(temp_dir: str) -> list[int]:
    """Processes of the cluster started by the test: their command line names its temp dir."""
    import psutil

    pids = []
    for p in psutil.process_iter(["pid", "cmdline"]):
        try:
            if any(temp_dir in a for a in (p.info["cmdline"] or [])):
                pids.append(p.info["pid"])
        except (psutil.NoSuchProcess, psutil.AccessDenied):
            pass
    return pids


def _tree(pids: list[int]) -> set[int]:
    """The processes and all their descendants (Ray's agents retitle themselves, so their
    command lines no longer name the temp dir: they are found as children)."""
    import psutil

    out = set(pids)
    for pid in pids:
        try:
            out |= {c.pid for c in psutil.Process(pid).children(recursive=True)}
        except psutil.NoSuchProcess:
            pass
    return out


@pytest.fixture
def loopback_cluster():
    """A head and a worker node on 127.0.0.1, one CPU each, started with ``ray start``; every
    process they started is stopped by id afterwards."""
    import psutil

    ray_bin = str(Path(sys.executable).with_name("ray"))
    temp_dir = tempfile.mkdtemp(prefix="trb", dir="/tmp")  # short: Ray's socket paths
    port = _free_port()
    env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0"}
    common = ["--num-cpus=1", "--node-ip-address=127.0.0.1", "--disable-usage-stats",
              f"--temp-dir={temp_dir}"]
    started: set[int] = set()
    try:
        subprocess.run([ray_bin, "start", "--head", f"--port={port}",
                        "--include-dashboard=false", *common], check=True, env=env,
                       capture_output=True, timeout=180)
        started |= _tree(_session_pids(temp_dir))
        subprocess.run([ray_bin, "start", f"--address=127.0.0.1:{port}", *common], check=True,
                       env=env, capture_output=True, timeout=180)
        started |= _tree(_session_pids(temp_dir))
        yield f"127.0.0.1:{port}", temp_dir
    finally:
        procs = []
        for pid in started | _tree(_session_pids(temp_dir)):
            try:
                p = psutil.Process(pid)
                p.terminate()
                procs.append(p)
            except psutil.NoSuchProcess:
                pass
        _, alive = psutil.wait_procs(procs, timeout=10)
        for p in alive:
            try:
                p.kill()
            except psutil.NoSuchProcess:
                pass
        psutil.wait_procs(alive, timeout=5)
        shutil.rmtree(temp_dir, ignore_errors=True)


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_loopback_cluster_same_poses_with_a_worker_killed(survey, local_batch, loopback_cluster,
                                                         tmp_path):
    import psutil

    address, temp_dir = loopback_cluster
    _, local_out, _ = local_batch
    good = [str(survey / "room_a"), str(survey / "room_b")]
    out = tmp_path / "cluster"
    killed: list[int] = []

    def killer():
        # kill the first worker process seen running a reconstruction (once)
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline and not killed:
            # psutil.pids() + own Process objects: process_iter's cached objects (and their
            # .info) are shared with any other thread of this process iterating at the same time
            for pid in psutil.pids():
                try:
                    cmd = " ".join(psutil.Process(pid).cmdline())
                except psutil.Error:
                    continue
                if cmd.startswith("ray::reconstruct_recording"):
                    time.sleep(1.0)  # mid-task
                    try:
                        os.kill(pid, signal.SIGKILL)
                        killed.append(pid)
                    except ProcessLookupError:
                        continue
                    return
            time.sleep(0.2)

    th = threading.Thread(target=killer, daemon=True)
    th.start()
    rc = main(["batch", *good, "-o", str(out), "--address", address, "--quiet",
               "--max-retries", "2", *_sets(survey)])
    th.join(timeout=5)
    assert killed, "no worker was seen running a task"
    assert rc == 0
    b = json.loads((out / "batch.json").read_text())
    assert [o["status"] for o in b["recordings"]] == ["done", "done"]
    assert b["engine"].startswith(f"cluster {address}")
    # the killed attempt was retried: both recordings were finished by other worker processes
    assert killed[0] not in {o["pid"] for o in b["recordings"]}
    for name in ("room_a", "room_b"):
        for f in COMPARED:
            assert (out / name / f).read_bytes() == (local_out / name / f).read_bytes(), (name, f)
