# SPDX-License-Identifier: BSD-3-Clause
"""A procedural building as a capture scene: its route keeps clear of the mesh."""

from __future__ import annotations

import numpy as np
import pytest

from tripod_processor.sim.building_scene import building_scene
from tripod_processor.sim.procedural import make_building
from tripod_processor.sim.scenes import check_route, load_scene_file, write_mesh_ply


@pytest.mark.parametrize("family", ["hall", "apartment", "L", "open_plan"])
def test_route_through_free_floor(family, tmp_path):
    """The route stays >= 0.25 m from the mesh at the tripod's heights under a ceiling
    (``check_route``, what ``tripod simulate`` asks), is >= 2 m end to end and <= 15 m long, and
    the mesh written for ``scene_file`` reads back with its classes; the buildings' default
    route (a loop inset from the bounds) is blocked."""
    b = make_building(family, 7)
    scene = building_scene(b)
    check_route(scene, scene.route, False)
    steps = np.linalg.norm(np.diff(scene.route, axis=0), axis=1)
    assert np.linalg.norm(scene.route[-1] - scene.route[0]) >= 2.0
    assert steps.sum() <= 15.0 + 1.0
    write_mesh_ply(tmp_path / "b.ply", scene)
    back = load_scene_file(tmp_path / "b.ply")
    assert np.array_equal(back.classes, scene.classes)
    if family in ("apartment", "L"):  # interior walls across the bounds' inset loop
        with pytest.raises(ValueError):
            check_route(back, back.route, True)
