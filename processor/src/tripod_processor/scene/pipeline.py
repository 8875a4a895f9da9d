# SPDX-License-Identifier: BSD-3-Clause
"""The heightmaps pipeline: labels → planes → one heightmap per plane → low-poly room model.

``tripod heightmaps`` and ``bench/scene.py`` both run :func:`analyse_scene`; :func:`write_scene`
writes what the command leaves in its output folder.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..io.mesh_obj import write_obj
from ..preprocess import point_normals
from .config import SceneConfig
from .heightmaps import (CLASS_COLOURS, CLASS_NAMES, Heightmap, low_poly_mesh, plane_heightmap,
                         write_mesh_ply)
from .planes import Plane, extract_planes, plane_inlier_share

#: normals of the heightmap pipeline: voxel moments at this edge [m]
NORMAL_VOXEL_M = 0.05


@dataclass
class SceneResult:
    """Planes, their heightmaps and the low-poly room of one labelled cloud."""

    planes: list[Plane]
    heightmaps: list[Heightmap]
    mesh: tuple[np.ndarray, np.ndarray, np.ndarray]  # vertices (V,3), triangles (T,3), classes (T,)
    inlier_share: float  # floor/ceiling/wall points within 5 cm of a plane of their class
    seconds: dict[str, float] = field(default_factory=dict)  # per step [s]: wall, *_cpu: CPU


def segment_labels(points: np.ndarray, cfg: SceneConfig) -> np.ndarray:
    """(N,) int32 labels of ``points`` by the segmenter of ``cfg.segment``.

    Raises FileNotFoundError / ValueError for unusable weights."""
    from .segmentation import Segmenter

    return Segmenter(cfg.segment.weights, cfg.segment.num_threads,
                     plane_consistency=cfg.segment.plane_consistency)(points)


def analyse_scene(points: np.ndarray, labels: np.ndarray, cfg: SceneConfig | None = None,
                  progress: bool = False) -> SceneResult:
    """Planes per class, a heightmap per plane and the low-poly room of a labelled cloud.

    Parameters
    ----------
    points : (N, 3) float32 [m], z up
    labels : (N,) int (0 ceiling, 1 floor, 2 wall, 3 other)
    cfg : planes / heightmaps / threads settings (defaults when None)
    progress : a tqdm bar over the planes
    """
    cfg = cfg or SceneConfig()
    threads = cfg.segment.num_threads
    seconds = {}
    t0, c0 = time.perf_counter(), time.process_time()
    planes = extract_planes(points, labels, num_threads=threads, **cfg.planes.model_dump())
    seconds["planes"], seconds["planes_cpu"] = time.perf_counter() - t0, time.process_time() - c0
    t0 = time.perf_counter()
    normals = point_normals(points, NORMAL_VOXEL_M, threads)
    if progress:
        from tqdm import tqdm

        planes_iter = tqdm(planes, desc="heightmaps", unit="plane")
    else:
        planes_iter = planes
    hms = [plane_heightmap(points, pl, normals=normals, **cfg.heightmaps.model_dump())
           for pl in planes_iter]
    seconds["heightmaps"] = time.perf_counter() - t0
    mesh = low_poly_mesh(planes)
    share = plane_inlier_share(points, labels, planes, 0.05)
    return SceneResult(planes, hms, mesh, share, seconds)


def heightmap_name(k: int, plane: Plane) -> str:
    """File name of the ``k``-th plane's heightmap PNG."""
    return f"plane_{k:02d}_{CLASS_NAMES[plane.label]}.png"


def write_scene(output: Path, res: SceneResult, points: np.ndarray, labels: np.ndarray,
                source: str, labels_from: str, cfg: SceneConfig, frame: dict | None = None
                ) -> None:
    """The heightmap PNGs (+ JSON), ``room_lowpoly.ply`` and ``room_lowpoly.obj`` (+ ``.mtl``),
    ``planes.json``, ``overview.png`` and ``config.yaml`` of a result in ``output``.
    ``frame``: how the points were levelled (up, R_level_cloud), kept in planes.json."""
    from tripod_shared.config_io import dump_config

    from .plots import save_overview

    output = Path(output)
    output.mkdir(parents=True, exist_ok=True)
    for k, (pl, hm) in enumerate(zip(res.planes, res.heightmaps)):
        hm.save(output / heightmap_name(k, pl))
    write_mesh_ply(output / "room_lowpoly.ply", *res.mesh)
    write_obj(output / "room_lowpoly.obj", *res.mesh, list(CLASS_NAMES), CLASS_COLOURS)
    (output / "planes.json").write_text(json.dumps(
        {"source": source, "labels": labels_from, **({"frame": frame} if frame else {}),
         "planes": [dict(pl.as_dict(), heightmap=heightmap_name(k, pl))
                    for k, pl in enumerate(res.planes)]}, indent=1))
    save_overview(output / "overview.png", points, labels, res.planes, res.heightmaps,
                  title=f"{Path(source).name}: {len(res.planes)} planes")
    dump_config(cfg, output / "config.yaml")
