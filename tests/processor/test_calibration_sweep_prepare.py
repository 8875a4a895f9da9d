"""A sweep prepared once for all its pairs (calibration._prepare_sweep) registers as the array."""

import numpy as np
from scipy.spatial.transform import Rotation

from tripod_processor.reconstruction import calibration as cal


def _room(rng, n=20000):
    """Points on the walls, floor and ceiling of a 6 x 4 x 3 m box around the origin."""
    u = rng.uniform(-1, 1, (n, 3)) * [3.0, 2.0, 1.5]
    face = rng.integers(0, 6, n)
    ax, sign = face // 2, np.where(face % 2, 1.0, -1.0)
    u[np.arange(n), ax] = sign * np.array([3.0, 2.0, 1.5])[ax]
    return u + rng.normal(0, 0.005, (n, 3))


def test_a_prepared_sweep_registers_to_the_bit_as_its_array():
    rng = np.random.default_rng(5)
    tgt = _room(rng)
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", 20, degrees=True).as_matrix()
    T[:3, 3] = [0.1, -0.05, 0.0]
    src = _room(rng) @ T[:3, :3] + 0.0  # the same room seen turned
    init = np.eye(4)
    init[:3, :3] = T[:3, :3].T
    a = cal._register_sweeps(src, tgt, init, 2)
    ps, pt = cal._prepare_sweep(src, 2), cal._prepare_sweep(tgt, 2)
    b = cal._register_sweeps(ps, pt, init, 2)
    c = cal._register_sweeps(ps, pt, init, 2)  # a prepared cloud serves several pairs
    assert a is not None and b is not None
    assert a.T_target_source.tobytes() == b.T_target_source.tobytes() == c.T_target_source.tobytes()
    assert a.fitness == b.fitness and np.array_equal(a.information, b.information)
    # a sweep too small to prepare gives no registration, as its array does
    tiny = tgt[:2]
    assert cal._prepare_sweep(tiny, 2) is None or cal._register_sweeps(
        cal._prepare_sweep(tiny, 2), pt, init, 2) is None
    assert cal._register_sweeps(None, pt, init, 2) is None
    assert cal._register_sweeps(tiny, tgt, init, 2) is None
