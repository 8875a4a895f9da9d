"""The extension as the code of commit c8984a8 saw it: today's _ext for everything but the
predictive encoder, which is that commit's C++ (predictive-sph1) through ctypes."""
import ctypes
from pathlib import Path

import numpy as np
from tripod_processor._ext import *  # noqa: F401,F403
from tripod_processor._ext import OCTREE_MAX_DEPTH  # noqa: F401

_lib = ctypes.CDLL(str(Path(__file__).resolve().parents[1] / "sph1.so"))
_lib.sph1_encode.restype = ctypes.c_long
_P = ctypes.c_void_p
_lib.sph1_encode.argtypes = [_P, ctypes.c_long, _P, ctypes.c_double, ctypes.c_long,
                             ctypes.c_double, _P, ctypes.c_long, ctypes.c_int, _P, ctypes.c_long,
                             _P, _P, _P]
_lib.sph1_decode.restype = ctypes.c_int
_lib.sph1_decode.argtypes = [_P, ctypes.c_long, ctypes.c_long, _P, ctypes.c_double,
                             ctypes.c_long, ctypes.c_double, _P, ctypes.c_long, ctypes.c_int,
                             ctypes.c_uint, _P]


def predictive_encode(points, origin, range_step, az_count, el_step, el_table, row_shift,
                      num_threads=0):
    p = np.ascontiguousarray(points, np.float32)
    o = np.ascontiguousarray(origin, np.float64)
    t = np.ascontiguousarray(el_table, np.float64)
    out = np.empty(16 * len(p) + 1024, np.uint8)
    err, cs, bits = ctypes.c_double(), ctypes.c_uint(), (ctypes.c_double * 3)()
    dp = lambda a, ty: a.ctypes.data  # noqa: E731
    n = _lib.sph1_encode(dp(p, ctypes.c_float), len(p), dp(o, ctypes.c_double),
                         ctypes.c_double(range_step), int(az_count), ctypes.c_double(el_step),
                         dp(t, ctypes.c_double), len(t), int(row_shift),
                         dp(out, ctypes.c_ubyte), len(out), ctypes.byref(err), ctypes.byref(cs),
                         bits)
    assert n >= 0
    return out[:n].tobytes(), err.value, cs.value, tuple(bits)


def predictive_decode(stream, n_points, origin, range_step, az_count, el_step, el_table,
                      row_shift, checksum, num_threads=0):
    data = np.frombuffer(stream, np.uint8)
    o = np.ascontiguousarray(origin, np.float64)
    t = np.ascontiguousarray(el_table, np.float64)
    out = np.empty((int(n_points), 3), np.float32)
    dp = lambda a, ty: a.ctypes.data  # noqa: E731
    rc = _lib.sph1_decode(dp(data, ctypes.c_ubyte), len(data), int(n_points),
                          dp(o, ctypes.c_double), ctypes.c_double(range_step), int(az_count),
                          ctypes.c_double(el_step), dp(t, ctypes.c_double), len(t),
                          int(row_shift), ctypes.c_uint(checksum), dp(out, ctypes.c_float))
    if rc:
        raise RuntimeError("corrupt sph1 stream")
    return out
