# SPDX-License-Identifier: BSD-3-Clause
"""``tripod heightmaps``: planes of a (labelled) cloud, one heightmap per plane, a low-poly room
model and an overview picture."""

from __future__ import annotations

import json
import time
from pathlib import Path

import typer

from . import app
from ._common import console, fail


@app.command("heightmaps", rich_help_panel="Scene understanding")
def heightmaps_cmd(
    cloud: Path = typer.Argument(..., help="input cloud (PLY or PCD), z up"),
    output: Path = typer.Option(..., "-o", "--output", help="output folder"),
    label_field: str = typer.Option("label", "--label-field",
                                    help="use this field as labels when present (else segment)"),
    weights: Path = typer.Option(None, "--weights", help="segmenter weights when segmenting"),
    config: Path = typer.Option(None, "--config", help="YAML config (segment/planes/heightmaps)"),
    pixel: float = typer.Option(None, "--pixel", help="heightmap pixel edge [m] (default 0.05)"),
    threads: int = typer.Option(0, "--threads", help="CPU threads, 0 = all"),
) -> None:
    """Planes per class with outlines, a 16-bit PNG + JSON heightmap per plane, the low-poly room
    (room_lowpoly.ply), planes.json and overview.png in OUTPUT."""
    import numpy as np
    from rich.table import Table
    from tqdm import tqdm

    from tripod_shared.config_io import ConfigError, dump_config, load_config

    from ..scene.heightmaps import CLASS_NAMES, low_poly_mesh, plane_heightmap, write_mesh_ply
    from ..scene.planes import extract_planes, plane_inlier_share
    from ..scene.config import SceneConfig
    from .segment_cmd import _read_points

    try:
        cfg = load_config(SceneConfig, config, {"heightmaps.pixel": pixel,
                                                "segment.num_threads": threads or None,
                                                "segment.weights": str(weights) if weights else None})
    except ConfigError as exc:
        fail(str(exc))
    src, pts = _read_points(cloud)
    t0 = time.perf_counter()
    if label_field in src.dtype.names:
        labels = np.asarray(src[label_field]).astype(np.int32)
        how = f"field {label_field!r}"
    else:
        from ..scene.segmentation import Segmenter

        try:
            labels = Segmenter(cfg.segment.weights, cfg.segment.num_threads,
                               plane_consistency=cfg.segment.plane_consistency)(pts)
        except (FileNotFoundError, ValueError) as exc:
            fail(f"segmenter weights: {exc}")
        how = "segmenter"
    t_seg = time.perf_counter() - t0
    t0 = time.perf_counter()
    planes = extract_planes(pts, labels, num_threads=cfg.segment.num_threads,
                            **cfg.planes.model_dump())
    t_planes = time.perf_counter() - t0
    output.mkdir(parents=True, exist_ok=True)
    from .. import _ext

    normals = _ext.voxel_local_shape(np.ascontiguousarray(pts), 0.05, 1, cfg.segment.num_threads)[:, :3]
    hms = []
    t0 = time.perf_counter()
    for k, pl in enumerate(tqdm(planes, desc="heightmaps", unit="plane")):
        hm = plane_heightmap(pts, pl, normals=normals, **cfg.heightmaps.model_dump())
        hm.save(output / f"plane_{k:02d}_{CLASS_NAMES[pl.label]}.png")
        hms.append(hm)
    t_hm = time.perf_counter() - t0
    V, T, C = low_poly_mesh(planes)
    write_mesh_ply(output / "room_lowpoly.ply", V, T, C)
    (output / "planes.json").write_text(json.dumps(
        {"source": str(cloud), "labels": how,
         "planes": [dict(pl.as_dict(), heightmap=f"plane_{k:02d}_{CLASS_NAMES[pl.label]}.png")
                    for k, pl in enumerate(planes)]}, indent=1))
    from ..scene.plots import save_overview

    save_overview(output / "overview.png", pts, labels, planes, hms, title=f"{cloud.name}: {len(planes)} planes")
    dump_config(cfg, output / "config.yaml")
    share = plane_inlier_share(pts, labels, planes, 0.05)
    table = Table(title=f"tripod heightmaps: {len(pts):,} points -> {output}")
    table.add_column("plane")
    table.add_column("class")
    table.add_column("points", justify="right")
    table.add_column("area [m²]", justify="right")
    table.add_column("σ [mm]", justify="right")
    table.add_column("heightmap px", justify="right")
    for k, (pl, hm) in enumerate(zip(planes, hms)):
        table.add_row(str(k), CLASS_NAMES[pl.label], f"{len(pl.indices):,}", f"{pl.area:.1f}",
                      f"{pl.sigma * 1000:.1f}", f"{hm.height.shape[1]}x{hm.height.shape[0]}")
    console.print(table)
    console.print(f"labels from {how} ({t_seg:.2f} s), planes {t_planes:.2f} s, heightmaps "
                  f"{t_hm:.2f} s; {share:.1%} of floor/ceiling/wall points within 5 cm of a plane; "
                  f"low-poly model {len(T)} triangles")
