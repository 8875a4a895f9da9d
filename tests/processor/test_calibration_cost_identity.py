# SPDX-License-Identifier: BSD-3-Clause
"""The calibration's cheaper arithmetic is the old arithmetic to the bit: the IMU's slerp
normalised by the explicit sum of squares (``ImuOrientation.quat_at``) and the planar voxels'
residuals gathered once (``calibration._voxel_plane_residuals``)."""

import numpy as np
from scipy.spatial.transform import Rotation

from tripod_processor.reconstruction import calibration as cal
from tripod_processor.reconstruction.inputs import ImuTrack
from tripod_processor.reconstruction.placement import ImuOrientation


def _orientation(seed: int = 0) -> ImuOrientation:
    rng = np.random.default_rng(seed)
    n = 2000
    host = 1_700_000_000_000_000_000 + np.arange(n, dtype=np.int64) * 10_000_000
    rotvec = np.cumsum(rng.normal(scale=0.02, size=(n, 3)), axis=0)
    q = Rotation.from_rotvec(rotvec).as_quat()[:, [3, 0, 1, 2]]
    return ImuOrientation(ImuTrack(host, q), 0)


def test_quat_at_normalised_as_numpy_norm():
    o = _orientation()
    rng = np.random.default_rng(1)
    t = np.sort(rng.integers(o.t_ns[0] - 10**8, o.t_ns[-1] + 10**8, 200_000))
    got = o.quat_at(t)
    # the old normalisation: the same slerp, divided by np.linalg.norm
    ts = o.t_ns
    i = np.clip(np.searchsorted(ts, t, side="right") - 1, 0, len(ts) - 2)
    dt_k, theta_k, s_k, small_k = o._slerp_table()
    u = np.clip((t - ts[i]).astype(np.float64) / dt_k[i], 0.0, 1.0)
    theta, s, small = theta_k[i], s_k[i], small_k[i]
    w0 = np.where(small, 1.0 - u, np.sin((1.0 - u) * theta) / s)
    w1 = np.where(small, u, np.sin(u * theta) / s)
    q = w0[:, None] * o._q[i] + w1[:, None] * o._q[i + 1]
    ref = q / np.linalg.norm(q, axis=1, keepdims=True)
    assert np.array_equal(got, ref)
    # and on any 4-vectors, not only unit-ish ones
    a = np.random.default_rng(2).normal(size=(100_000, 4)) * 10.0 ** rng.integers(-3, 4, (1, 4))
    n2 = a[:, 0] * a[:, 0]
    for c in (1, 2, 3):
        n2 += a[:, c] * a[:, c]
    assert np.array_equal(np.sqrt(n2), np.linalg.norm(a, axis=1))


def _old_voxel_plane_residuals(p, J, t, voxel_m, sep_ns):
    k3 = np.floor(p / voxel_m).astype(np.int64) & 0x1FFFFF
    keys = (k3[:, 0] << 42) | (k3[:, 1] << 21) | k3[:, 2]
    _, inv, cnt = np.unique(keys, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    V = len(cnt)
    t_lo = np.full(V, np.iinfo(np.int64).max)
    t_hi = np.full(V, np.iinfo(np.int64).min)
    np.minimum.at(t_lo, inv, t)
    np.maximum.at(t_hi, inv, t)
    ok_v = (cnt >= 10) & (t_hi - t_lo > sep_ns)
    sel = ok_v[inv]
    vid = np.cumsum(ok_v) - 1
    iv = vid[inv[sel]]
    ps, Js = p[sel], J[sel]
    c, d, ev, nrm, Jbar = cal._voxel_planes(ps, Js, iv, int(ok_v.sum()))
    keep = (ev[:, 0] < 0.2 * ev[:, 1])[iv]
    nn = nrm[iv][keep]
    return np.einsum("qi,qi->q", nn, d[keep]), np.einsum("qi,qij->qj", nn,
                                                         Js[keep] - Jbar[iv][keep])


def test_voxel_plane_residuals_as_before():
    rng = np.random.default_rng(3)
    n = 60_000
    # points on a few planes with noise, fired over 10 s
    nrm = rng.normal(size=(6, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    k = rng.integers(0, 6, n)
    uv = rng.uniform(-3, 3, (n, 3))
    p = uv - (np.einsum("ni,ni->n", uv, nrm[k]) - 1.0)[:, None] * nrm[k]
    p += rng.normal(scale=0.005, size=p.shape)
    t = rng.integers(0, 10_000_000_000, n)
    J = rng.normal(size=(n, 3, 5))
    r, Jr = cal._voxel_plane_residuals(p, J, t, 0.5, 300_000_000)
    r0, Jr0 = _old_voxel_plane_residuals(p, J, t, 0.5, 300_000_000)
    assert len(r) > 1000
    assert np.array_equal(r, r0) and np.array_equal(Jr, Jr0)
    # the split form: the later points to the earlier points' planes, as many as before
    rs, Jrs = cal._voxel_plane_residuals(p, J, t, 0.5, 300_000_000, split=True)
    assert len(rs) > 500 and Jrs.shape == (len(rs), 5)
