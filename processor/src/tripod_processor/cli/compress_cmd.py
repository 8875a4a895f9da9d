# SPDX-License-Identifier: BSD-3-Clause
"""``tripod compress`` / ``decompress`` / ``rd`` / ``train-compressor``: the learned codec."""

from __future__ import annotations

import json
import re
import time
from pathlib import Path
from typing import Optional

import typer

from . import app
from ._common import console, fail

_PANEL = "Compression"
_UNITS = {"": 1.0, "m": 1.0, "cm": 1e-2, "mm": 1e-3, "um": 1e-6}


def parse_length(text: str) -> float:
    """'2mm', '0.5 cm', '0.002' (metres) -> metres."""
    m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+(?:e-?[0-9]+)?)\s*([a-z]*)\s*", text.lower())
    if not m or m.group(2) not in _UNITS:
        raise ValueError(f"not a length: {text!r} (use e.g. 2mm, 0.5cm, 0.002)")
    value = float(m.group(1)) * _UNITS[m.group(2)]
    if value <= 0:
        raise ValueError(f"length must be > 0: {text!r}")
    return value


def _read_cloud(path: Path):
    from ..io.clouds import read_cloud

    try:
        return read_cloud(path)
    except (OSError, ValueError) as exc:
        fail(f"{path}: {exc}")


def _read_points(path: Path):
    import numpy as np

    from ..io.clouds import xyz

    return xyz(_read_cloud(path), np.float32)


@app.command("compress", rich_help_panel=_PANEL)
def compress_cmd(
    cloud: Path = typer.Argument(..., help="Input cloud (PLY or PCD)."),
    output: Path = typer.Option(..., "-o", "--output", help="Output .tpc file."),
    error: Optional[str] = typer.Option(None, "--error",
                                        help="Max distance of any point from its decoded position, "
                                             "e.g. 2mm (the default: 2mm)."),
    bpp: Optional[float] = typer.Option(None, "--bpp", help="Target bits per point instead."),
    voxel: Optional[str] = typer.Option(None, "--voxel", help="Voxel edge instead, e.g. 5mm."),
    intensity: bool = typer.Option(True, "--intensity/--no-intensity",
                                   help="Keep the cloud's intensity field, if it has one "
                                        "(octree: mean per voxel; predictive: per point)."),
    mode: str = typer.Option("auto", "--mode",
                             help="auto (both, the smaller file), octree (learned, any cloud) "
                                  "or predictive (ordered sensor scans, keeps every point in "
                                  "order)."),
    origin: Optional[str] = typer.Option(None, "--origin",
                                         help="Sensor position x,y,z [m] for the predictive "
                                              "mode (default: the PCD VIEWPOINT, else 0,0,0)."),
) -> None:
    """Compress a cloud's geometry (and intensity) to a .tpc file (learned octree, or
    predictive coding of an ordered scan: the smaller of the two by default)."""
    import numpy as np

    from ..io.clouds import pcd_viewpoint, xyz
    from ..compression import MODES, CodecError, compress_with_info
    from ..compression.model import load_table

    if sum(v is not None for v in (error, bpp, voxel)) > 1:
        fail("give only one of --error, --bpp, --voxel")
    if mode not in MODES:
        fail(f"--mode must be one of {', '.join(MODES)}, not {mode!r}")
    if origin is not None:
        try:
            kw_origin = np.array([float(v) for v in origin.split(",")])
            if kw_origin.shape != (3,) or not np.isfinite(kw_origin).all():
                raise ValueError
        except ValueError:
            fail(f"--origin must be x,y,z in metres, not {origin!r}")
    else:
        kw_origin = pcd_viewpoint(cloud) if cloud.is_file() else None
    try:
        kw = {"bpp": bpp} if bpp is not None else (
            {"voxel_size": parse_length(voxel)} if voxel is not None
            else {"error": parse_length(error or "2mm")})
    except ValueError as exc:
        fail(str(exc))
    structured = _read_cloud(cloud)
    points = xyz(structured, np.float32)
    names = structured.dtype.names or ()
    if intensity and "intensity" in names:
        kw["intensity"] = structured["intensity"]
    kw.update(mode=mode, origin=kw_origin)
    load_table()  # once per machine (disk cache), not part of the speed shown
    t = time.perf_counter()
    try:
        data, info = compress_with_info(points, **kw)
    except CodecError as exc:
        fail(str(exc))
    dt = time.perf_counter() - t
    output.parent.mkdir(parents=True, exist_ok=True)
    output.write_bytes(data)
    what = (f"{info.n_voxels} voxels of {1e3 * info.voxel_size:.3g} mm" if info.mode == "octree"
            else f"{info.n_voxels} points in order (predictive, max error "
                 f"{1e3 * info.voxel_size * 3**0.5 / 2:.3g} mm)")
    console.print(f"{cloud} -> {output}: {info.n_points} points -> {what}, {len(data)} bytes, "
                  f"{info.bits_per_point:.3f} bits/point, {info.n_points / dt / 1e6:.2f} M points/s")


@app.command("decompress", rich_help_panel=_PANEL)
def decompress_cmd(
    tpc: Path = typer.Argument(..., help="Input .tpc file."),
    output: Path = typer.Option(..., "-o", "--output", help="Output cloud (.ply or .pcd)."),
) -> None:
    """Decompress a .tpc file to a PLY/PCD cloud (octree: one point per occupied voxel;
    predictive: every point, in the original order)."""
    from ..io.clouds import make_cloud, write_cloud
    from ..compression import CodecError, ContainerError
    from ..compression.codec import decode_cloud
    from ..compression.model import load_table

    if not tpc.is_file():
        fail(f"no such file: {tpc}")
    if output.suffix.lower() not in (".ply", ".pcd"):
        fail(f"unknown cloud extension {output.suffix!r} (use .ply or .pcd)")
    load_table()
    t = time.perf_counter()
    try:
        points, attributes, header = decode_cloud(tpc.read_bytes())
    except (ContainerError, CodecError) as exc:
        fail(f"{tpc}: {exc}")
    dt = time.perf_counter() - t
    output.parent.mkdir(parents=True, exist_ok=True)
    write_cloud(output, make_cloud(points, **{k: v.astype("float32")
                                              for k, v in attributes.items()}))
    mode = "predictive" if "range_step" in header else "octree"
    console.print(f"{tpc} -> {output}: {len(points)} points ({mode}, voxel "
                  f"{1e3 * header['voxel_size']:.3g} mm), {len(points) / max(dt, 1e-9) / 1e6:.2f} "
                  f"M points/s")


@app.command("rd", rich_help_panel=_PANEL)
def rd_cmd(
    clouds: list[Path] = typer.Argument(..., help="Cloud(s) (PLY or PCD)."),
    plot: Path = typer.Option(Path("rd.png"), "--plot", help="RD plot (PNG); a .json beside it."),
    q_min: int = typer.Option(8, help="Coarsest Draco quantisation [bits]."),
    q_max: int = typer.Option(12, help="Finest Draco quantisation [bits]."),
    mode: str = typer.Option("auto", "--mode", help="tripod geometry mode: auto (the smaller "
                                                    "file at each step), octree or predictive."),
) -> None:
    """Rate-distortion of the tripod codec against Draco: bits/point, D1 PSNR, speed, plot
    (the 'mode' column says which geometry mode auto chose at each step)."""
    from tqdm import tqdm

    from ..io.clouds import pcd_viewpoint
    from ..compression import MODES
    from ..compression.rd import draco_available, plot_rd, print_rd_tables, run_rd

    if not 2 <= q_min <= q_max <= 20:
        fail("need 2 <= --q-min <= --q-max <= 20")
    if mode not in MODES:
        fail(f"--mode must be one of {', '.join(MODES)}, not {mode!r}")
    with_draco = draco_available()
    if not with_draco:
        console.print("DracoPy is not installed (pip install 'tripod-processor[bench]'): "
                      "showing the tripod codec only")
    curves = {}
    for path in clouds:
        points = _read_points(path)
        n_jobs = (q_max - q_min + 3) + (q_max - q_min + 1 if with_draco else 0)
        with tqdm(total=n_jobs, desc=path.name, leave=False) as bar:
            curves[path.name] = run_rd(points, range(q_min, q_max + 1), with_draco,
                                       progress=lambda *_: bar.update(), mode=mode,
                                       origin=pcd_viewpoint(path))
    print_rd_tables(curves)
    plot.parent.mkdir(parents=True, exist_ok=True)
    plot_rd(curves, plot)
    plot.with_suffix(".json").write_text(json.dumps(
        {k: [r.as_dict() for r in v] for k, v in curves.items()}, indent=1))
    console.print(f"plot: {plot}")


@app.command("train-compressor", rich_help_panel=_PANEL)
def train_compressor_cmd(
    output: Path = typer.Option(None, "-o", "--output",
                                help="Weights file (default: the shipped one, overwritten)."),
    clouds: Optional[list[Path]] = typer.Argument(None, help="Training clouds (PLY/PCD, e.g. "
                                                  "tripod simulate output); default: built-in "
                                                  "synthetic rooms."),
    seed: int = typer.Option(8, help="Random seed (8 reproduces the shipped weights)."),
    fragments: int = typer.Option(5, help="Fragments to simulate when no clouds are given."),
    epochs: int = typer.Option(400, help="Full-batch epochs."),
    source: str = typer.Option("sim", help="Without clouds: 'sim' (tripod simulate, the "
                                           "default) or 'synthetic' (quick built-in rooms)."),
) -> None:
    """Train the occupancy-context model on the CPU (minutes) and save its integer weights."""
    from ..compression.model import DEFAULT_WEIGHTS
    from ..compression.train import train

    for c in clouds or []:
        if not c.is_file():
            fail(f"no such file: {c}")
    if source not in ("sim", "synthetic"):
        fail(f"--source must be sim or synthetic, not {source!r}")
    out = output or DEFAULT_WEIGHTS
    train(out, clouds=clouds or None, n_fragments=fragments, seed=seed, epochs=epochs,
          source_kind=source, log=console.print)
    console.print(f"weights: {out}")
