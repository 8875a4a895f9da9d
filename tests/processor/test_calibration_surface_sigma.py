# SPDX-License-Identifier: BSD-3-Clause
"""The surfaces' own time offset weighed with a widened sigma in its joins with the turns'
(issue 12, stop 40, i12-offset7; ``calibration.surface_time_sigma_floor_ms`` and
``surface_time_consistency``, both off by default).

A surfaces' estimate sure to 0.3 ms but 5.5 ms from turns of σ 2 ms lies inside the 3-sigma
window (6.1 ms) and, by its own sigma, takes ~97 % of the weight: the join is the surfaces'.
Widened (a floor, or to the disagreement), the turns keep their share.
"""

from types import SimpleNamespace

import numpy as np

from tripod_processor.reconstruction.config import ReconstructConfig
from tripod_processor.reconstruction.pipeline import (_join_with_surfaces,
                                                      _rejoin_joint_with_widened_surfaces,
                                                      _surface_sigma_for_join,
                                                      _surfaces_own_offset)

TURN_NS, TURN_SIG = -2_000_000, 2.0  # the turns' offset (here the truth) and sigma
SURF_NS, SURF_SIG = 3_500_000, 0.3  # a sure but wrong surfaces' own estimate


def test_surface_sigma_for_join():
    assert _surface_sigma_for_join(5.5, 2.0, 0.3) == 0.3  # defaults: its own
    assert _surface_sigma_for_join(5.5, 2.0, 0.3, floor_ms=1.0) == 1.0
    assert _surface_sigma_for_join(0.5, 2.0, 0.3, floor_ms=1.0) == 1.0
    s = _surface_sigma_for_join(5.5, 2.0, 0.3, consistency=True)
    assert abs(s - np.sqrt(5.5**2 - 2.0**2)) < 1e-12
    assert _surface_sigma_for_join(1.5, 2.0, 0.3, consistency=True) == 0.3  # they agree


def test_the_turns_keep_their_share_after_the_remeasure():
    m0, s0, j0 = _join_with_surfaces(TURN_NS, TURN_SIG, (SURF_NS, SURF_SIG), 0.5)
    assert j0 and abs(m0 * 1e-6 - 3.38) < 0.01 and s0 < 0.3  # old: the surfaces' (5.4 ms off)
    m, s, j = _join_with_surfaces(TURN_NS, TURN_SIG, (SURF_NS, SURF_SIG), 0.5, 0.0, True)
    assert j and abs(m - TURN_NS) * 1e-6 < 0.8 and abs(s - TURN_SIG) < 0.3, (m, s)
    m, s, j = _join_with_surfaces(TURN_NS, TURN_SIG, (SURF_NS, SURF_SIG), 0.5, 2.0)
    assert j and abs(m * 1e-6 - 0.75) < 1e-6 and abs(s - np.sqrt(2.0)) < 1e-9
    # the gates still judge the surfaces' own sigma: unsure or far off, not joined at all
    assert not _join_with_surfaces(TURN_NS, TURN_SIG, (SURF_NS, 0.6), 0.5, 0.0, True)[2]
    assert not _join_with_surfaces(TURN_NS, TURN_SIG, (9_000_000, SURF_SIG), 0.5, 0.0, True)[2]


def test_the_joint_fit_rejoined_with_the_widened_sigma():
    # the joint fit's posterior: the turns' prior times the surfaces' own likelihood
    i_t, i_s = TURN_SIG**-2, SURF_SIG**-2
    post_ms = (TURN_NS * 1e-6 * i_t + SURF_NS * 1e-6 * i_s) / (i_t + i_s)
    turn = SimpleNamespace(offset_ns=TURN_NS, sigma_ms=TURN_SIG)

    def cal():
        return SimpleNamespace(time_offset_ns=int(round(post_ms * 1e6)),
                               time_offset_sigma_ms=(i_t + i_s) ** -0.5)

    m_own, s_own = _surfaces_own_offset(cal(), turn)
    assert abs(m_own - SURF_NS) < 50 and abs(s_own - SURF_SIG) < 1e-6
    cc = ReconstructConfig().calibration
    assert cc.surface_time_sigma_floor_ms == 0 and not cc.surface_time_consistency
    c = cal()
    _rejoin_joint_with_widened_surfaces(c, turn, cc)  # defaults: as the joint fit left it
    assert c.time_offset_ns == cal().time_offset_ns
    cc.surface_time_consistency = True
    c = cal()
    _rejoin_joint_with_widened_surfaces(c, turn, cc)
    ref, s_ref, _ = _join_with_surfaces(TURN_NS, TURN_SIG, (m_own, s_own), 0.5, 0.0, True)
    assert abs(c.time_offset_ns - ref) < 100 and abs(c.time_offset_sigma_ms - s_ref) < 1e-6
    assert abs(c.time_offset_ns - TURN_NS) * 1e-6 < 0.8
