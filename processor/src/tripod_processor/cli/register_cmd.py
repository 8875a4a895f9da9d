# SPDX-License-Identifier: BSD-3-Clause
"""``tripod register``: align two PLY/PCD clouds and print T_target_source + quality as JSON."""

from __future__ import annotations

import json
import re
import sys
import time
from pathlib import Path
from typing import Optional

import typer

from . import app
from ._common import EXIT_FAILED, fail, unit_hint

#: local statuses that mean no usable alignment ("max_iterations" is kept, with a warning)
FAILED_STATUSES = ("too_few_correspondences", "degenerate")


@app.command("register", rich_help_panel="Processing")
def register_cmd(
    source: Path = typer.Argument(..., help="Source cloud (PLY or PCD, binary_compressed too)."),
    target: Path = typer.Argument(..., help="Target cloud (PLY or PCD)."),
    method: str = typer.Option("gicp", "--method", "-m",
                               help="gicp, icp (point-to-point), plane, symmetric, lm (Ceres) or heightmaps "
                                    "(global: match floor heightmaps of the segmented clouds)."),
    init: str = typer.Option("identity", "--init",
                             help="'identity' or a text file with the 4x4 initial T_target_source."),
    voxel: Optional[float] = typer.Option(None, "--voxel", help="Downsampling voxel in m."),
    global_: bool = typer.Option(False, "--global",
                                 help="Global registration (FPFH + RANSAC) first; needs --voxel."),
    gravity: bool = typer.Option(False, "--gravity",
                                 help="Global search over yaw only: about each cloud's up "
                                      "(--up, or the files'; else both z up)."),
    max_distance: Optional[str] = typer.Option(
        None, "--max-distance",
        help="Max correspondence distance in m; a comma list is a coarse-to-fine schedule."),
    max_iterations: int = typer.Option(64, "--max-iterations", help="Per stage."),
    loss: str = typer.Option("none", "--loss", help="none, huber, cauchy or tukey."),
    loss_scale: float = typer.Option(0.1, "--loss-scale", help="Robust kernel scale in m."),
    lock_z: bool = typer.Option(False, "--lock-z", help="Keep the initial z translation."),
    point_sigma: float = typer.Option(0.02, "--point-sigma", help="Range noise in m."),
    output: Optional[Path] = typer.Option(None, "-o", "--output",
                                          help="Also write the JSON here (and the options beside)."),
    threads: int = typer.Option(0, "--threads", help="Threads (0: all cores)."),
    up: Optional[str] = typer.Option(
        None, "--up", help="heightmaps: up direction X,Y,Z of both clouds in their own frames "
                           "(overrides the files'; tripod reconstruct writes it)."),
    source_up: Optional[str] = typer.Option(None, "--source-up",
                                            help="heightmaps: the source's up X,Y,Z (over --up)."),
    target_up: Optional[str] = typer.Option(None, "--target-up",
                                            help="heightmaps: the target's up X,Y,Z (over --up)."),
) -> None:
    """Register SOURCE onto TARGET; prints JSON: the 4x4 T_target_source and quality figures."""
    import numpy as np

    from ..io import clouds as cloud_io
    from ..registration import pairwise as reg

    if method == "heightmaps":  # scene understanding's global method (no initial guess needed)
        from ._heightmap_register import register_heightmaps_cmd

        register_heightmaps_cmd(source, target, output, threads, _dumps,
                                source_up or up, target_up or up)
        return
    if (up or source_up or target_up) and not gravity:
        fail("--up, --source-up and --target-up apply to --method heightmaps and --gravity")
    if method not in reg.METHODS + ("heightmaps",):
        fail(f"unknown method '{method}' (choose from {', '.join(reg.METHODS + ('heightmaps',))})")
    if loss not in reg.LOSSES:
        fail(f"unknown loss '{loss}' (choose from {', '.join(reg.LOSSES)})")
    if global_ and not voxel:
        fail("--global needs --voxel (the feature scale)")
    if voxel is not None and not voxel > 0:
        fail("--voxel must be > 0")
    dists = None
    if max_distance:
        try:
            dists = [float(v) for v in max_distance.split(",")]
        except ValueError:
            fail(f"--max-distance: not a number list: {max_distance!r}")
    try:
        src_c, src_meta = cloud_io.read_cloud_meta(source)
        tgt_c, tgt_meta = cloud_io.read_cloud_meta(target)
        src, tgt = cloud_io.xyz(src_c), cloud_io.xyz(tgt_c)
        T0 = np.eye(4) if init == "identity" else cloud_io.read_matrix4(init)
        ups = _gravity_ups(source_up or up, target_up or up, src_meta.up, tgt_meta.up)
    except (OSError, ValueError) as exc:
        fail(str(exc).splitlines()[0] if str(exc) else type(exc).__name__)
    for path, pts in ((source, src), (target, tgt)):
        if not len(pts):
            fail(f"{path}: the cloud has no points")

    out: dict = {"source": str(source), "target": str(target), "method": method}
    t0 = time.perf_counter()
    failure = ""
    r = None
    try:
        if global_:
            g = reg.register_global(src, tgt, voxel_size=voxel,
                                    gravity_aligned=gravity and ups is None,
                                    up_source=ups[0] if gravity and ups else None,
                                    up_target=ups[1] if gravity and ups else None,
                                    num_threads=threads)
            out["global"] = g.to_dict()
            if not g.success:
                failure = f"global registration failed: {g.status}"
            elif g.ambiguous:
                print("tripod: warning: global registration is ambiguous: a twin turned "
                      f"{abs(g.twins[1]['turn_deg'] - g.twins[0]['turn_deg']):.0f} deg about the up "
                      "fits about as well",
                      file=sys.stderr)
            T0 = g.T_target_source
        if not failure:
            r = reg.register(src, tgt, method=method, init=T0, voxel_size=voxel,
                             max_correspondence_distance=dists, max_iterations=max_iterations,
                             loss=loss, loss_scale=loss_scale, lock_z=lock_z,
                             point_sigma=point_sigma, num_threads=threads)
    except ValueError as exc:
        fail(str(exc))
    if r is not None:
        out.update(r.to_dict())
        if r.status in FAILED_STATUSES:
            failure = f"registration failed: {r.status}"
    else:
        out["T_target_source"] = np.eye(4).tolist()
    out["success"] = not failure
    out["wall_time_s"] = time.perf_counter() - t0
    text = _dumps(out)
    print(text)
    if output is not None:
        output.parent.mkdir(parents=True, exist_ok=True)
        output.write_text(text + "\n")
        options = {"method": method, "init": init, "voxel": voxel, "global": global_,
                   "gravity": gravity, "max_distance": dists, "max_iterations": max_iterations,
                   "loss": loss, "loss_scale": loss_scale, "lock_z": lock_z,
                   "point_sigma": point_sigma, "threads": threads}
        output.with_name(output.stem + ".options.json").write_text(json.dumps(options, indent=2))
    if failure:  # the JSON above still says what was tried; exit 1 as for any failed job
        fail(failure + unit_hint(src, tgt), code=EXIT_FAILED)
    if not r.converged:
        print(f"tripod: warning: registration status {r.status}", file=sys.stderr)


def _gravity_ups(src_given, tgt_given, src_file, tgt_file):
    """(up_source, up_target) for ``--gravity``: the command line's over the files', z for a
    cloud without one; None when neither has one."""
    from ..scene.gravity import parse_up

    s = parse_up(src_given) if src_given else src_file
    t = parse_up(tgt_given) if tgt_given else tgt_file
    if s is None and t is None:
        return None
    z = (0.0, 0.0, 1.0)
    return (z if s is None else s, z if t is None else t)


def _dumps(obj) -> str:
    """Indented JSON with each innermost list of numbers (a matrix row) on one line."""
    text = json.dumps(obj, indent=2)
    return re.sub(r"\[[\s\d.eE+\-,]*\]", lambda m: re.sub(r"\s+", " ", m.group(0))
                  .replace("[ ", "[").replace(" ]", "]"), text)
