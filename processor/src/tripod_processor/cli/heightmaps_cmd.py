# SPDX-License-Identifier: BSD-3-Clause
"""``tripod heightmaps``: planes of a (labelled) cloud, one heightmap per plane, a low-poly room
model and an overview picture."""

from __future__ import annotations

import time
from pathlib import Path

import typer

from . import app
from ._common import UP_HELP, console, fail


@app.command("heightmaps", rich_help_panel="Scene understanding")
def heightmaps_cmd(
    cloud: Path = typer.Argument(..., help="input cloud (PLY or PCD): with its up direction, "
                                           "or z up"),
    output: Path = typer.Option(..., "-o", "--output", help="output folder"),
    up: str = typer.Option(None, "--up", help=UP_HELP),
    label_field: str = typer.Option("label", "--label-field",
                                    help="use this field as labels when present (else segment)"),
    weights: Path = typer.Option(None, "--weights", help="segmenter weights when segmenting"),
    config: Path = typer.Option(None, "--config", help="YAML config (segment/planes/heightmaps)"),
    pixel: float = typer.Option(None, "--pixel", help="heightmap pixel edge [m] (default 0.05)"),
    threads: int = typer.Option(0, "--threads", help="CPU threads, 0 = all"),
) -> None:
    """Planes per class with outlines, a 16-bit PNG + JSON heightmap per plane, the low-poly room
    (room_lowpoly.ply and room_lowpoly.obj + .mtl), planes.json and overview.png in OUTPUT.
    A cloud with an up direction (its file's, or --up) is levelled first: the outputs are then
    in the levelled frame (z up), and planes.json gives R_level_cloud (x_level = R x_cloud)."""
    import numpy as np
    from rich.table import Table

    from tripod_shared.config_io import ConfigError, load_config

    from ..scene.config import SceneConfig
    from ..scene.heightmaps import CLASS_NAMES
    from ..scene.pipeline import analyse_scene, segment_labels, write_scene
    from ._common import read_points_up

    try:
        cfg = load_config(SceneConfig, config, {"heightmaps.pixel": pixel,
                                                "segment.num_threads": threads or None,
                                                "segment.weights": str(weights) if weights else None})
    except ConfigError as exc:
        fail(str(exc))
    src, pts, up_vec, up_from = read_points_up(cloud, up)
    frame = None
    if up_vec is not None:  # planes, heightmaps and the room model want z up
        from ..scene.gravity import level_points

        pts, R = level_points(pts, up_vec)
        frame = {"up": up_vec.tolist(), "up_from": up_from, "R_level_cloud": R.tolist()}
    t0 = time.perf_counter()
    if label_field in src.dtype.names:
        labels = np.asarray(src[label_field]).astype(np.int32)
        how = f"field {label_field!r}"
    else:
        try:
            labels = segment_labels(pts, cfg)
        except (FileNotFoundError, ValueError) as exc:
            fail(f"segmenter weights: {exc}")
        how = "segmenter"
    t_seg = time.perf_counter() - t0
    res = analyse_scene(pts, labels, cfg, progress=True)
    write_scene(output, res, pts, labels, str(cloud), how, cfg, frame=frame)
    table = Table(title=f"tripod heightmaps: {len(pts):,} points -> {output}")
    table.add_column("plane")
    table.add_column("class")
    table.add_column("points", justify="right")
    table.add_column("area [m²]", justify="right")
    table.add_column("σ [mm]", justify="right")
    table.add_column("heightmap px", justify="right")
    for k, (pl, hm) in enumerate(zip(res.planes, res.heightmaps)):
        table.add_row(str(k), CLASS_NAMES[pl.label], f"{len(pl.indices):,}", f"{pl.area:.1f}",
                      f"{pl.sigma * 1000:.1f}", f"{hm.height.shape[1]}x{hm.height.shape[0]}")
    console.print(table)
    console.print(f"labels from {how} ({t_seg:.2f} s), planes {res.seconds['planes']:.2f} s, "
                  f"heightmaps {res.seconds['heightmaps']:.2f} s; {res.inlier_share:.1%} of "
                  "floor/ceiling/wall points within 5 cm of a plane; "
                  f"low-poly model {len(res.mesh[1])} triangles")
    if up_vec is not None:
        where = "--up" if up_from == "--up" else "the file"
        console.print(f"levelled by the up direction from {where}"
                      f" ({up_vec[0]:.3f}, {up_vec[1]:.3f}, {up_vec[2]:.3f}); outputs in the "
                      "levelled frame (R_level_cloud in planes.json)")
