# SPDX-License-Identifier: BSD-3-Clause
"""Small operating-system helpers."""

from __future__ import annotations

import ctypes
import sys

_PR_SET_NAME = 15


def set_thread_name(name: str) -> None:
    """Name the calling thread for the OS (``top -H``, ``/proc/PID/task/TID/comm``; 15 bytes
    at most), so each thread's CPU can be told apart. Does nothing where unsupported."""
    if not sys.platform.startswith("linux"):
        return
    try:
        ctypes.CDLL(None).prctl(_PR_SET_NAME, ctypes.c_char_p(name.encode()[:15]), 0, 0, 0)
    except (OSError, AttributeError):
        pass
