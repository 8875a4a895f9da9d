# SPDX-License-Identifier: BSD-3-Clause
"""``tripod-daemon ctl`` against a real daemon on loopback: status, start, stop, mark, the exit
codes (0 done, 1 refused, 2 usage/connection) and one-line errors for wrong credentials."""

from __future__ import annotations

import json

import pytest

from daemon_helpers import RunningDaemon, free_tcp_port, loopback_config, mutual_tls_setup
from tripod_daemon.ctl import main as ctl
from tripod_shared.recording import RecordingReader


def _run(capsys, *args) -> tuple[int, str, str]:
    rc = ctl(list(args))
    out, err = capsys.readouterr()
    return rc, out, err


def _daemon(tmp_path, **zenoh):
    port = free_tcp_port()
    ep = f"tcp/127.0.0.1:{port}"
    cfg = loopback_config(tmp_path, zenoh={"enabled": True, "listen": [ep], **zenoh})
    return cfg, ep


def test_round_trip_status_mark_stop_start(tmp_path, capsys):
    cfg, ep = _daemon(tmp_path)
    with RunningDaemon(cfg) as d:
        rc, out, err = _run(capsys, "status", "--connect", ep)
        assert rc == 0, err
        assert out.startswith("state     recording (") and "lidar     0 packets/s" in out
        rc, out, _ = _run(capsys, "status", "--json", "--connect", ep)
        st = json.loads(out)
        assert rc == 0 and st["recording"] is True and st["disk"]["free_bytes"] > 0
        assert st["disk"]["file_started_ns"] > 0
        first = d.daemon.recorder.file

        rc, out, err = _run(capsys, "mark", "station 1", "--connect", ep)
        assert (rc, out.strip()) == (0, f"marked 'station 1' in {first}"), err
        rc, out, _ = _run(capsys, "stop", "--connect", ep)
        assert (rc, out.strip()) == (0, "stopped")
        assert d.wait_for(lambda: not d.daemon.recorder.active)
        # a mark while not recording is refused: exit 1, one line saying why
        rc, out, err = _run(capsys, "mark", "lost", "--connect", ep)
        assert rc == 1 and out == ""
        assert err.strip() == ("tripod-daemon ctl: mark: not recording: the mark was not "
                               "written (start first)")
        rc, out, _ = _run(capsys, "start", "--connect", ep, "--json")
        reply = json.loads(out)
        assert rc == 0 and reply["ok"] and reply["recording"] and reply["file"] != first
        rc, _, _ = _run(capsys, "mark", "--connect", ep)  # no label
        assert rc == 0
        d.stop()
    files = d.daemon.recorder.files
    assert len(files) == 2
    ev0 = [(e.kind, e.label) for e in RecordingReader(files[0]).events()]
    ev1 = [(e.kind, e.label) for e in RecordingReader(files[1]).events()]
    assert ("mark", "station 1") in ev0 and ("mark", "lost") not in ev0 + ev1
    assert ("mark", "") in ev1


def test_refusals_exit_1_with_the_reason(tmp_path, capsys):
    cfg, ep = _daemon(tmp_path)
    with RunningDaemon(cfg):
        rc, _, err = _run(capsys, "mark", "x" * 300, "--connect", ep)
        assert rc == 1
        assert err.strip() == "tripod-daemon ctl: mark: label too long: 300 bytes > 256"


def _users(tmp_path):
    users = tmp_path / "zenoh-users"
    users.write_text("operator:op-secret\nviewer:view-secret\n")
    files = {}
    for name, line in (("operator", "operator:op-secret"), ("viewer", "viewer:view-secret"),
                       ("wrong", "operator:guess")):
        files[name] = tmp_path / f"{name}.cred"
        files[name].write_text(f"# login for ctl\n{line}\n")
    return users, files


def test_logins_wrong_password_and_not_allowed(tmp_path, capsys, monkeypatch):
    users, cred = _users(tmp_path)
    cfg, ep = _daemon(tmp_path, auth={"users_file": str(users)},
                      control={"allow_loopback": False, "users": ["operator"]})
    with RunningDaemon(cfg) as d:
        # wrong password: no session, exit 2, one clear line
        rc, out, err = _run(capsys, "stop", "--connect", ep, "--credentials", str(cred["wrong"]),
                            "--timeout", "2")
        assert rc == 2 and out == ""
        assert err.strip() == (f"tripod-daemon ctl: {ep} answers but refused the session: "
                               "user 'operator': wrong user or password?")
        # no credentials at all
        rc, _, err = _run(capsys, "status", "--connect", ep, "--timeout", "2")
        assert rc == 2 and "it may ask for a login (--credentials FILE)" in err
        assert len(err.strip().splitlines()) == 1
        # a viewer logs in and reads the status, but may not control: exit 1
        rc, out, _ = _run(capsys, "status", "--connect", ep, "--credentials", str(cred["viewer"]))
        assert rc == 0 and "recording" in out
        rc, _, err = _run(capsys, "stop", "--connect", ep, "--credentials", str(cred["viewer"]),
                          "--timeout", "1.5")
        assert rc == 1
        assert err.strip() == ("tripod-daemon ctl: stop: control/stop refused: user 'viewer' "
                               "is not allowed to control tripod/tripod0 (the daemon's "
                               "zenoh.control)")
        assert d.daemon.recorder.active and d.daemon.counts["control_requests"] == 0
        # the operator may; credentials also from $TRIPOD_CREDENTIALS
        monkeypatch.setenv("TRIPOD_CREDENTIALS", str(cred["operator"]))
        rc, out, err = _run(capsys, "stop", "--connect", ep)
        assert (rc, out.strip()) == (0, "stopped"), err
        assert d.wait_for(lambda: not d.daemon.recorder.active)


def test_connection_and_usage_errors_exit_2(tmp_path, capsys):
    port = free_tcp_port()  # nothing listens there
    rc, _, err = _run(capsys, "status", "--connect", f"tcp/127.0.0.1:{port}", "--timeout", "1")
    assert rc == 2 and err.startswith(f"tripod-daemon ctl: cannot connect to tcp/127.0.0.1:{port}")
    assert len(err.strip().splitlines()) == 1
    rc, _, err = _run(capsys, "status", "--connect", "tcp/nowhere")
    assert rc == 2 and "needs host:port" in err
    rc, _, err = _run(capsys, "stop", "now", "--connect", "tcp/127.0.0.1:1")
    assert rc == 2 and "stop takes no label" in err
    rc, _, err = _run(capsys, "reboot")
    assert rc == 2 and "invalid choice" in err
    rc, _, err = _run(capsys, "status", "--credentials", str(tmp_path / "missing"))
    assert rc == 2 and "credentials file" in err and "No such file" in err
    bad = tmp_path / "bad.cred"
    bad.write_text("just-a-password\n")
    rc, _, err = _run(capsys, "status", "--credentials", str(bad))
    assert rc == 2 and "expected one line 'user:password'" in err


@pytest.mark.parametrize("argv", [["ctl", "--help"]])
def test_ctl_is_a_subcommand(argv, capsys):
    from tripod_daemon.main import main

    assert main(argv) == 0
    assert "Exit codes: 0 done, 1 refused" in capsys.readouterr().out


def test_mutual_tls_with_the_ca_and_client_certificates(tmp_path, capsys):
    cfg, ep, certs, ca = mutual_tls_setup(tmp_path)

    def tls(name):
        return ["--connect", ep, "--ca", ca, "--cert", str(certs / f"{name}.pem"),
                "--key", str(certs / f"{name}.key")]

    with RunningDaemon(cfg) as d:
        rc, _, err = _run(capsys, "stop", *tls("viewer"), "--timeout", "1.5")
        assert rc == 1 and "'viewer'" not in err and "this client is not allowed" in err
        rc, out, err = _run(capsys, "stop", *tls("operator"))
        assert (rc, out.strip()) == (0, "stopped"), err
        assert d.wait_for(lambda: not d.daemon.recorder.active)
        # without a client certificate the daemon refuses the TLS session: exit 2
        rc, _, err = _run(capsys, "status", "--connect", ep, "--ca", ca, "--timeout", "2")
        assert rc == 2 and "answers but refused the session" in err and "--cert/--key" in err
        rc, _, err = _run(capsys, "status", "--connect", ep, "--cert", str(certs / "x.pem"),
                          "--key", str(certs / "x.key"))
        assert rc == 2 and err.strip() == (f"tripod-daemon ctl: --cert: file not found: "
                                           f"{certs / 'x.pem'}")
