# SPDX-License-Identifier: BSD-3-Clause
"""The merge's shortlist of recording pairs (``merge.shortlist_k``): which pairs survive, a pair
kept when either recording ranks it, ties, capture-time neighbours, and the pair score."""

import random

import numpy as np
import pytest
from pydantic import ValidationError

from tripod_processor.reconstruction.merge import MergeConfig, pair_score, shortlist_pairs

# five recordings: 0, 1, 2 share a lot, 3 touches 2 a little, 4 shares nothing
SCORES = {(0, 1): 0.9, (0, 2): 0.8, (1, 2): 0.85, (2, 3): 0.1}


def every(n):
    return {(a, b) for a in range(n) for b in range(a + 1, n)}


def test_k1_each_recording_keeps_its_best_partner_either_side():
    keep = shortlist_pairs(5, SCORES, 1)
    # 0 and 1 pick each other, 2 picks 1, 3 picks 2 (its weak best: kept although 2 ranks it
    # last), 4 (all 0) picks its nearest in capture order, 3; 0 x 2 (0.8) is nobody's best
    assert keep == {(0, 1), (1, 2), (2, 3), (3, 4)}
    assert all(a < b for a, b in keep)


def test_k2_and_ties_by_capture_order():
    keep = shortlist_pairs(5, SCORES, 2)
    # 3: 2, then a tie at 0 between 0, 1 and 4 -> 4 (nearest); 4: 3, then 2 (next nearest)
    assert keep == {(0, 1), (0, 2), (1, 2), (2, 3), (3, 4), (2, 4)}


def test_result_does_not_depend_on_the_order_of_the_scores():
    items = list(SCORES.items()) + [((0, 3), 0.0), ((1, 4), 0.0)]
    want = shortlist_pairs(5, SCORES, 2)
    rng = random.Random(3)
    for _ in range(5):
        rng.shuffle(items)
        assert shortlist_pairs(5, dict(items), 2) == want


def test_all_pairs_for_k0_and_small_buildings():
    assert shortlist_pairs(5, SCORES, 0) == every(5)
    # a building of <= k + 1 recordings: each recording has at most k partners, all kept
    assert shortlist_pairs(5, SCORES, 4) == every(5)
    assert shortlist_pairs(5, SCORES, 9) == every(5)
    assert shortlist_pairs(3, {}, 2) == every(3)
    assert shortlist_pairs(1, {}, 1) == set()
    assert MergeConfig().shortlist_k == 4
    with pytest.raises(ValidationError):
        MergeConfig(shortlist_k=-1)


def test_capture_time_neighbours_are_kept_and_break_ties():
    # capture order 4, 0, 3, 1, 2 (start times in ns, not in index order)
    start_ns = [20, 40, 50, 30, 10]
    keep = shortlist_pairs(5, SCORES, 1, start_ns)
    by_score = {(0, 1), (1, 2), (2, 3)}
    neighbours = {(0, 4), (0, 3), (1, 3), (1, 2)}
    # 4 scores 0 with everyone: its tie goes to its capture neighbour 0 (not to 3, its
    # neighbour by index, as without the times)
    assert keep == by_score | neighbours
    assert (3, 4) not in keep


def test_pair_score_is_the_share_of_the_smaller_map():
    H = np.eye(4)
    # B (1000 points) matched at 0.2 onto A (4000): 200 points, the share of B (the smaller)
    assert pair_score(("global", H, 0.2), 4000, 1000) == pytest.approx(0.2)
    # B (4000) matched at 0.2 onto A (1000): 800 points, 0.8 of A
    assert pair_score(("global", H, 0.2), 1000, 4000) == pytest.approx(0.8)
    assert pair_score(("global", H, 0.9), 1000, 4000) == 1.0
    assert pair_score(None, 1000, 1000) == 0.0
    assert pair_score(("global", H, 0.5), 0, 1000) == 0.0
