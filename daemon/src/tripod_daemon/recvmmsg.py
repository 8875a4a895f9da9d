# SPDX-License-Identifier: BSD-3-Clause
"""Many datagrams per system call (Linux ``recvmmsg``) straight into rows of a numpy array.

One ``recvmmsg`` reads up to ``capacity`` datagrams of a non-blocking socket, each into its own
row of ``rows`` at column ``data_offset`` (so a row can already be the record the datagram will
be stored as), with its sender address, its length and flags, and its control messages: the
kernel's receive stamp (``SO_TIMESTAMPNS``) and drop count (``SO_RXQ_OVFL``). Everything after
the call is numpy on whole arrays, so the cost per datagram is a few hundred nanoseconds instead
of the microseconds of a Python ``recvmsg`` each.

Called through ctypes (no compiled extension to build on the device); :func:`available` says
whether libc has ``recvmmsg`` (Linux, glibc or musl). The layouts below are those of 64-bit
Linux (x86_64, aarch64), the only targets; :func:`available` refuses others.
"""

from __future__ import annotations

import ctypes
import errno
import os
import socket
import struct
import sys

import numpy as np

MSG_DONTWAIT = getattr(socket, "MSG_DONTWAIT", 0x40)
MSG_TRUNC = socket.MSG_TRUNC
SOL_SOCKET = socket.SOL_SOCKET
SCM_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)
SO_RXQ_OVFL = getattr(socket, "SO_RXQ_OVFL", 40)

# struct mmsghdr on 64-bit Linux: struct msghdr (56 bytes) + unsigned msg_len (+4 padding)
_MMSGHDR = np.dtype({
    "names": ["name", "namelen", "iov", "iovlen", "control", "controllen", "flags", "len"],
    "formats": ["<u8", "<u4", "<u8", "<u8", "<u8", "<u8", "<i4", "<u4"],
    "offsets": [0, 8, 16, 24, 32, 40, 48, 56],
    "itemsize": 64,
})
_IOVEC = np.dtype({"names": ["base", "len"], "formats": ["<u8", "<u8"], "offsets": [0, 8],
                   "itemsize": 16})
_NAME_SIZE = 16  # struct sockaddr_in
# control space per datagram: a timespec cmsg (16 + 16) and a u32 cmsg (16 + 4, padded to 24)
_CTRL_SIZE = 64
_TS_CMSG_SPACE = 32  # CMSG_SPACE(sizeof(struct timespec)): where the second cmsg starts

_libc = None


def _recvmmsg():
    global _libc
    if _libc is None:
        lib = ctypes.CDLL(None, use_errno=True)
        fn = lib.recvmmsg
        fn.argtypes = [ctypes.c_int, ctypes.c_void_p, ctypes.c_uint, ctypes.c_int, ctypes.c_void_p]
        fn.restype = ctypes.c_int
        _libc = fn
    return _libc


def available() -> bool:
    """True on 64-bit Linux with a libc that has ``recvmmsg``."""
    if not sys.platform.startswith("linux") or struct.calcsize("P") != 8:
        return False
    if sys.byteorder != "little":
        return False
    try:
        _recvmmsg()
    except (OSError, AttributeError):
        return False
    return True


class BatchReceiver:
    """Receive up to ``capacity`` datagrams of ``sock`` per :meth:`receive` into
    ``rows[i, data_offset:data_offset + max_size]`` (the other columns are left as they were:
    uninitialised until the caller fills them).

    After ``n = receive()``, for i < n: ``lengths[i]`` (bytes received; a datagram longer than
    ``max_size`` has ``truncated[i]`` set), ``stamps_ns[i]`` (kernel receive time,
    host_realtime; 0 when the kernel gave none), ``addresses[i]`` (IPv4 sender as the 4 bytes
    of ``sin_addr`` read as a little-endian u32); ``kernel_drops`` is the socket's cumulative
    drop count from the last datagram that carried one (else -1).
    """

    def __init__(self, sock: socket.socket, capacity: int, row_size: int, data_offset: int,
                 max_size: int):
        if data_offset + max_size > row_size:
            raise ValueError("a datagram must fit its row")
        self.sock = sock
        self.fd = sock.fileno()
        self.capacity = capacity
        self._row_size, self._data_offset = row_size, data_offset
        self._names = np.zeros((capacity, _NAME_SIZE), dtype=np.uint8)
        self._ctrl = np.zeros((capacity, _CTRL_SIZE), dtype=np.uint8)
        self._iov = np.zeros(capacity, dtype=_IOVEC)
        self._hdr = np.zeros(capacity, dtype=_MMSGHDR)
        self._iov["len"] = max_size
        self._new_rows()
        self._hdr["name"] = self._names.ctypes.data + np.arange(capacity, dtype=np.uint64) \
            * _NAME_SIZE
        self._hdr["iov"] = self._iov.ctypes.data + np.arange(capacity, dtype=np.uint64) \
            * _IOVEC.itemsize
        self._hdr["iovlen"] = 1
        self._hdr["control"] = self._ctrl.ctypes.data + np.arange(capacity, dtype=np.uint64) \
            * _CTRL_SIZE
        self._hdr_ptr = self._hdr.ctypes.data
        self._fn = _recvmmsg()
        self.lengths = np.zeros(0, dtype=np.uint32)
        self.truncated = np.zeros(0, dtype=bool)
        self.stamps_ns = np.zeros(0, dtype=np.int64)
        self.addresses = np.zeros(0, dtype=np.uint32)
        self.kernel_drops = -1

    def _new_rows(self) -> None:
        self.rows = np.empty((self.capacity, self._row_size), dtype=np.uint8)
        self._iov["base"] = self.rows.ctypes.data + self._data_offset \
            + np.arange(self.capacity, dtype=np.uint64) * self._row_size

    def take(self, n: int) -> np.ndarray:
        """The first ``n`` rows, handed over without a copy: the next :meth:`receive` reads
        into a new array."""
        rows = self.rows[:n]
        self._new_rows()
        return rows

    def receive(self, limit: int | None = None) -> int:
        """Read what the socket holds, at most ``limit`` (default ``capacity``) datagrams;
        0 when it is empty. OSError for other errors than "nothing to read"."""
        k = self.capacity if limit is None else min(limit, self.capacity)
        hdr = self._hdr
        hdr["namelen"][:k] = _NAME_SIZE
        hdr["controllen"][:k] = _CTRL_SIZE
        hdr["flags"][:k] = 0
        n = self._fn(self.fd, self._hdr_ptr, k, MSG_DONTWAIT, None)
        if n < 0:
            e = ctypes.get_errno()
            if e in (errno.EAGAIN, errno.EWOULDBLOCK, errno.EINTR):
                n = 0
            else:
                raise OSError(e, os.strerror(e))
        h = hdr[:n]
        self.lengths = h["len"].copy()
        self.truncated = (h["flags"] & MSG_TRUNC) != 0
        ctrl = self._ctrl[:n]
        clen = h["controllen"]
        # cmsg 1: len u64 @0, level i32 @8, type i32 @12, struct timespec @16
        lvl = ctrl[:, 8:16].copy().view("<i4")
        has_ts = (clen >= _TS_CMSG_SPACE) & (lvl[:, 0] == SOL_SOCKET) \
            & (lvl[:, 1] == SCM_TIMESTAMPNS)
        ts = ctrl[:, 16:32].copy().view("<i8")
        self.stamps_ns = np.where(has_ts, ts[:, 0] * 1_000_000_000 + ts[:, 1], 0)
        # cmsg 2 (only once the socket has dropped): SO_RXQ_OVFL, u32 @ 32 + 16
        self.kernel_drops = -1
        if n and (clen > _TS_CMSG_SPACE).any():
            lvl2 = ctrl[:, 40:48].copy().view("<i4")
            has = (clen >= _TS_CMSG_SPACE + 20) & (lvl2[:, 0] == SOL_SOCKET) \
                & (lvl2[:, 1] == SO_RXQ_OVFL)
            if has.any():
                drops = ctrl[:, 48:52].copy().view("<u4")[:, 0]
                self.kernel_drops = int(drops[has].max())
        # struct sockaddr_in: family u16, port u16 (big-endian), addr 4 bytes
        self.addresses = self._names[:n, 4:8].copy().view("<u4")[:, 0]
        return n


def ipv4_key(address: str) -> int:
    """An IPv4 address as :attr:`BatchReceiver.addresses` holds it."""
    return int.from_bytes(socket.inet_aton(address), "little")
