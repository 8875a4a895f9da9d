# SPDX-License-Identifier: BSD-3-Clause
"""Config: the commented default file, unknown keys, layering and command-line overrides."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from tripod_daemon import config
from tripod_daemon.main import _overrides, _run_parser, main

REPO = Path(__file__).resolve().parents[2]


def test_deploy_default_config_is_the_packaged_one_and_the_defaults():
    text = (REPO / "deploy/etc/daemon.yaml").read_text()
    assert text == config.default_config_text()
    cfg = config.load(str(REPO / "deploy/etc/daemon.yaml"), system_config=None)
    assert cfg == config.DaemonConfig()
    # every key of the model appears in the file (fully commented default)
    data = yaml.safe_load(text)
    assert config.DaemonConfig.model_validate(data).model_dump() == config.DaemonConfig().model_dump()
    for section in ("lidar", "imu", "zenoh", "recording", "status", "health"):
        assert set(data[section]) == set(type(getattr(config.DaemonConfig(), section)).model_fields)


def test_print_default_config(capsys):
    assert main(["--print-default-config"]) == 0
    assert capsys.readouterr().out == config.default_config_text()


def test_unknown_key_is_a_one_line_error_naming_it(tmp_path, capsys):
    p = tmp_path / "bad.yaml"
    p.write_text("lidar:\n  data_prot: 2368\n")
    with pytest.raises(config.ConfigError, match=r"unknown key 'lidar.data_prot'"):
        config.load(str(p), system_config=None)
    assert main(["--no-system-config", "--config", str(p)]) == 2
    err = capsys.readouterr().err
    assert "unknown key 'lidar.data_prot'" in err and err.count("\n") == 1


def test_bad_values_and_missing_file(tmp_path):
    p = tmp_path / "bad.yaml"
    p.write_text("recording:\n  fsync: sometimes\n")
    with pytest.raises(config.ConfigError, match="recording.fsync"):
        config.load(str(p), system_config=None)
    with pytest.raises(config.ConfigError, match="not found"):
        config.load(str(tmp_path / "nope.yaml"), system_config=None)
    p.write_text("device_id: 'a/b'\n")
    with pytest.raises(config.ConfigError, match="device_id"):
        config.load(str(p), system_config=None)


def test_layering_system_file_then_config_then_flags(tmp_path):
    system = tmp_path / "system.yaml"
    system.write_text("lidar:\n  data_port: 1111\n  position_port: 2222\nimu:\n  url: /dev/a\n")
    user = tmp_path / "user.yaml"
    user.write_text("lidar:\n  data_port: 3333\n")
    args = _run_parser().parse_args(
        ["--imu", "socket://localhost:4223", "--zenoh-connect", "tcp/10.0.0.1:7447",
         "--record-dir", "/data", "--no-record"])
    cfg = config.load(str(user), _overrides(args), system_config=str(system))
    assert cfg.lidar.data_port == 3333  # --config over the system file
    assert cfg.lidar.position_port == 2222  # kept from the system file
    assert cfg.imu.url == "socket://localhost:4223"  # flag over both
    assert cfg.zenoh.connect == ["tcp/10.0.0.1:7447"]
    assert cfg.recording.directory == "/data" and cfg.recording.enabled is False


@pytest.mark.parametrize("text,match", [
    ("recording:\n  enabled: false\n  enabled: true\n", "duplicate key 'enabled'"),
    ("lidar:\n  data_port: 1\nlidar:\n  position_port: 2\n", "duplicate key 'lidar'"),
    ("recording:\n  enabled: yes\n", "recording.enabled"),
    ("zenoh:\n  enabled: 'on'\n", "zenoh.enabled"),
    ("zenoh:\n  enabled: \"true\"\n", "zenoh.enabled"),
    ("zenoh:\n  listen: [tcp/0.0.0.0]\n", "host:port"),
    ("zenoh:\n  listen: [tcp/0.0.0.0:99999]\n", "port 0..65535"),
    ("zenoh:\n  connect: [tpc/10.0.0.1:7447]\n", "unknown protocol 'tpc'"),
    ("zenoh:\n  connect: ['tcp/10.0.0.300:7447']\n", "not an IPv4 address"),
    ("zenoh:\n  listen: ['127.0.0.1:7447']\n", "not proto/address"),
    ("zenoh:\n  config_file: /nonexistent/zenoh.json5\n", "file not found: /nonexistent"),
    ("zenoh:\n  tls:\n    client_ca: /nonexistent/ca.pem\n", "file not found"),
    ("zenoh:\n  listen: [tls/0.0.0.0:7447]\n", "needs tls.certificate"),
    ("zenoh:\n  control:\n    users: [operator]\n", "needs auth.users_file"),
])
def test_strict_config_exits_2_with_one_line(tmp_path, capsys, text, match):
    p = tmp_path / "bad.yaml"
    p.write_text(text)
    with pytest.raises(config.ConfigError, match=match):
        config.load(str(p), system_config=None)
    assert main(["--no-system-config", "--config", str(p)]) == 2
    err = capsys.readouterr().err
    assert match.split("'")[0] in err and err.count("\n") == 1, err


def test_valid_endpoints_and_credentials_directory(tmp_path, monkeypatch):
    for ep in ("tcp/0.0.0.0:7447", "tcp/[::1]:7447", "udp/tripod.local:7447",
               "tls/192.168.1.5:7447#iface=eth0", "unixsock-stream//run/tripod.sock"):
        assert config.check_endpoint(ep) == ep
    (tmp_path / "zenoh-users").write_text("operator:secret\n")
    monkeypatch.setenv("CREDENTIALS_DIRECTORY", str(tmp_path))
    p = tmp_path / "ok.yaml"
    p.write_text("zenoh:\n  auth:\n    users_file: ${CREDENTIALS_DIRECTORY}/zenoh-users\n"
                 "  control:\n    users: [operator]\n    allow_loopback: false\n"
                 "recording:\n  enabled: false\n")
    cfg = config.load(str(p), system_config=None)
    assert cfg.zenoh.auth.users_file == str(tmp_path / "zenoh-users")
    assert cfg.recording.enabled is False
