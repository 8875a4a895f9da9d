# SPDX-License-Identifier: BSD-3-Clause
"""``tripod-daemon gen-certs DIR``: a small CA, this device's TLS certificate and client
certificates, made with the ``openssl`` command (the same commands are in deploy/README.md).

::

    DIR/ca.pem  ca.key                 the CA (keep ca.key off the device)
    DIR/device.pem  device.key         zenoh.tls.certificate / private_key (SAN: names given)
    DIR/<client>.pem  <client>.key     one per --client NAME (CN=NAME: zenoh.control
                                       .cert_common_names lists who may control)

EC P-256 keys; certificates carry subjectAltName, key usages and both TLS purposes (rustls,
which zenoh uses, refuses certificates without them). Existing files are never overwritten.
"""

from __future__ import annotations

import argparse
import ipaddress
import os
import shutil
import socket
import subprocess
import sys

_KEY = ["-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes"]


def _openssl(*args: str, cwd: str) -> None:
    r = subprocess.run(["openssl", *args], cwd=cwd, capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"openssl {args[0]} failed: {r.stderr.strip().splitlines()[-1:]}")


def _issue(out: str, name: str, cn: str, sans: list[str], days: int) -> None:
    ext = os.path.join(out, f".{name}.ext")
    with open(ext, "w") as fh:
        fh.write("basicConstraints=critical,CA:FALSE\n"
                 "keyUsage=critical,digitalSignature,keyEncipherment\n"
                 "extendedKeyUsage=serverAuth,clientAuth\n"
                 f"subjectAltName={','.join(sans)}\n")
    try:
        _openssl("req", *_KEY, "-subj", f"/CN={cn}", "-keyout", f"{name}.key",
                 "-out", f".{name}.csr", cwd=out)
        _openssl("x509", "-req", "-in", f".{name}.csr", "-CA", "ca.pem", "-CAkey", "ca.key",
                 "-CAcreateserial", "-days", str(days), "-sha256", "-extfile", ext,
                 "-out", f"{name}.pem", cwd=out)
    finally:
        for f in (ext, os.path.join(out, f".{name}.csr")):
            if os.path.exists(f):
                os.remove(f)
    os.chmod(os.path.join(out, f"{name}.key"), 0o600)


def gen_certs(out: str, device_names: list[str], clients: list[str], days: int = 825) -> list[str]:
    """Make the files in ``out`` (created); returns the paths written. FileExistsError when a
    file is already there."""
    if shutil.which("openssl") is None:
        raise RuntimeError("the openssl command is needed (apt install openssl)")
    out = os.path.abspath(out)  # openssl runs in ``out``: relative paths would point elsewhere
    os.makedirs(out, exist_ok=True)
    names = ["ca", "device", *clients]
    for n in names:
        for ext in ("pem", "key"):
            if os.path.exists(os.path.join(out, f"{n}.{ext}")):
                raise FileExistsError(f"{os.path.join(out, n)}.{ext} exists; not overwriting")
    _openssl("req", "-x509", *_KEY, "-days", str(days * 2), "-sha256", "-subj", "/CN=tripod CA",
             "-addext", "basicConstraints=critical,CA:TRUE",
             "-addext", "keyUsage=critical,keyCertSign,cRLSign",
             "-keyout", "ca.key", "-out", "ca.pem", cwd=out)
    os.chmod(os.path.join(out, "ca.key"), 0o600)
    sans = []
    for n in device_names:
        try:
            ipaddress.ip_address(n)
            sans.append(f"IP:{n}")
        except ValueError:
            sans.append(f"DNS:{n}")
    _issue(out, "device", device_names[0], sans, days)
    for c in clients:
        _issue(out, c, c, [f"DNS:{c}"], days)
    srl = os.path.join(out, "ca.srl")
    if os.path.exists(srl):
        os.remove(srl)
    return [os.path.join(out, f"{n}.{e}") for n in names for e in ("pem", "key")]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="tripod-daemon gen-certs",
        description="Make a CA, this device's TLS certificate and client certificates for "
        "Zenoh mutual TLS (README: security).")
    p.add_argument("directory", help="where to write (created; existing files are kept)")
    p.add_argument("--name", action="append", default=None, metavar="NAME",
                   help="device host name or IP for the certificate (repeatable; default: "
                   "this host's name, localhost, 127.0.0.1)")
    p.add_argument("--client", action="append", default=None, metavar="CN",
                   help="a client certificate with this common name (repeatable; default: "
                   "operator)")
    p.add_argument("--days", type=int, default=825, help="validity of the certificates [days]")
    a = p.parse_args(argv)
    names = a.name or [socket.gethostname(), "localhost", "127.0.0.1"]
    clients = a.client or ["operator"]
    try:
        written = gen_certs(a.directory, names, clients, a.days)
    except (FileExistsError, RuntimeError, OSError) as exc:
        print(f"tripod-daemon gen-certs: {exc}", file=sys.stderr)
        return 2 if isinstance(exc, FileExistsError) else 1
    for w in written:
        print(w)
    return 0
