# SPDX-License-Identifier: BSD-3-Clause
"""The cheaper and parallel paths of ``tripod reconstruct`` (issue 12's cost) give what the plain
ones give: the pcap batch read, the plain-array decode, the station splitter on threads and
with its second pass reusing the first one's windows, fragments and odometry side by side, the
self-calibration's stations side by side."""

from __future__ import annotations

import numpy as np
import pytest
from sim_fixtures import make_rig_capture

from tripod_shared import velodyne as vl
from tripod_shared.config_io import load_config

from tripod_processor.decode.timed import decode_timed_points, decode_xyz_time
from tripod_processor.io.events import pcap_events
from tripod_processor.io.pcap import PcapReader, PcapWriter
from tripod_processor.reconstruction import inputs
from tripod_processor.reconstruction.config import ReconstructConfig
from tripod_processor.reconstruction.placement import Extrinsic, ImuOrientation, fit_clock_map
from tripod_processor.reconstruction.stations import segment_stations


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    cap = make_rig_capture(tmp_path_factory.mktemp("cost"))
    rec = inputs.read_recording(cap)
    return cap, rec, ImuOrientation(rec.imu, fit_clock_map(rec.lidar), 0)


def _slow_read(path):
    """The per-datagram read the batch read replaced (``io.events.pcap_events``)."""
    col = inputs._LidarCollector()
    for host_ns, kind, payload in pcap_events(PcapReader(path), skipped=col.skipped):
        col.add(host_ns, kind, payload)
    lid, hour = inputs._finish_lidar(col.host, col.payloads, col.gprmc)
    return lid, hour, col.skipped


def test_batch_pcap_read_equals_the_per_datagram_read(rig, tmp_path):
    cap, rec, _ = rig
    pay = rec.lidar.payload
    # a capture with what the reader must count and skip: a broken block flag, a foreign
    # product, a bad return mode, 1206 bytes sent to the position port, a short datagram to the
    # data port, a datagram of another size on another port
    bad_flag, foreign, bad_mode = pay[3].copy(), pay[4].copy(), pay[5].copy()
    bad_flag[300] = 0x00
    foreign[vl.PRODUCT_ID_OFFSET] = 0x99
    bad_mode[vl.RETURN_MODE_OFFSET] = 0x01
    path = tmp_path / "mixed.pcap"
    with PcapWriter(path) as w:
        for k in range(3000):
            t = int(rec.lidar.host_ns[k])
            if k == 3:
                w.write_udp(t, bad_flag.tobytes(), 2368, vl.DATA_PORT)
            elif k == 4:
                w.write_udp(t, foreign.tobytes(), 2368, vl.DATA_PORT)
            elif k == 5:
                w.write_udp(t, bad_mode.tobytes(), 2368, vl.DATA_PORT)
            elif k == 6:
                w.write_udp(t, pay[k].tobytes(), 8308, vl.POSITION_PORT)
            elif k == 7:
                w.write_udp(t, b"\x00" * 100, 2368, vl.DATA_PORT)
            elif k == 8:
                w.write_udp(t, b"\x01" * 77, 5000, 5001)
            else:
                w.write_udp(t, pay[k].tobytes(), 2368, 2368 if k % 2 else 7777)
    for p in (path, cap / "capture.pcap"):
        fast = inputs._read_pcap(p)
        lid, hour, skipped = _slow_read(p)
        assert len(fast.lidar) == len(lid) > 0
        assert np.array_equal(fast.lidar.host_ns, lid.host_ns)
        assert np.array_equal(fast.lidar.lidar_ns, lid.lidar_ns)
        assert np.array_equal(fast.lidar.payload, lid.payload)
        assert fast.lidar.return_mode == lid.return_mode and fast.hour_source == hour
        assert fast.skipped == skipped
    assert _slow_read(path)[2] == {"bad_lidar_packet": 4, "bad_position_packet": 1,
                                   "other_datagram": 1}
    assert len(inputs._read_pcap(path).lidar) == 3000 - 6


def test_plain_array_decode_equals_the_timed_points(rig):
    _, rec, _ = rig
    lid = rec.lidar
    for a, b, inten in ((100, 2600, True), (7, 8, False), (50, 50, True)):
        pts = decode_timed_points(lid.payload, lid.lidar_ns, a, b, min_range=0.5,
                                  max_range=40.0)
        xyz, t, i = decode_xyz_time(lid.payload, lid.lidar_ns, a, b, min_range=0.5,
                                    max_range=40.0, with_intensity=inten)
        assert xyz.dtype == np.float32 and xyz.shape == (len(pts), 3) and t.dtype == np.int64
        assert np.array_equal(xyz, np.stack([pts["x"], pts["y"], pts["z"]], axis=1))
        assert np.array_equal(t, pts["time_ns"])
        assert (i is None) if not inten else np.array_equal(i, pts["intensity"])


def test_plain_array_decode_with_the_scan_line_smoothing(rig):
    # the same points and times; each point moved along its own beam only, by about the range
    # noise's share the fit removes
    _, rec, _ = rig
    lid = rec.lidar
    xyz, t, _ = decode_xyz_time(lid.payload, lid.lidar_ns, 100, 2600, min_range=0.5)
    for fit in ("mean", "linear", "quadratic"):
        xyz_s, t_s, _ = decode_xyz_time(lid.payload, lid.lidar_ns, 100, 2600, min_range=0.5,
                                        denoise_firings=5, denoise_fit=fit)
        assert xyz_s.dtype == np.float32 and xyz_s.shape == xyz.shape
        assert np.array_equal(t_s, t)
        a, b = xyz.astype(np.float64), xyz_s.astype(np.float64)
        r, r_s = np.linalg.norm(a, axis=1), np.linalg.norm(b, axis=1)
        sin = np.linalg.norm(np.cross(a, b), axis=1) / (r * r_s)
        assert np.max(sin) < 1e-6  # [rad]: float32's rounding
        assert 0.001 < np.median(np.abs(r_s - r)) < 0.05


def test_station_splitter_is_the_same_on_threads_and_reusing_its_windows(rig):
    _, rec, orient = rig
    cfg = ReconstructConfig().stations
    ext0 = Extrinsic.from_config(None, None)
    ext1 = Extrinsic.from_config(None, [0.0, 0.06, 0.0])  # a "calibrated" rig for pass two

    def key(seg):
        return ([(s.start_ns, s.end_ns, s.packet_start, s.packet_stop) for s in seg.stations],
                seg.motion_m.tobytes(), seg.still.tobytes(), seg.lever_correction_m.tobytes(),
                seg.notes)

    one = [segment_stations(rec.lidar, orient, e, cfg, num_threads=1) for e in (ext0, ext1)]
    assert len(one[0].stations) >= 2
    windows: dict = {}
    two = [segment_stations(rec.lidar, orient, e, cfg, num_threads=2, reuse=windows)
           for e in (ext0, ext1)]
    assert windows["samples"]  # the second pass had the first one's windows to place again
    for a, b in zip(one, two):
        assert key(a) == key(b)


def test_self_calibration_is_the_same_on_threads(rig):
    """The turns' time offset and the surfaces' fit with their stations side by side on threads
    give the one-thread result exactly (the capture: a hand pan with a pause and a reversal, a
    10 cm lever arm, 4 ms IMU latency)."""
    from tripod_processor.reconstruction.calibration import self_calibrate, time_offset_from_turns

    _, rec, orient = rig
    ext = Extrinsic.from_config(None, None)
    seg = segment_stations(rec.lidar, orient, ext, ReconstructConfig().stations, num_threads=1)
    assert len(seg.stations) >= 2
    turns = [time_offset_from_turns(rec.lidar, seg.stations, orient, ext, n) for n in (1, 2)]
    assert turns[0].pairs >= 3
    assert turns[0] == turns[1]
    cals = [self_calibrate(rec.lidar, seg.stations, orient, ext, num_threads=n) for n in (1, 2)]
    a, b = cals
    assert len(a.stations) >= 2 and a.pairs > 1000
    assert a.stations == b.stations and a.pairs == b.pairs
    assert np.array_equal(a.lever_arm_m, b.lever_arm_m)
    assert np.array_equal(a.R_imu_lidar, b.R_imu_lidar)
    assert a.time_offset_ns == b.time_offset_ns
    assert np.array_equal(a.lever_arm_sigma_m, b.lever_arm_sigma_m)
    assert a.iterations == b.iterations


def test_reconstruction_does_not_depend_on_the_threads(rig, tmp_path):
    from tripod_processor.reconstruction.pipeline import reconstruct

    cap, _, _ = rig
    out = {}
    for n in (1, 2):
        cfg = load_config(ReconstructConfig, overrides={"num_threads": n,
                                                        "output.report": False,
                                                        "output.write_mcap": False})
        out[n] = reconstruct(cap, tmp_path / f"t{n}", cfg, quiet=True)
    a, b = out[1], out[2]
    assert [(s.start_ns, s.end_ns) for s in a.segmentation.stations] == \
        [(s.start_ns, s.end_ns) for s in b.segmentation.stations]
    assert a.calibration == b.calibration  # the self-calibration's stations on threads
    for fa, fb in zip(a.fragments, b.fragments, strict=True):
        assert np.array_equal(fa.points, fb.points)
    assert [(e.i, e.j, e.kind) for e in a.slam.edges] == [(e.i, e.j, e.kind) for e in b.slam.edges]
    np.testing.assert_allclose(a.slam.T_odometry, b.slam.T_odometry, atol=1e-9)
    np.testing.assert_allclose(a.slam.T_optimized, b.slam.T_optimized, atol=1e-6)


def _serial_offset_tolerant(lidar, times, win, gap, orient, ext, e, motion, todo, cfg,
                            n_points, n_query, n_grid=5):
    """The one-window-at-a-time refit that ``stations._offset_tolerant_motion`` replaced (its
    windows and offsets now side by side on threads), for the windows ``todo``."""
    from tripod_processor.reconstruction import stations as S

    out = motion.copy()
    dmax_ns = int(cfg.max_time_offset_error_ms * 1e6)
    ab = np.searchsorted(lidar.lidar_ns, np.stack([times, times + win], axis=1))
    samples = {}

    def sample(k):
        if k not in samples:
            pts = S._window_points(lidar, int(ab[k, 0]), int(ab[k, 1]))
            rng = np.random.default_rng([0x5EED, k])
            samples[k] = S._window_sample(pts, S._window_subset(len(pts[0]), n_points, rng))
        return samples[k]

    for k in todo:
        j = k - gap
        sj, sk = sample(j), sample(k)
        if len(sj[0]) <= 50 or len(sk[0]) <= 50:
            continue

        def shift(d_ns):
            o = orient.with_offset(orient.time_offset_ns + int(d_ns))
            ref, a_j = S._place_window(lidar, int(ab[j, 0]), sj, o, ext)
            c, a_k = S._place_window(lidar, int(ab[k, 0]), sk, o, ext)
            fit = S.pivot_shift_fit(ref, c[:n_query])
            if fit is None:
                return float("inf")
            R_j, R_k = o.rotation_at(np.array([a_j, a_k]))
            d, P = fit
            return float(np.linalg.norm(P @ (d - (R_k - R_j) @ e)))

        grid = np.linspace(-dmax_ns, dmax_ns, n_grid).astype(np.int64)
        vals = [shift(int(t)) for t in grid]
        step = int(2 * dmax_ns // (n_grid - 1))
        best = int(grid[int(np.argmin(vals))])
        fine = [shift(best + int(t)) for t in np.linspace(-step, step, n_grid + 2)[1:-1]]
        out[k] = min(float(out[k]), min(vals), min(fine))
    return out


def test_station_refit_is_the_serial_one_on_threads(rig, monkeypatch):
    """The splitter's refit of windows where the pan rate changes (``_offset_tolerant_motion``,
    here with the IMU time offset 8 ms off so that the capture's pause and reversal need it)
    gives the serial loop's motions exactly, on 1 and 2 threads and in blocks of any size."""
    from tripod_processor.reconstruction import stations as S

    _, rec, orient = rig
    orient = orient.with_offset(8_000_000)
    ext = Extrinsic.from_config(None, None)
    cfg = ReconstructConfig().stations
    calls = []
    real = S._offset_tolerant_motion

    def spy(*args, **kw):
        out = real(*args, **kw)
        calls.append((args, kw, out.copy()))  # the splitter fills its gaps in place
        return out

    monkeypatch.setattr(S, "_offset_tolerant_motion", spy)
    segs = [segment_stations(rec.lidar, orient, ext, cfg, num_threads=n) for n in (1, 2)]
    assert [(s.start_ns, s.end_ns) for s in segs[0].stations] == \
        [(s.start_ns, s.end_ns) for s in segs[1].stations]
    (args, kw, out1), (_, _, out2) = calls
    lidar, times, win, gap, o, ex, axis, e, motion, imu_still, c, n_points, n_query = args
    refit = np.flatnonzero(out1 != motion)
    assert len(refit) >= 3  # the refit did run, and lowered some windows' motion
    assert np.array_equal(out1, out2)
    todo = np.flatnonzero(np.isfinite(motion) & (motion >= c.still_threshold) & imu_still)
    todo = [k for k in todo.tolist() if k >= gap]
    want = _serial_offset_tolerant(lidar, times, win, gap, o, ex, e, motion, todo, c,
                                   n_points, n_query)
    # the serial loop on every candidate; the threaded one skips those whose pan rate does not
    # change (their refit cannot lower the motion)
    assert np.array_equal(out1[refit], want[refit])
    small = real(*args, num_threads=2, block=2)
    assert np.array_equal(small, out1)


def test_fragment_on_the_fitted_anchor_is_the_slerped_one_moved_rigidly(rig):
    """A fragment anchored on the fitted attitude (``placement.anchor_fit``) holds the same
    world points as the slerped one: only its frame differs, by a small rotation."""
    from scipy.spatial.transform import Rotation

    from tripod_processor.reconstruction.fragments import build_fragment
    from tripod_processor.reconstruction.stations import Station

    _, rec, orient = rig
    ext = Extrinsic.from_config([0.97, 0.1, 0.2, 0.05], [0.03, 0.08, 0.01])
    t0 = int(rec.lidar.lidar_ns[0])
    s_ns, e_ns = t0 + 1_000_000_000, t0 + 4_000_000_000
    a, b = np.searchsorted(rec.lidar.lidar_ns, [s_ns, e_ns])
    st = Station(0, s_ns, e_ns, int(a), int(b))
    f0 = build_fragment(rec.lidar, st, orient, ext, 0.05, 0.4, 100.0, 2, anchor_fit=False)
    f1 = build_fragment(rec.lidar, st, orient, ext, 0.05, 0.4, 100.0, 2, anchor_fit=True)
    assert len(f0.points) == len(f1.points) > 1000
    dR = Rotation.from_matrix(f0.R_world_lidar.T @ f1.R_world_lidar).magnitude()
    assert 0 < np.degrees(dR) < 0.3  # the sample's noise, no more

    def world(f):
        R_wi = f.R_world_lidar @ ext.R_imu_lidar.T
        return f.points.astype(np.float64) @ f.R_world_lidar.T + R_wi @ ext.lever_arm_m

    assert np.abs(world(f0) - world(f1)).max() < 1e-5  # [m]: float32 at ~10 m


def _serial_merge_runs(runs, ctx, max_gap_s=10.0):
    """The gap-by-gap, vote-by-vote merge that ``stations._merge_runs`` replaced (each gap's
    two votes now side by side on threads); also the number of votes cast."""
    from tripod_processor.reconstruction import stations as S

    def same_place(i, j):
        out = []
        for k in (i, j):
            t = ctx.times[k]
            a, b = np.searchsorted(ctx.lidar.lidar_ns, [t, t + ctx.win])
            out.append(S._window_cloud(ctx.lidar, int(a), int(b), ctx.orient, ctx.ext,
                                       ctx.n_points, ctx.rng)[0])
        if len(out[0]) < 50 or len(out[1]) < 50:
            return None
        fit = S.pivot_shift_fit(out[0], out[1][: ctx.n_query])
        if fit is None:
            return None
        d, P = fit
        if np.linalg.matrix_rank(P) < 2:
            return None
        r = np.linalg.norm(P @ (d - (ctx.R_w[j] - ctx.R_w[i]) @ ctx.e))
        return bool(r < ctx.cfg.still_threshold)

    step_ns = int(ctx.times[1] - ctx.times[0])
    pan = S._pan_angle(ctx.R_w, ctx.axis)
    out, merged, cast = [runs[0]], 0, 0
    for k, e in runs[1:]:
        pk, pe = out[-1]
        if (ctx.times[k] - ctx.times[pe]) * 1e-9 > max_gap_s:
            out.append((k, e))
            continue
        sw = S._swing_deg(ctx.R_w[pe:pe + 1], ctx.R_w[k:k + 1], ctx.axis)[0]
        sw_gap = S._swing_deg(np.repeat(ctx.R_w[pe:pe + 1], k - pe + 1, axis=0),
                              ctx.R_w[pe:k + 1], ctx.axis).max()
        if sw > ctx.cfg.still_tilt_deg or sw_gap > 2 * ctx.cfg.still_tilt_deg:
            out.append((k, e))
            continue
        ii = np.arange(max(pk, pe - int(5e9 / step_ns)), pe + 1)
        jj = np.arange(k, min(e, k + int(5e9 / step_ns)) + 1)
        dphi = np.abs(np.angle(np.exp(1j * (pan[ii][:, None] - pan[jj][None, :]))))
        order = np.argsort(dphi, axis=None)[:2]
        votes = [same_place(int(ii[o // len(jj)]), int(jj[o % len(jj)])) for o in order]
        cast += len(votes)
        votes = [v for v in votes if v is not None]
        if votes and all(votes):
            out[-1] = (pk, e)
            merged += 1
        else:
            out.append((k, e))
    return out, merged, cast


def test_station_run_merge_is_the_serial_one_on_threads(rig, monkeypatch):
    """The splitter's merge of still runs across a gap where the pivot did not move (each gap's
    two votes on threads) gives the serial loop's runs and leaves the random draws where it
    did, on 1 and 2 threads (the capture's first pass, mount unknown: its runs are broken)."""
    import copy

    from tripod_processor.reconstruction import stations as S

    _, rec, orient = rig
    ext = Extrinsic.from_config(None, None)
    cfg = ReconstructConfig().stations
    seen = []
    real = S._merge_runs

    def spy(runs, ctx, *a, **kw):
        before = copy.deepcopy(ctx.rng.bit_generator.state)
        out = real(runs, ctx, *a, **kw)
        seen.append((list(runs), ctx, before, out, copy.deepcopy(ctx.rng.bit_generator.state)))
        return out

    monkeypatch.setattr(S, "_merge_runs", spy)
    for n in (1, 2):
        segment_stations(rec.lidar, orient, ext, cfg, num_threads=n)
    (runs, ctx, before, out1, after1), (_, _, _, out2, after2) = seen
    assert out1 == out2 and after1 == after2
    ctx.rng.bit_generator.state = before
    want, merged, cast = _serial_merge_runs(runs, ctx)
    assert cast >= 2  # votes were cast
    assert (want, merged) == out1
    assert ctx.rng.bit_generator.state == after1


def _quat_at_per_point(orient: ImuOrientation, t_ns: np.ndarray) -> np.ndarray:
    """The slerp as it was before its per-interval terms were tabled: every term per point."""
    t = np.asarray(t_ns, dtype=np.int64)
    ts = orient.t_ns
    i = np.clip(np.searchsorted(ts, t, side="right") - 1, 0, len(ts) - 2)
    dt = (ts[i + 1] - ts[i]).astype(np.float64)
    u = np.clip((t - ts[i]).astype(np.float64) / np.maximum(dt, 1.0), 0.0, 1.0)
    q0, q1 = orient._q[i], orient._q[i + 1]
    dot = np.clip(np.einsum("ij,ij->i", q0, q1), -1.0, 1.0)
    theta = np.arccos(dot)
    s = np.sin(theta)
    small = s < 1e-9
    w0 = np.where(small, 1.0 - u, np.sin((1.0 - u) * theta) / np.where(small, 1.0, s))
    w1 = np.where(small, u, np.sin(u * theta) / np.where(small, 1.0, s))
    q = w0[:, None] * q0 + w1[:, None] * q1
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def test_tabled_slerp_is_the_per_point_one_bit_for_bit(rig):
    _, rec, orient = rig
    rng = np.random.default_rng(5)
    t0, t1 = int(orient.t_ns[0]), int(orient.t_ns[-1])
    # inside, before and after the track (clamped), on the samples themselves
    t = np.concatenate([rng.integers(t0 - 10**9, t1 + 10**9, 200_000), orient.t_ns[::7]])
    for o in (orient, orient.with_offset(3_217_000), orient.with_offset(-8_000_001)):
        assert np.array_equal(o.quat_at(t), _quat_at_per_point(o, t))
    # repeated samples (a zero interval, a zero angle: the linear branch) and one sample alone
    from tripod_processor.reconstruction.inputs import ImuTrack

    imu = rec.imu
    host = np.repeat(np.asarray(imu.host_ns[:50]), 2)
    q = np.repeat(np.asarray(imu.q_wxyz[:50]), 2, axis=0)
    for track in (ImuTrack(host, q), ImuTrack(host[:1], q[:1])):
        o = ImuOrientation(track, 0, 0)
        tt = rng.integers(int(host[0]) - 10**8, int(host[-1]) + 10**8, 5000)
        assert np.array_equal(o.quat_at(tt), _quat_at_per_point(o, tt))


def test_blas_one_thread_inside_reconstruct_only():
    from threadpoolctl import threadpool_info

    from tripod_processor.reconstruction.scaleout import blas_one_thread

    before = [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]
    with blas_one_thread():
        assert all(i["num_threads"] == 1 for i in threadpool_info() if i["user_api"] == "blas")
    assert [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"] == before


def test_stacked_matmul_is_numpys_stacked_product():
    from scipy.spatial.transform import Rotation

    from tripod_processor.reconstruction.calibration import stacked_matmul
    from tripod_processor.reconstruction.scaleout import blas_one_thread

    R = Rotation.random(50_000, random_state=3).as_matrix()
    U = np.linalg.qr(np.random.default_rng(4).normal(size=(3, 3)))[0]
    with blas_one_thread():  # as inside reconstruct
        for M in (U[:, :2], U, Rotation.random(random_state=5).as_matrix()):
            assert np.array_equal(stacked_matmul(R, M), R @ M)
    for M in (U[:, :2], U):
        assert np.array_equal(stacked_matmul(R, M), R @ M)


def _old_offset_shift(lidar, ab, orient, ext, e, n_query, sj, sk, j, k, d_ns):
    """The per-(window pair, offset) shift that ``stations._ShiftEvaluator`` replaced: both
    windows placed anew for every offset."""
    from tripod_processor.reconstruction.stations import _place_window, pivot_shift_fit

    o = orient.with_offset(orient.time_offset_ns + int(d_ns))
    ref, a_j = _place_window(lidar, int(ab[j, 0]), sj, o, ext)
    c, a_k = _place_window(lidar, int(ab[k, 0]), sk, o, ext)
    fit = pivot_shift_fit(ref, c[:n_query])
    if fit is None:
        return float("inf")
    R_j, R_k = o.rotation_at(np.array([a_j, a_k]))
    d, P = fit
    return float(np.linalg.norm(P @ (d - (R_k - R_j) @ e)))


def test_shift_evaluator_gives_the_per_offset_shifts_bit_for_bit(rig):
    from concurrent.futures import ThreadPoolExecutor

    from tripod_processor.reconstruction.stations import (_ShiftEvaluator, _window_points,
                                                          _window_sample, _window_subset)

    _, rec, orient = rig
    lidar = rec.lidar
    ext = Extrinsic.from_config(None, None)
    win, step, gap, n_points, n_query = int(0.1e9), int(0.5e9), 1, 12000, 4000
    times = np.arange(int(lidar.lidar_ns[0]), int(lidar.lidar_ns[-1]) - win, step)[:12]
    ab = np.searchsorted(lidar.lidar_ns, np.stack([times, times + win], axis=1))
    samples = {}
    for w in range(len(times)):
        pts = _window_points(lidar, int(ab[w, 0]), int(ab[w, 1]))
        samples[w] = _window_sample(pts, _window_subset(len(pts[0]), n_points,
                                                        np.random.default_rng([0x5EED, w])))
    e = np.array([0.01, -0.02, 0.0])
    # windows 3, 4, 5 in a row (4 at δ is 5's reference at δ), a lone one, offsets repeated
    # across the two calls as the fine grid repeats the coarse grid's best
    coarse = [(k, d) for k in (3, 4, 5, 9) for d in (-12_000_000, 0, 12_000_000)]
    fine = [(k, d) for k in (3, 4, 9) for d in (-4_000_000, 0, 4_000_000)]
    with ThreadPoolExecutor(2) as pool:
        ev = _ShiftEvaluator(lidar, ab, samples, orient, ext, e, gap, n_query, pool)
        got = ev.values(coarse) + ev.values(fine)
    want = [_old_offset_shift(lidar, ab, orient, ext, e, n_query, samples[k - gap], samples[k],
                              k - gap, k, d) for k, d in coarse + fine]
    assert np.isfinite(want).sum() >= len(want) - 2
    assert np.array_equal(np.array(got), np.array(want))


def _old_window_shifts(lidar: LidarPackets, times: np.ndarray, win: int, gap: int,
                   orient: ImuOrientation, ext: Extrinsic, n_points: int, n_query: int,
                   rng: np.random.Generator, num_threads: int, progress=None,
                   reuse: dict | None = None, reuse_max_bytes: int = 512 << 20
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The block-wise ``stations._window_shifts`` the pipeline replaced (barriers between
    the decode, the draw, the placement and the fit of each block of 16 windows)."""
    import os
    from concurrent.futures import ThreadPoolExecutor

    from tripod_processor.reconstruction.stations import (_place_window, _window_points,
                                                          _window_sample, _window_subset,
                                                          pivot_shift_fit)

    K = len(times)
    anchors = np.zeros(K, dtype=np.int64)
    D = np.full((K, 3), np.nan)
    Pm = np.zeros((K, 3, 3))
    clouds: dict[int, np.ndarray] = {}
    ab = np.searchsorted(lidar.lidar_ns, np.stack([times, times + win], axis=1))
    block = 16

    def fit(k: int):
        ref, c = clouds.get(k - gap), clouds[k]
        if ref is not None and len(ref) > 50 and len(c) > 50:
            return pivot_shift_fit(ref, c[:n_query])
        return None

    key = (int(times[0]) if K else 0, K, win, n_points, id(lidar))
    cached = reuse.get("samples") if reuse is not None and reuse.get("key") == key else None
    keep: list | None = [] if reuse is not None and cached is None else None
    kept_bytes = 0
    workers = max(1, num_threads or (os.cpu_count() or 1))
    with ThreadPoolExecutor(workers) as pool:
        for s in range(0, K, block):
            ks = range(s, min(K, s + block))
            if cached is not None:
                samples = cached[s:s + len(ks)]
            else:
                pts = list(pool.map(lambda k: _window_points(lidar, int(ab[k, 0]),
                                                             int(ab[k, 1])), ks))
                samples = [_window_sample(p, _window_subset(len(p[0]), n_points, rng))
                           for p in pts]
                if keep is not None:
                    keep += samples
                    kept_bytes += sum(x.nbytes + t.nbytes + (0 if o is None else o.nbytes)
                                      for x, t, o in samples)
                    if kept_bytes > reuse_max_bytes:
                        keep = None  # too long a recording to keep: the next pass decodes
            placed = list(pool.map(lambda i: _place_window(lidar, int(ab[ks[i], 0]),
                                                           samples[i], orient, ext),
                                   range(len(ks))))
            for k, (c, anc) in zip(ks, placed):
                clouds[k], anchors[k] = c, anc
            for k, f in zip(ks, pool.map(fit, ks)):
                if f is not None:
                    D[k], Pm[k] = f
            for j in [j for j in clouds if j <= ks[-1] - gap]:
                del clouds[j]  # bounded memory
            if progress is not None:
                progress.update(len(ks))
    if cached is not None:
        rng.bit_generator.state = reuse["rng_state"]
    elif keep is not None:
        reuse.update(key=key, samples=keep, rng_state=rng.bit_generator.state)
    return anchors, D, Pm



def test_window_pipeline_gives_the_block_wise_shifts_bit_for_bit(rig):
    from tripod_processor.reconstruction.stations import _window_shifts

    _, rec, orient = rig
    lidar = rec.lidar
    ext = Extrinsic.from_config(None, None)
    win, step = int(0.1e9), int(0.5e9)
    times = np.arange(int(lidar.lidar_ns[0]), int(lidar.lidar_ns[-1]) - win, step)[:40]
    for gap, n_points, threads, ahead in ((1, 12000, 2, 32), (2, 3000, 1, 32), (1, 3000, 2, 3)):
        rng_old, rng_new = np.random.default_rng(0), np.random.default_rng(0)
        want = _old_window_shifts(lidar, times, win, gap, orient, ext, n_points, 4000, rng_old,
                                  2)
        reuse: dict = {}
        got = _window_shifts(lidar, times, win, gap, orient, ext, n_points, 4000, rng_new,
                             threads, reuse=reuse, ahead=ahead)
        assert rng_new.bit_generator.state == rng_old.bit_generator.state
        assert np.isfinite(want[1][:, 0]).sum() > len(times) // 2
        for w, g in zip(want, got):
            assert np.array_equal(w, g, equal_nan=True)
        # the second pass places the kept samples again: the same numbers, the rng moved on
        rng_again = np.random.default_rng(0)
        again = _window_shifts(lidar, times, win, gap, orient, ext, n_points, 4000, rng_again,
                               threads, reuse=reuse, ahead=ahead)
        assert rng_again.bit_generator.state == rng_old.bit_generator.state
        for w, g in zip(want, again):
            assert np.array_equal(w, g, equal_nan=True)


def test_timed_records_filled_in_place_equal_the_per_field_records(rig):
    """``decode_timed_points`` fills one record array in place (the shared fields in one
    multi-field copy): the same records, byte for byte, as each decoder call's points copied a
    field at a time into their own records, then concatenated (the old path)."""
    from tripod_processor.decode.native import NativeVlp16Decoder
    from tripod_processor.decode.timed import TIMED_POINT_DTYPE

    _, rec, _ = rig
    lid = rec.lidar
    for a, b, chunk in ((100, 2600, 1000), (7, 8, 1000), (50, 50, 1000), (0, 900, 128)):
        got = decode_timed_points(lid.payload, lid.lidar_ns, a, b, min_range=0.5,
                                  max_range=40.0, chunk=chunk)
        dec = NativeVlp16Decoder(min_range_m=0.5, max_range_m=40.0)
        ref = []
        for s in range(a, b, chunk):
            pts = dec.decode(lid.payload[s:min(b, s + chunk)],
                             lid.lidar_ns[s:min(b, s + chunk)]).points
            c = np.empty(len(pts), dtype=TIMED_POINT_DTYPE)
            for f in ("x", "y", "z", "intensity", "ring", "return_type"):
                c[f] = pts[f]
            c["time_ns"] = lid.lidar_ns[s] + pts["time_offset_ns"].astype(np.int64)
            ref.append(c)
        ref = np.concatenate(ref) if ref else np.empty(0, TIMED_POINT_DTYPE)
        assert got.dtype == TIMED_POINT_DTYPE and got.tobytes() == ref.tobytes()
        assert (len(got) > 0) == (b - a > 0)
