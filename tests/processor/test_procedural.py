# SPDX-License-Identifier: BSD-3-Clause
"""Procedural buildings (sim.procedural): families, openings with recesses, the one label
convention, determinism, seed splits; the shipped segmenter on generated test buildings."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from tripod_processor.sim.procedural import (CONVENTION, FAMILIES, PART_CLASS, PART_NAMES,
                                             SEED_SPLITS, free_stations, make_building,
                                             scan_building, split_seeds)
from tripod_processor.sim.scenes import CEILING, FLOOR, OTHER, WALL


@functools.lru_cache(maxsize=None)
def _scan(family: str, seed: int):
    b = make_building(family, seed)
    p, lab, parts = scan_building(b, np.random.default_rng(seed), n_stations=2, head_steps=8,
                                  noise_m=0.01, return_parts=True)
    return b, p, lab, parts


def _part(name: str) -> int:
    return PART_NAMES.index(name)


@pytest.mark.parametrize("family", FAMILIES)
def test_every_family_is_deterministic_and_labelled_by_the_convention(family):
    a, b = make_building(family, 7), make_building(family, 7)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.parts, b.parts)
    c = make_building(family, 8)
    assert a.vertices.shape != c.vertices.shape or not np.array_equal(a.vertices, c.vertices)
    # the class of every triangle is its part's class in the one written convention
    np.testing.assert_array_equal(a.classes, PART_CLASS[a.parts])
    assert a.triangles.max() < len(a.vertices) and a.family == family
    present = {PART_NAMES[k] for k in np.unique(a.parts)}
    assert {"floor", "ceiling", "wall", "furniture"} <= present, present
    # windows: recesses with reveals and the window at their back
    assert a.counts.get("windows", 0) >= 1 and {"reveal", "window"} <= present


def test_convention_classes():
    want = {"floor": FLOOR, "ceiling": CEILING, "wall": WALL, "reveal": WALL, "sill": WALL,
            "lintel": WALL, "window": WALL, "door_closed": WALL, "door_open": OTHER,
            "column": OTHER, "beam": OTHER, "low_partition": OTHER, "stairs": OTHER,
            "furniture": OTHER, "radiator": OTHER, "wall_item": OTHER, "clutter": OTHER}
    assert {p: c for p, (c, _) in CONVENTION.items()} == want


def test_recesses_have_depth_and_openings_reach_through_interior_walls():
    depths, kinds = [], set()
    for family in ("apartment", "rooms", "corridor"):
        for seed in range(3):
            b = make_building(family, seed)
            tri = b.vertices[b.triangles]
            for part in ("reveal", "sill"):
                sel = tri[b.parts == _part(part)]
                if len(sel):
                    # a reveal spans the recess: from the inside face to the window (or through)
                    ext = (sel[..., :2].max(1) - sel[..., :2].min(1)).max(1)
                    depths += ext.tolist()
            kinds |= {k for k in b.counts if k.startswith("doors_") or k == "wide_openings"}
    assert min(depths) > 0.02 and np.median(depths) > 0.1, (min(depths), np.median(depths))
    assert {"doors_open", "doors_closed"} <= kinds, kinds


def test_structure_and_contents_appear_across_families():
    seen: dict[str, int] = {}
    for family in FAMILIES:
        for seed in range(3):
            for k, v in make_building(family, seed).counts.items():
                seen[k] = seen.get(k, 0) + v
    for k in ("windows", "doors_open", "doors_closed", "columns", "beams", "low_partitions",
              "stairs", "radiators", "pilasters"):
        assert seen.get(k, 0) > 0, (k, seen)


@pytest.mark.parametrize("family", ["apartment", "hall", "corridor"])
def test_scans_are_labelled_per_point_by_the_convention(family):
    b, p, lab, parts = _scan(family, 3)
    assert p.dtype == np.float32 and p.shape == (len(lab), 3) and len(p) > 100_000
    np.testing.assert_array_equal(lab, PART_CLASS[parts])
    assert set(np.unique(lab)) == {0, 1, 2, 3}
    # every point lies inside the building, between floor and ceiling
    assert p[:, 2].min() > -0.2 and p[:, 2].max() < b.height + 0.2
    floor = lab == FLOOR
    assert np.abs(p[floor, 2]).max() < 0.1  # 1 cm range noise, 4 sigma is far below
    # the scan sees into the recesses: reveal or window points are there
    assert np.isin(parts, [_part("reveal"), _part("window"), _part("sill")]).sum() > 100


def test_stations_stand_free_on_the_floor():
    b = make_building("open_plan", 4)
    st = free_stations(b, 3, np.random.default_rng(0))
    assert len(st) == 3
    for s in st:
        assert 1.2 <= s[2] <= 1.7
        assert any(a[0] <= s[0] <= a[2] and a[1] <= s[1] <= a[3] for al in b.free for a in al)


def test_seed_splits_are_disjoint():
    names = ("train", "dev", "test", "test2", "test3")
    sets = [set(split_seeds(s, 10_000)) for s in names]
    for i in range(len(sets)):
        for j in range(i):
            assert not (sets[i] & sets[j]), (names[i], names[j])
    assert [SEED_SPLITS[s] for s in names] == sorted(SEED_SPLITS[s] for s in names)
    with pytest.raises(ValueError, match="unknown split"):
        split_seeds("nope", 1)
    with pytest.raises(ValueError, match="unknown family"):
        make_building("castle", 0)


def test_shipped_weights_on_generated_test_buildings():
    """The shipped segmenter on buildings of test seeds (never used in training or development)
    of every family; IoU from the confusion summed over them."""
    from tripod_processor.scene.segmentation import Segmenter
    from tripod_processor.scene.segmentation.metrics import confusion, iou

    seg = Segmenter()
    total = np.zeros((4, 4), np.int64)
    for k, family in enumerate(FAMILIES):
        b = make_building(family, split_seeds("test", 200)[-1 - k])
        p, lab = scan_building(b, np.random.default_rng(k), n_stations=2, head_steps=8,
                               noise_m=0.02)
        total += confusion(lab, seg(p))
    ious = iou(total)
    # measured 0.992 / 0.991 / 0.926 / 0.854 (fifth round: two stages, auto-context; the fourth
    # round's one stage 0.991 / 0.991 / 0.913 / 0.828; the third's 0.991 / 0.990 / 0.898 /
    # 0.798; before issue 18's 41 features 0.990 / 0.991 / 0.884 / 0.767; 8 head positions per
    # station: sparser than the benchmark's scans; the goals .98 / .98 / .95 / .85 are
    # not all met, see README)
    assert ious[0] > 0.975 and ious[1] > 0.975, ious
    assert ious[2] > 0.90, ious
    assert ious[3] > 0.80, ious


def test_procedural_training_smoke_and_leave_one_family_out_rows():
    from tripod_processor.scene.segmentation.train import procedural_features, train_on_families

    feats = procedural_features(["rooms", "hall"], per_family=1, copies=1, keep_per_copy=20_000)
    from tripod_processor.scene.segmentation.features import FEATURE_NAMES

    assert all(len(f[0]) == 20_000 and f[0].shape[1] == len(FEATURE_NAMES) for f in feats.values())
    again = procedural_features(["hall"], per_family=1, copies=1, keep_per_copy=20_000)
    np.testing.assert_array_equal(again["hall"][0], feats["hall"][0])  # a family's rows are its own
    m1, r1 = train_on_families(feats, ["rooms"], steps=60, batch=1024, num_threads=1)
    m2, r2 = train_on_families(feats, ["rooms"], steps=60, batch=1024, num_threads=1)
    assert r1.points == 20_000 and r1.final_loss == r2.final_loss


def test_tall_buildings_reach_a_halls_height_and_older_generators_stay_reachable():
    """Generator 3 (opt-in): the tall buildings of rooms, open plans and L/U wings reach 10 m (a
    hall's range, 4.5-10 m; generator 2, the default, stops at 8 m), drawn from their own
    stream: the same layout as generator 2's draw, a taller ceiling; a building that is not tall
    is the same in both."""
    from tripod_processor.sim import procedural

    assert procedural.GENERATOR == 2 and procedural.TALL is procedural.TALL_BY_GENERATOR[2]
    for fam in ("rooms", "open_plan", "L", "U"):
        assert procedural.TALL_BY_GENERATOR[3][fam][2] == 10.0
        assert procedural.TALL_BY_GENERATOR[2][fam][2] == 8.0
    # the first train seed of `rooms` whose building is over 8 m high, and one that is not tall
    heights = {s: make_building("rooms", s, generator=3).height for s in range(30)}
    over = [s for s, h in heights.items() if h > 8.0]
    plain = [s for s, h in heights.items() if h < 3.6]
    assert over and plain, heights
    b3, b2 = make_building("rooms", over[0], generator=3), make_building("rooms", over[0])
    assert b3.height > 8.0 and 4.0 <= b2.height <= 8.0
    assert b3.rooms == b2.rooms and b3.room_types == b2.room_types  # same layout, taller
    assert b3.vertices[:, 2].max() == pytest.approx(b3.height)
    n3, n2 = make_building("rooms", plain[0], generator=3), make_building("rooms", plain[0])
    assert n3.height == n2.height
    np.testing.assert_array_equal(n3.vertices, n2.vertices)
    np.testing.assert_array_equal(n3.parts, n2.parts)
    # the module's version picks the table when none is given (bench/scene.py --generator)
    old = procedural.GENERATOR
    try:
        procedural.GENERATOR = 3
        assert make_building("rooms", over[0]).height == b3.height
    finally:
        procedural.GENERATOR = old


def _fingerprint(b) -> str:
    import hashlib

    h = hashlib.sha256(np.round(b.vertices, 4).astype(np.float64).tobytes())
    h.update(b.parts.tobytes())
    h.update(b.triangles.astype(np.int64).tobytes())
    return h.hexdigest()[:16]


def test_generator_4_gives_big_rooms_a_halls_parts_and_leaves_generator_2_alone():
    """Generator 4 (opt-in, issue 18): the big rooms of the other families (open areas, rooms of
    40 m^2 and 5 m on) get pilasters and stairs / ledges about as often as a hall; the layout,
    heights, the hall, apartments and corridors stay as in generator 2, whose buildings are
    pinned (fingerprints of generator 2 as shipped, before generator 4 existed)."""
    from tripod_processor.sim import procedural

    assert procedural.GENERATOR == 2
    pinned = {("open_plan", 0): "ddfc297e1c847a0c", ("U", 2): "d208ea8c6950174b",
              ("hall", 0): "1fb1a7aa2dffdf21", ("apartment", 0): "54ebbcc762609cfc"}
    for (fam, seed), want in pinned.items():
        assert _fingerprint(make_building(fam, seed)) == want, (fam, seed)
        assert _fingerprint(make_building(fam, seed, generator=2)) == want, (fam, seed)
    # deterministic, and only the parts differ from generator 2's draw
    a, b = make_building("U", 2, generator=4), make_building("U", 2, generator=4)
    assert _fingerprint(a) == _fingerprint(b) != pinned[("U", 2)]
    g2 = make_building("U", 2)
    assert a.rooms == g2.rooms and a.room_types == g2.room_types and a.height == g2.height
    assert a.counts["pilasters"] > g2.counts.get("pilasters", 0)
    assert a.counts["stairs"] > g2.counts.get("stairs", 0)
    for fam in ("hall", "apartment", "corridor"):  # no hall-like rooms there (or the hall itself)
        for seed in range(3):
            assert _fingerprint(make_building(fam, seed, generator=4)) == \
                _fingerprint(make_building(fam, seed)), (fam, seed)
    # over 20 train seeds, open plans and L/U buildings with pilasters / stairs: about doubled
    seeds = split_seeds("train", 20)
    for fam in ("open_plan", "L", "U"):
        n = {g: {k: sum(make_building(fam, s, generator=g).counts.get(k, 0) > 0 for s in seeds)
                 for k in ("pilasters", "stairs")} for g in (2, 4)}
        assert n[4]["pilasters"] >= n[2]["pilasters"] + 4, (fam, n)
        assert n[4]["stairs"] >= n[2]["stairs"] + 2, (fam, n)
    # the module's version is read at call time (bench/scene.py --generator 4)
    old = procedural.GENERATOR
    try:
        procedural.GENERATOR = 4
        assert _fingerprint(make_building("U", 2)) == _fingerprint(a)
    finally:
        procedural.GENERATOR = old
