# SPDX-License-Identifier: BSD-3-Clause
"""deploy/: the systemd unit verifies and is hardened; the install script parses; sysctl and
config agree with the daemon's defaults."""

from __future__ import annotations

import configparser
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tripod_daemon.config import DaemonConfig

REPO = Path(__file__).resolve().parents[2]
UNIT = REPO / "deploy/systemd/tripod-daemon.service"


def _unit_with_local_binary(tmp_path: Path) -> Path:
    """The unit with ExecStart pointing at this checkout's tripod-daemon (verify checks that
    the binary exists; on the device install-device.sh puts it in /opt/tripod/venv)."""
    exe = Path(sys.executable).parent / "tripod-daemon"
    assert exe.exists(), exe
    text = UNIT.read_text().replace("/opt/tripod/venv/bin/tripod-daemon", str(exe))
    out = tmp_path / UNIT.name
    out.write_text(text)
    return out


def test_unit_passes_systemd_analyze_verify(tmp_path):
    assert shutil.which("systemd-analyze"), "systemd-analyze (Debian package systemd) needed"
    r = subprocess.run(["systemd-analyze", "verify", str(_unit_with_local_binary(tmp_path))],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "tripod-daemon.service" not in r.stderr  # no warnings about our unit


def test_unit_security_exposure_at_most_2_5(tmp_path):
    r = subprocess.run(["systemd-analyze", "security", "--offline=true", "--no-pager",
                        str(_unit_with_local_binary(tmp_path))], capture_output=True, text=True)
    m = re.search(r"Overall exposure level for tripod-daemon\.service: ([\d.]+)", r.stdout)
    assert m, r.stdout[-500:] + r.stderr
    assert float(m.group(1)) <= 2.5


def test_unit_has_the_service_contract():
    cp = configparser.ConfigParser(strict=False, interpolation=None)
    cp.optionxform = str
    cp.read_string(re.sub(r"^(DeviceAllow|SystemCallFilter)=", r"#\1=", UNIT.read_text(),
                          flags=re.M))
    s = cp["Service"]
    assert s["Type"] == "notify" and s["Restart"] == "on-failure"
    assert s["WatchdogSec"] and s["User"] == "tripod"
    assert s["ProtectSystem"] == "strict" and s["NoNewPrivileges"] == "yes"
    assert s["CapabilityBoundingSet"] == "" and s["DevicePolicy"] == "closed"
    assert "-HUP" in s["ExecReload"]
    assert "/var/lib/tripod/recordings" == DaemonConfig().recording.directory
    assert "tripod tripod/recordings" == s["StateDirectory"]


def test_sysctl_allows_the_default_receive_buffer():
    text = (REPO / "deploy/sysctl/90-tripod-daemon.conf").read_text()
    rmem = int(re.search(r"net\.core\.rmem_max\s*=\s*(\d+)", text).group(1))
    assert rmem >= DaemonConfig().lidar.receive_buffer_bytes


def test_udev_rule_names_the_device_the_unit_allows():
    rules = (REPO / "deploy/udev/99-tripod-imu.rules").read_text()
    assert 'SYMLINK+="tripod-imu"' in rules and 'GROUP="dialout"' in rules
    assert "SupplementaryGroups=dialout" in UNIT.read_text()


def test_install_script_parses_and_dry_runs():
    script = REPO / "deploy/install-device.sh"
    assert subprocess.run(["bash", "-n", str(script)]).returncode == 0
    r = subprocess.run([str(script), "--dry-run", "--no-start", "--prefix", "/opt/x"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    steps = r.stdout
    assert f"pip install {REPO}/shared {REPO}/daemon[panel]" in steps  # no processor
    assert "processor" not in steps
    assert "/etc/systemd/system/tripod-daemon.service" in steps
    assert "systemctl enable tripod-daemon.service tripod-panel.service" in steps
    assert "/etc/systemd/system/tripod-panel.service" in steps
    assert "gen-certs /root/tripod-ca" in steps
    assert "/etc/tripod/credentials/panel-credentials" in steps


def test_daemon_stays_light():
    """The capture device installs only tripod-shared and tripod-daemon: nothing the daemon
    imports may pull in the processor or its heavy dependencies."""
    code = (
        "import sys, tripod_daemon.main, tripod_daemon.loop, tripod_daemon.publisher, "
        "tripod_daemon.recover, tripod_daemon.watch\n"
        "heavy = [m for m in ('tripod_processor', 'torch', 'open3d', 'scipy', 'matplotlib', "
        "'velodyne_decoder') if m in sys.modules]\n"
        "print(heavy)\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "[]"
    import tomllib

    meta = tomllib.loads((REPO / "daemon/pyproject.toml").read_text())["project"]
    deps = " ".join(meta["dependencies"])
    assert "tripod-processor" not in deps and "torch" not in deps and "open3d" not in deps


PANEL_UNIT = REPO / "deploy/systemd/tripod-panel.service"


def test_panel_unit_verifies_and_is_hardened(tmp_path):
    exe = Path(sys.executable).parent / "tripod-daemon"
    unit = tmp_path / PANEL_UNIT.name
    unit.write_text(PANEL_UNIT.read_text().replace("/opt/tripod/venv/bin/tripod-daemon", str(exe)))
    r = subprocess.run(["systemd-analyze", "verify", str(unit)], capture_output=True, text=True)
    assert r.returncode == 0 and "tripod-panel.service" not in r.stderr, r.stderr
    r = subprocess.run(["systemd-analyze", "security", "--offline=true", "--no-pager", str(unit)],
                       capture_output=True, text=True)
    m = re.search(r"Overall exposure level for tripod-panel\.service: ([\d.]+)", r.stdout)
    assert m and float(m.group(1)) <= 2.0, r.stdout[-500:]
    text = PANEL_UNIT.read_text()
    assert "ExecStart=/opt/tripod/venv/bin/tripod-daemon panel --config /etc/tripod/daemon.yaml" \
        in text and "User=tripod" in text and "PrivateDevices=yes" in text


def test_panel_stays_light():
    """The panel's extra is two small pure-Python packages, and the daemon never imports them."""
    import tomllib

    extras = tomllib.loads((REPO / "daemon/pyproject.toml").read_text())["project"][
        "optional-dependencies"]
    assert [d.split(">")[0] for d in extras["panel"]] == ["starlette", "uvicorn"]
    code = ("import sys, tripod_daemon.main, tripod_daemon.loop, tripod_daemon.ctl\n"
            "print([m for m in ('starlette', 'uvicorn', 'selenium') if m in sys.modules])\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0 and r.stdout.strip() == "[]", r.stderr


def test_secure_example_config_loads_with_generated_credentials(tmp_path, monkeypatch):
    from tripod_daemon.certs import gen_certs
    from tripod_daemon.config import ConfigError, load

    creds = tmp_path / "creds"
    certs = tmp_path / "certs"
    gen_certs(str(certs), ["localhost"], ["operator"])
    creds.mkdir()
    for name in ("device.pem", "device.key", "ca.pem"):  # as LoadCredential=tripod:DIR names them
        (creds / f"tripod_{name}").write_bytes((certs / name).read_bytes())
    (creds / "tripod_zenoh-users").write_text("operator:x\n")
    monkeypatch.setenv("CREDENTIALS_DIRECTORY", str(creds))
    cfg = load(str(REPO / "deploy/etc/daemon.secure.yaml"), system_config=None)
    assert cfg.zenoh.tls.certificate == str(creds / "tripod_device.pem")
    assert cfg.zenoh.listen == ["tls/0.0.0.0:7447"] and cfg.zenoh.control.users == ["operator"]
    assert "LoadCredential=tripod:/etc/tripod/credentials" in UNIT.read_text()
    monkeypatch.setenv("CREDENTIALS_DIRECTORY", str(tmp_path / "nothing"))
    with pytest.raises(ConfigError, match="file not found"):
        load(str(REPO / "deploy/etc/daemon.secure.yaml"), system_config=None)


def test_gen_certs_with_a_relative_folder(tmp_path, monkeypatch):
    """`tripod-daemon gen-certs certs` run from the folder above (openssl runs inside it)."""
    from tripod_daemon.certs import gen_certs

    monkeypatch.chdir(tmp_path)
    written = gen_certs("certs", ["localhost"], ["operator"])
    for name in ("ca.pem", "device.pem", "device.key", "operator.pem", "operator.key"):
        assert (tmp_path / "certs" / name).stat().st_size > 0
    assert all(p.startswith(str(tmp_path)) for p in written)
