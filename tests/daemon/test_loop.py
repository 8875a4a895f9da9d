# SPDX-License-Identifier: BSD-3-Clause
"""The running daemon: Zenoh status and control queryables, SIGHUP reload, bad start-up."""

from __future__ import annotations

import json
import signal

import zenoh

from tripod_shared import messages, topics
from tripod_shared.config_io import ConfigError
from tripod_shared.recording import RecordingReader

from daemon_helpers import (
    RunningDaemon,
    free_tcp_port,
    loopback_config,
    make_data_packet,
    send_paced,
    udp_sender,
)
from tripod_daemon.loop import Daemon
from tripod_daemon.systemd import Notifier
from tripod_daemon.config import ZenohConfig
from tripod_daemon.publisher import build_zenoh_config


def _client(port: int) -> zenoh.Session:
    # a subscriber peer: the daemon's own config builder, connecting to it
    conf = build_zenoh_config(ZenohConfig(listen=[], connect=[f"tcp/127.0.0.1:{port}"]))
    return zenoh.open(conf)


def _query(session, key: str, timeout: float = 5.0) -> dict:
    for reply in session.get(key, timeout=timeout):
        if reply.ok is not None:
            return json.loads(reply.ok.payload.to_bytes())
        return {"error_reply": reply.err.payload.to_bytes().decode()}
    return {}


def test_status_and_control_queryables(tmp_path):
    port = free_tcp_port()
    cfg = loopback_config(tmp_path, zenoh={"enabled": True, "listen": [f"tcp/127.0.0.1:{port}"]})
    dev = cfg.device_id
    with RunningDaemon(cfg) as d, _client(port) as z:
        status = {}
        assert d.wait_for(lambda: bool(status.update(_query(z, topics.key_status(dev), 1.0))
                                       or status), timeout=15)
        assert status["state"] == "recording" and status["recording"] is True
        assert "lidar_data" in status["counts"] and "lidar" in status["clocks"]
        first = d.daemon.recorder.file

        r = _query(z, topics.key_control(dev, "mark") + "?label=station-1")
        assert r["ok"] is True and r["label"] == "station-1"
        send_paced(udp_sender(), d.data_addr, [make_data_packet(k) for k in range(20)], 1000)
        assert d.wait_for(lambda: d.daemon.counts["lidar_data"] == 20)

        r = _query(z, topics.key_control(dev, "stop"))
        assert r == {"ok": True, "recording": False, "file": None}
        r = _query(z, topics.key_control(dev, "mark") + "?label=ignored")
        assert r["ok"] is False  # nothing to mark into

        r = _query(z, topics.key_control(dev, "start"))
        assert r["ok"] is True and r["file"] != first
        r = _query(z, topics.key_control(dev, "reboot"))
        assert "unknown command" in r.get("error_reply", "")
        assert d.stop() == 0
    f1, f2 = d.daemon.recorder.files
    events = [(e.kind, e.label) for e in RecordingReader(f1).events()]
    assert events[0][0] == "start" and ("mark", "station-1") in events
    assert events[-1] == ("stop", "control")
    assert len(list(RecordingReader(f1).lidar_packets())) == 20
    assert [e.kind for e in RecordingReader(f2).events()] == ["start", "stop"]


def test_sighup_rereads_config_and_starts_a_new_file(tmp_path):
    cfg = loopback_config(tmp_path)
    new = cfg.model_copy(deep=True)
    new.recording.prefix = "station"
    calls = []

    def reload():
        calls.append(1)
        if len(calls) == 2:
            raise ConfigError("daemon.yaml: unknown key 'lidar.prot'")
        return new

    with RunningDaemon(cfg, reload_config=reload) as d:
        port = d.daemon.lidar.data_port
        send_paced(udp_sender(), d.data_addr, [make_data_packet(k) for k in range(10)], 1000)
        assert d.wait_for(lambda: d.daemon.counts["lidar_data"] == 10)
        d.daemon.signal(signal.SIGHUP)
        assert d.wait_for(lambda: len(d.daemon.recorder.files) == 2
                          and "station_" in (d.daemon.recorder.file or ""))
        send_paced(udp_sender(), d.data_addr, [make_data_packet(k) for k in range(10, 15)], 1000)
        assert d.wait_for(lambda: d.daemon.counts["lidar_data"] == 15)
        d.daemon.signal(signal.SIGHUP)  # a broken config: logged, old one kept
        assert d.wait_for(lambda: len(calls) == 2)
        assert d.daemon.lidar.data_port == port and d.daemon.recorder.active
        assert d.stop() == 0
    old_files = sorted((tmp_path / "rec").glob("tripod_*.mcap"))
    new_files = sorted((tmp_path / "rec").glob("station_*.mcap"))
    assert len(old_files) == 1 and len(new_files) == 1
    assert len(list(RecordingReader(old_files[0]).lidar_packets())) == 10
    assert len(list(RecordingReader(new_files[0]).lidar_packets())) == 5


def test_port_in_use_fails_start_up_cleanly(tmp_path):
    import socket

    blocker = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    blocker.bind(("127.0.0.1", 0))
    try:
        cfg = loopback_config(tmp_path, lidar={"data_port": blocker.getsockname()[1]})
        d = Daemon(cfg, notifier=Notifier({}), install_signal_handlers=False)
        assert d.run() == 1
    finally:
        blocker.close()


def test_status_message_is_valid_json_schema_shape(tmp_path):
    cfg = loopback_config(tmp_path)
    with RunningDaemon(cfg) as d:
        st = messages.decode_status(d.daemon.status_json())
        assert st.state == "recording" and st.file.endswith(".mcap")
        assert set(st.counts) >= {"lidar_data", "lidar_malformed", "record_dropped"}
        d.stop()


def test_watch_prints_the_live_rates(tmp_path, capsys):
    from tripod_daemon.main import main

    port = free_tcp_port()
    cfg = loopback_config(tmp_path, zenoh={"enabled": True, "listen": [f"tcp/127.0.0.1:{port}"]})
    with RunningDaemon(cfg) as d:
        import threading

        stop = threading.Event()

        def feed():
            k = 0
            s = udp_sender()
            while not stop.is_set():
                s.sendto(make_data_packet(k), d.data_addr)
                k += 1
                stop.wait(0.01)

        t = threading.Thread(target=feed, daemon=True)
        t.start()
        assert main(["watch", "--connect", f"tcp/127.0.0.1:{port}", "--seconds", "2.5"]) == 0
        stop.set()
        t.join()
        d.stop()
    out = capsys.readouterr().out
    assert "watching tripod/tripod0/{lidar/blocks," in out
    assert "lidar/packets" in out and "[recording" in out
    assert "lidar lost 0, stamp gaps" in out  # blocks came, none lost between daemon and here


def test_zenoh_endpoint_in_use_keeps_recording(tmp_path):
    import socket

    blocker = socket.socket()
    blocker.bind(("127.0.0.1", 0))
    blocker.listen(1)
    port = blocker.getsockname()[1]
    try:
        cfg = loopback_config(tmp_path, zenoh={"enabled": True,
                                               "listen": [f"tcp/127.0.0.1:{port}"]})
        with RunningDaemon(cfg) as d:
            assert d.daemon.publisher is None and "zenoh unavailable" in d.daemon.zenoh_error
            send_paced(udp_sender(), d.data_addr, [make_data_packet(k) for k in range(50)], 1000)
            assert d.wait_for(lambda: d.daemon.counts["lidar_data"] == 50)
            assert d.wait_for(lambda: b"zenoh unavailable" in d.daemon.status_json())
            assert d.stop() == 0
    finally:
        blocker.close()
    assert len(list(RecordingReader(d.daemon.recorder.files[0]).lidar_packets())) == 50


def test_control_and_reload_under_load_never_stall_reception(tmp_path):
    import threading

    cfg = loopback_config(tmp_path, lidar={"receive_buffer_bytes": 64 << 20})
    n = 40_000
    packets = [make_data_packet(k) for k in range(n)]
    with RunningDaemon(cfg, reload_config=lambda: cfg) as d:
        results = []

        def operator():
            import time as _t

            _t.sleep(0.3)
            results.append(d.daemon.control("mark", "busy"))
            results.append(d.daemon.control("stop", "pause"))
            _t.sleep(0.2)
            results.append(d.daemon.control("start", "resume"))
            d.daemon.signal(signal.SIGHUP)  # new file with the same config

        t = threading.Thread(target=operator)
        t.start()
        send_paced(udp_sender(), d.data_addr, packets, 20_000)
        t.join()
        c = d.daemon.counts
        assert d.wait_for(lambda: c["lidar_data"] == n, timeout=15)
        assert d.stop() == 0
    assert c["lidar_kernel_drops"] == 0 and c["record_dropped"] == 0
    assert [r["ok"] for r in results] == [True, True, True]
    assert results[2]["file"] and results[2]["file"].endswith(".mcap")
    files = d.daemon.recorder.files
    assert len(files) == 3  # before the stop, after the start, after SIGHUP
    got = [p for f in files for _ns, p in RecordingReader(f).lidar_packets()]
    # in order, no duplicates; only what arrived while stopped (0.2 s) is absent
    idx = [int.from_bytes(p[2:6], "little") for p in got]  # the sequence number
    assert idx == sorted(set(idx))
    assert n - len(got) < 0.6 * 20_000


def test_sighup_applies_new_lidar_and_imu_settings(tmp_path):
    cfg = loopback_config(tmp_path)
    new = cfg.model_copy(deep=True)
    new.lidar.accept_products = [0x22]  # a changed lidar section: sockets are reopened
    new.imu.url = str(tmp_path / "not-there")  # an IMU appears in the config
    with RunningDaemon(cfg, reload_config=lambda: new) as d:
        old_lidar = d.daemon.lidar
        d.daemon.signal(signal.SIGHUP)
        assert d.wait_for(lambda: (li := d.daemon.lidar) is not None and li is not old_lidar
                          and li.cfg.accept_products == [0x22]
                          and d.daemon.imu is not None)
        s = udp_sender()
        s.sendto(make_data_packet(1), d.data_addr)
        s.sendto(make_data_packet(2, product=0x21), d.data_addr)  # now foreign
        c = d.daemon.counts
        assert d.wait_for(lambda: c["lidar_data"] == 1 and c["lidar_foreign"] == 1)
        assert d.wait_for(lambda: b"not-there" in d.daemon.status_json())  # IMU error shown
        assert d.stop() == 0
