# SPDX-License-Identifier: BSD-3-Clause
"""``tripod simulate``: write a simulated VLP-16 + IMU capture with ground truth."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from . import app
from ._common import console, fail


@app.command("simulate", rich_help_panel="Test bed")
def simulate_cmd(
    output: Path = typer.Option(..., "-o", "--output", help="Output directory (created)."),
    scene: Optional[str] = typer.Option(
        None, "--scene", help="room, corridor, two_rooms, office or hall (default room)."),
    scene_file: Optional[Path] = typer.Option(
        None, "--scene-file", help="Any mesh (PLY/OBJ/STL/...) instead of --scene."),
    stations: Optional[int] = typer.Option(
        None, "--stations", help="Number of stations (default 3)."),
    seed: Optional[int] = typer.Option(None, "--seed", help="Random seed (default 0)."),
    return_mode: Optional[str] = typer.Option(
        None, "--return-mode", help="strongest, last or dual (default strongest)."),
    rpm: Optional[float] = typer.Option(
        None, "--rpm", help="Motor speed 300..1200 (default 600)."),
    imu_protocol: Optional[str] = typer.Option(
        None, "--imu-protocol", help="tfp (IMU Brick 2.0) or witmotion (default tfp)."),
    imu_rate: Optional[float] = typer.Option(
        None, "--imu-rate", help="IMU rate in Hz (default 100)."),
    range_noise: Optional[float] = typer.Option(None, "--range-noise",
                                                help="Range noise sigma in m (default 0.03)."),
    noise_free: bool = typer.Option(False, "--noise-free",
                                    help="No range noise, IMU noise or random dropout."),
    gps: bool = typer.Option(False, "--gps", help="GPS attached: PPS locked, GPRMC sentences."),
    mcap: bool = typer.Option(False, "--mcap",
                              help="Also write recording.mcap, as the daemon would record it."),
    config: Optional[Path] = typer.Option(None, "--config", help="YAML config (see config.yaml "
                                          "of any capture); options given here override it."),
    threads: int = typer.Option(0, "--threads", help="Ray-casting threads (0: all cores)."),
    rig: Optional[int] = typer.Option(
        None, "--rig", help="A random rig and capture drawn from this seed (sim.rigs: mount, "
                            "lever arm, IMU latency, hand or motor pan, scene size; development "
                            "seeds 0-9999, test seeds 10000+); the options above override it."),
    survey: Optional[str] = typer.Option(
        None, "--survey", help="The two-wing building surveyed as many recordings: full (8 "
                               "recordings, 223 stations) or small (3, for tests), one capture "
                               "folder each under OUTPUT (for tripod batch --merge); with "
                               "--seed only."),
) -> None:
    """Simulate a tripod capture: capture.pcap, IMU log, ground truth, mesh, labels, meta.json."""
    from tripod_shared.config_io import ConfigError, load_config

    from ..sim import SimConfig, simulate

    if survey is not None:
        _survey(output, survey, seed or 0, threads)
        return

    overrides = {
        "scene": scene,
        "scene_file": str(scene_file) if scene_file else None,
        "stations": stations, "seed": seed, "lidar.return_mode": return_mode, "lidar.rpm": rpm,
        "imu.protocol": imu_protocol, "imu.rate_hz": imu_rate, "lidar.range_noise_m": range_noise,
    }
    if noise_free:
        overrides.update({"lidar.range_noise_m": 0.0, "lidar.dropout": 0.0, "imu.noise_deg": 0.0})
    if gps:
        overrides["lidar.gps"] = True
    if mcap:
        overrides["mcap"] = True
    tmp_cfg = None
    if rig is not None:
        if config is not None:
            fail("--rig and --config: give one of them")
        import tempfile

        import yaml

        from ..sim.rigs import draw_rig

        fd, tmp_cfg = tempfile.mkstemp(suffix=".yaml", prefix="tripod-rig-")
        with open(fd, "w") as fh:
            yaml.safe_dump(draw_rig(rig).model_dump(mode="json", exclude_none=True), fh)
        config = Path(tmp_cfg)
    try:
        cfg = load_config(SimConfig, config, overrides)
    except ConfigError as exc:
        fail(str(exc))
    finally:
        if tmp_cfg is not None:
            Path(tmp_cfg).unlink(missing_ok=True)
    if cfg.scene_file is None:
        from ..sim.scenes import SCENE_NAMES

        if cfg.scene not in SCENE_NAMES:
            fail(f"unknown scene '{cfg.scene}' (choose from {', '.join(SCENE_NAMES)})")
    elif not Path(cfg.scene_file).is_file():
        fail(f"no such mesh file: {cfg.scene_file}")

    from rich.table import Table
    from tqdm import tqdm

    bar = tqdm(total=None, unit="pkt", desc="simulate", disable=None)

    def progress(done: int, total: int) -> None:
        bar.total = total
        bar.n = done
        bar.refresh()

    try:
        s = simulate(cfg, output, nthreads=threads, progress=progress)
    except (ValueError, OSError) as exc:
        bar.close()
        fail(str(exc).splitlines()[0] if str(exc) else type(exc).__name__)
    bar.close()
    t = Table(title=f"tripod simulate → {output}")
    t.add_column("quantity")
    t.add_column("value", justify="right")
    t.add_row("scene", cfg.scene_file or cfg.scene)
    t.add_row("stations", str(s.stations))
    t.add_row("sensor time (s)", f"{s.duration_s:.2f}")
    t.add_row("data packets", str(s.data_packets))
    t.add_row("position packets", str(s.position_packets))
    t.add_row("IMU samples", str(s.imu_samples))
    t.add_row("wall time (s)", f"{s.wall_s:.2f}")
    t.add_row("real-time factor", f"{s.realtime_factor:.1f}x")
    console.print(t)


def _survey(output: Path, size: str, seed: int, threads: int) -> None:
    """``--survey``: every recording of the building (sim.survey_building)."""
    from rich.table import Table

    from ..sim.survey_building import simulate_survey, survey_plan

    if size not in ("full", "small"):
        fail(f"unknown survey {size!r} (full or small)")
    plan = survey_plan(size)
    try:
        dirs = simulate_survey(output, size, seed, nthreads=threads,
                               progress=lambda i, n: console.print(f"recording {i}/{n}"))
    except (ValueError, OSError) as exc:
        fail(str(exc).splitlines()[0] if str(exc) else type(exc).__name__)
    t = Table(title=f"tripod simulate --survey {size} → {output}")
    for c in ("recording", "stations", "route m"):
        t.add_column(c, justify="left" if c == "recording" else "right")
    import json

    for d, r in zip(dirs, plan):
        meta = json.loads((d / "meta.json").read_text())
        t.add_row(d.name, str(r.stations), f"{meta['scene']['route_length_m']:.1f}")
    console.print(t)
