#!/usr/bin/env bash
# SPDX-License-Identifier: BSD-3-Clause
# Install tripod-daemon on the capture device (Debian/Raspberry Pi OS with systemd), as root:
#   deploy/install-device.sh [--prefix /opt/tripod] [--no-start] [--dry-run]
# Creates the system user 'tripod', a venv with only tripod-shared + tripod-daemon[panel] (no
# PCL, Ceres, torch), the config /etc/tripod/daemon.yaml (kept if present), the device's
# certificate and the panel's password (made once, kept), the systemd units (daemon and panel),
# the udev rule for /dev/tripod-imu and the receive-buffer sysctl; then enables and starts them.
set -euo pipefail

PREFIX=/opt/tripod
START=1
DRY=0
while [ $# -gt 0 ]; do
  case "$1" in
    --prefix) PREFIX="$2"; shift 2 ;;
    --no-start) START=0; shift ;;
    --dry-run) DRY=1; shift ;;
    -h|--help) sed -n '3,8p' "$0"; exit 0 ;;
    *) echo "install-device.sh: unknown option $1" >&2; exit 2 ;;
  esac
done

REPO="$(cd "$(dirname "$0")/.." && pwd)"
run() { echo "+ $*"; [ "$DRY" -eq 1 ] || "$@"; }

if [ "$DRY" -eq 0 ] && [ "$(id -u)" -ne 0 ]; then
  echo "install-device.sh: run as root (or with sudo)" >&2; exit 1
fi

# 1. user and groups
if ! id tripod >/dev/null 2>&1; then
  run useradd --system --home-dir /var/lib/tripod --no-create-home --shell /usr/sbin/nologin \
    --groups dialout tripod
fi

# 2. Python environment: the light device dependencies only
run python3 -m venv "$PREFIX/venv"
run "$PREFIX/venv/bin/pip" install --upgrade pip
run "$PREFIX/venv/bin/pip" install "$REPO/shared" "$REPO/daemon[panel]"

# 3. config (never overwrite an operator's file); secrets go to the root-only credentials
#    directory the unit loads with LoadCredential= (deploy/README.md: certificates and logins)
run install -d -m 0755 /etc/tripod
run install -d -m 0700 /etc/tripod/credentials
run install -m 0644 "$REPO/deploy/etc/daemon.secure.yaml" /etc/tripod/daemon.secure.yaml.example
if [ ! -e /etc/tripod/daemon.yaml ]; then
  run install -m 0644 "$REPO/deploy/etc/daemon.yaml" /etc/tripod/daemon.yaml
else
  echo "keeping /etc/tripod/daemon.yaml (new defaults: tripod-daemon --print-default-config)"
fi

# 3b. the device's certificate (the panel's HTTPS, tls/ endpoints) and the panel's password,
# made once when absent, into the root-only credentials directory. The CA that signs the
# certificate stays in /root/tripod-ca (move it off the device: deploy/README.md).
if [ ! -e /etc/tripod/credentials/device.pem ]; then
  run "$PREFIX/venv/bin/tripod-daemon" gen-certs /root/tripod-ca --name "$(hostname)" \
    --name "$(hostname).local" --client operator
  run install -m 0600 /root/tripod-ca/device.pem /root/tripod-ca/device.key \
    /root/tripod-ca/ca.pem /etc/tripod/credentials/
fi
if [ ! -e /etc/tripod/credentials/panel-credentials ]; then
  echo "+ (umask 077; echo operator:<random> > /etc/tripod/credentials/panel-credentials)"
  if [ "$DRY" -eq 0 ]; then
    (umask 077; printf 'operator:%s\n' "$(head -c 12 /dev/urandom | base64 | tr '+/' '-_')" \
      > /etc/tripod/credentials/panel-credentials)
  fi
  echo "panel password: cut -d: -f2- /etc/tripod/credentials/panel-credentials"
fi

# 4. units, udev rule, sysctl
for unit in tripod-daemon tripod-panel; do
  sed "s#/opt/tripod/venv#$PREFIX/venv#g" "$REPO/deploy/systemd/$unit.service" \
    > /tmp/$unit.service.$$
  run install -m 0644 /tmp/$unit.service.$$ /etc/systemd/system/$unit.service
  rm -f /tmp/$unit.service.$$
done
run install -m 0644 "$REPO/deploy/udev/99-tripod-imu.rules" /etc/udev/rules.d/99-tripod-imu.rules
run install -m 0644 "$REPO/deploy/sysctl/90-tripod-daemon.conf" /etc/sysctl.d/90-tripod-daemon.conf
run sysctl --load /etc/sysctl.d/90-tripod-daemon.conf
run udevadm control --reload
run udevadm trigger --subsystem-match=tty

# 5. systemd
run systemctl daemon-reload
run systemd-analyze verify /etc/systemd/system/tripod-daemon.service \
  /etc/systemd/system/tripod-panel.service
if [ "$START" -eq 1 ]; then
  run systemctl enable --now tripod-daemon.service tripod-panel.service
  run systemctl --no-pager status tripod-daemon.service tripod-panel.service || true
else
  run systemctl enable tripod-daemon.service tripod-panel.service
fi
echo "tripod-daemon installed: journalctl -u tripod-daemon -f; recordings in /var/lib/tripod/recordings"
echo "operator's panel: https://$(hostname).local:8443/ (password: cut -d: -f2- /etc/tripod/credentials/panel-credentials)"
