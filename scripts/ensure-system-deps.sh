#!/usr/bin/env bash
# SPDX-License-Identifier: BSD-3-Clause
# Install the Debian packages tripod needs, only those missing (idempotent, fast when all there).
set -euo pipefail

PKGS=(
  build-essential cmake ninja-build pkg-config
  libeigen3-dev libpcl-dev libceres-dev   # processor's C++ core
  libgtest-dev                            # its C++ unit tests
  libsystemd-dev                          # systemd-python (daemon)
  libusb-1.0-0 libgomp1                   # Open3D's runtime needs
  systemd                                 # systemd-analyze verify of the unit
  chromium chromium-driver                # the panel's browser test (headless, Selenium)
)
# A Debian python3 needs its venv/dev packages; a pyenv/other Python brings its own.
PY=${PYTHON:-python3}
if ! "$PY" -c "import venv, ensurepip" >/dev/null 2>&1; then PKGS+=(python3-venv python3-dev); fi

missing=()
for p in "${PKGS[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
[ ${#missing[@]} -eq 0 ] && exit 0

echo "tripod: installing missing Debian packages: ${missing[*]}" >&2
SUDO=""
[ "$(id -u)" -ne 0 ] && SUDO="sudo"
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
