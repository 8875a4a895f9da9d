# SPDX-License-Identifier: BSD-3-Clause
"""Test helpers for the daemon: a pcap payload reader, UDP/pty senders, a running daemon."""

from __future__ import annotations

import contextlib
import os
import pty
import socket
import struct
import subprocess
import threading
import time
import tty
from pathlib import Path

from tripod_daemon.config import DaemonConfig
from tripod_daemon.loop import Daemon
from tripod_daemon.systemd import Notifier

# ---- pcap (classic libpcap, Ethernet/IPv4/UDP), just enough to replay the shared captures ------


def read_pcap_udp(path: str | os.PathLike) -> list[tuple[int, bytes]]:
    """(destination port, UDP payload) of every IPv4/UDP packet of a classic pcap, in order."""
    data = Path(path).read_bytes()
    magic = data[:4]
    if magic in (b"\xd4\xc3\xb2\xa1", b"\x4d\x3c\xb2\xa1"):
        end = "<"
    elif magic in (b"\xa1\xb2\xc3\xd4", b"\xa1\xb2\x3c\x4d"):
        end = ">"
    else:
        raise ValueError(f"{path}: not a classic pcap")
    linktype = struct.unpack_from(end + "I", data, 20)[0]
    out = []
    off = 24
    rec = struct.Struct(end + "IIII")
    while off + 16 <= len(data):
        _s, _u, incl, _orig = rec.unpack_from(data, off)
        frame = data[off + 16 : off + 16 + incl]
        off += 16 + incl
        if linktype == 1:  # Ethernet, maybe VLAN-tagged
            etype = struct.unpack_from(">H", frame, 12)[0]
            p = 14
            while etype == 0x8100:
                etype = struct.unpack_from(">H", frame, p + 2)[0]
                p += 4
            if etype != 0x0800:
                continue
        elif linktype == 113:  # Linux cooked
            p = 16
        elif linktype in (101, 228):  # raw IPv4
            p = 0
        else:
            raise ValueError(f"{path}: link type {linktype} not handled")
        ip = frame[p:]
        if len(ip) < 20 or ip[0] >> 4 != 4 or ip[9] != 17:
            continue
        ihl = (ip[0] & 0x0F) * 4
        total = struct.unpack_from(">H", ip, 2)[0]
        udp = ip[ihl:total]
        dport = struct.unpack_from(">H", udp, 2)[0]
        ulen = struct.unpack_from(">H", udp, 4)[0]
        out.append((dport, bytes(udp[8:ulen])))
    return out


def make_data_packet(seq: int, mode: int = 0x39, product: int = 0x22) -> bytes:
    """A well-formed 1206-byte data packet whose block bodies carry ``seq`` (unique bytes)."""
    body = struct.pack("<I", seq) * 24 + bytes(2)  # 98 bytes
    blocks = b"".join(b"\xff\xee" + body for _ in range(12))
    return blocks + struct.pack("<I", (seq * 664) % 3_600_000_000) + bytes([mode, product])


# ---- senders -------------------------------------------------------------------------------


def udp_sender() -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4 << 20)
    return s


def send_paced(sock: socket.socket, addr, payloads, rate_hz: float, burst: int = 32) -> float:
    """Send payloads at about ``rate_hz`` in small bursts; returns the achieved rate."""
    t0 = time.perf_counter()
    sendto = sock.sendto
    n = 0
    for p in payloads:
        sendto(p, addr)
        n += 1
        if n % burst == 0:
            ahead = n / rate_hz - (time.perf_counter() - t0)
            if ahead > 0:
                time.sleep(ahead)
    dt = time.perf_counter() - t0
    return n / dt if dt > 0 else float("inf")


class FakePty:
    """A pseudo-terminal standing in for the IMU's serial line; ``path`` is the symlink the
    daemon opens (as udev's /dev/tripod-imu), so unplug/replug can swap the pty under it."""

    def __init__(self, link: Path):
        self.link = Path(link)
        self.master = -1
        self.plug()

    def plug(self) -> None:
        master, slave = pty.openpty()
        tty.setraw(slave)  # no echo, no line discipline: bytes through as they are
        self.slave_name = os.ttyname(slave)
        os.close(slave)
        self.master = master
        tmp = self.link.with_suffix(".new")
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        os.symlink(self.slave_name, tmp)
        os.replace(tmp, self.link)

    def unplug(self) -> None:
        if self.master >= 0:
            os.close(self.master)
            self.master = -1
        with contextlib.suppress(FileNotFoundError):
            self.link.unlink()

    def write(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            n = os.write(self.master, view[:4096])
            view = view[n:]

    def read_available(self, timeout: float = 0.5) -> bytes:
        import select

        out = b""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            r, _, _ = select.select([self.master], [], [], 0.05)
            if r:
                try:
                    out += os.read(self.master, 4096)
                except OSError:
                    break
        return out

    def close(self) -> None:
        self.unplug()


def free_tcp_port() -> int:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def mutual_tls_setup(tmp_path: Path):
    """Certificates made by ``gen_certs`` (device for localhost/127.0.0.1, clients ``operator``
    and ``viewer``) and a loopback daemon config listening on TLS that takes control only from
    the ``operator`` certificate. Returns (config, endpoint, certs folder, CA path)."""
    from tripod_daemon.certs import gen_certs

    certs = tmp_path / "certs"
    gen_certs(str(certs), ["localhost", "127.0.0.1"], ["operator", "viewer"])
    ep = f"tls/127.0.0.1:{free_tcp_port()}"
    ca = str(certs / "ca.pem")
    cfg = loopback_config(tmp_path, zenoh={
        "enabled": True, "listen": [ep],
        "tls": {"certificate": str(certs / "device.pem"),
                "private_key": str(certs / "device.key"), "client_ca": ca},
        "control": {"allow_loopback": False, "cert_common_names": ["operator"]}})
    return cfg, ep, certs, ca


def loopback_config(tmp_path: Path, **sections) -> DaemonConfig:
    """A config for loopback tests: ephemeral ports, files under tmp_path, zenoh off unless
    asked (then listening on a free loopback port)."""
    base = {
        "lidar": {"bind_address": "127.0.0.1", "data_port": 0, "position_port": 0,
                  "receive_buffer_bytes": 32 << 20},
        "recording": {"directory": str(tmp_path / "rec"), "min_free_bytes": 0,
                      "flush_interval_s": 0.2},
        "zenoh": {"enabled": False},
        "status": {"interval_s": 0.2},
    }
    for k, v in sections.items():
        if isinstance(v, dict):
            base.setdefault(k, {}).update(v)
        else:
            base[k] = v
    return DaemonConfig.model_validate(base)




class RunningDaemon:
    """Run ``Daemon.run`` in a thread; ``stop()`` delivers SIGTERM through the self-pipe."""

    def __init__(self, cfg: DaemonConfig, **kw):
        kw.setdefault("notifier", Notifier({}))
        self.daemon = Daemon(cfg, install_signal_handlers=False, **kw)
        self.rc: int | None = None
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        self.rc = self.daemon.run()

    def __enter__(self) -> "RunningDaemon":
        self.thread.start()
        if not self.daemon.ready.wait(20):
            raise RuntimeError("daemon did not become ready")
        return self

    def stop(self, timeout: float = 30) -> int | None:
        import signal

        if self.thread.is_alive():
            self.daemon.signal(signal.SIGTERM)
            self.thread.join(timeout)
        return self.rc

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def data_addr(self):
        return ("127.0.0.1", self.daemon.lidar.data_port)

    @property
    def position_addr(self):
        return ("127.0.0.1", self.daemon.lidar.position_port)

    def wait_for(self, cond, timeout: float = 20.0, step: float = 0.05) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if cond():
                return True
            time.sleep(step)
        return cond()


def send_paced_in_process(addr, first_seq: int, n: int, rate_hz: float, burst: int = 32) -> float:
    """``send_paced`` of ``make_data_packet(first_seq ..)`` from a separate process, so that the
    sender does not share the interpreter lock with a daemon running in this process (as on
    the device, where the lidar is another machine); returns the achieved rate."""
    import subprocess
    import sys

    code = ("import sys; sys.path.insert(0, sys.argv[1]); import daemon_helpers as h; "
            "a = (sys.argv[2], int(sys.argv[3])); f, n = int(sys.argv[4]), int(sys.argv[5]); "
            "print(h.send_paced(h.udp_sender(), a, (h.make_data_packet(f + i) for i in range(n)), "
            "float(sys.argv[6]), int(sys.argv[7])))")
    out = subprocess.run(
        [sys.executable, "-c", code, str(Path(__file__).parent), addr[0], str(addr[1]),
         str(first_seq), str(n), str(rate_hz), str(burst)],
        capture_output=True, text=True, check=True, timeout=600)
    return float(out.stdout.split()[-1])


@contextlib.contextmanager
def small_tmpfs(path: Path, size_kb: int):
    """A real tmpfs of ``size_kb`` KiB at ``path`` when mounting is allowed (root): yields True;
    else yields False and the caller emulates a full disk. Unmounted on exit."""
    path.mkdir(parents=True, exist_ok=True)
    ok = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size_kb}k", "tmpfs", str(path)],
                        capture_output=True).returncode == 0
    try:
        yield ok
    finally:
        if ok:
            subprocess.run(["umount", "-l", str(path)], capture_output=True)
