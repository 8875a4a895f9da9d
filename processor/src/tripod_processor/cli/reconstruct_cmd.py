# SPDX-License-Identifier: BSD-3-Clause
"""``tripod reconstruct``: a recording in, a registered indoor model, report and numbers out."""

from __future__ import annotations

from pathlib import Path

import typer

from . import app
from ._common import fail, reconstruct_config



def results_table(summary: dict, title: str = "tripod reconstruct"):
    """A rich table of a run's numbers."""
    from rich.table import Table

    t = Table(title=title, show_header=True, header_style="bold")
    t.add_column("quantity")
    t.add_column("value", justify="right")
    rec_s = summary["recording_s"]
    t.add_row("recording", f"{rec_s:.1f} s, {summary['lidar_packets']} packets, "
                           f"{summary['imu_samples']} IMU samples")
    disc = summary["disconnected_stations"]
    t.add_row("stations", f"{summary['stations']}" + (f" ({len(disc)} disconnected: {disc})"
                                                     if disc else ""))
    t.add_row("edges: odometry / loop (rejected)",
              f"{summary['odometry_edges']} ({summary.get('odometry_edges_rejected', 0)}) / "
              f"{summary['loop_edges']} ({summary['loop_edges_rejected']})")
    est = (summary.get("calibration") or {}).get("estimate") or {}
    src = (summary.get("calibration") or {}).get("source", {})
    sig_t = est.get("imu_time_offset_sigma_ms")
    t.add_row("IMU time offset", f"{summary['imu_time_offset_ms']:.2f} ms" + (
        f" ± {sig_t:.2f} ({src.get('imu_time_offset_s', '')})"
        if sig_t is not None and sig_t == sig_t else ""))
    lev = summary["extrinsic"]["lever_arm_m"]
    sig_l = est.get("lever_arm_sigma_m")
    t.add_row("lever arm", "[" + ", ".join(f"{100 * v:.2f}" for v in lev) + "] cm" + (
        f" ± {1000 * max(sig_l):.1f} mm across the pan axis ({src.get('lever_arm_m', '')})"
        if sig_l and all(v == v for v in sig_l) else f" ({src.get('lever_arm_m', 'config')})"))
    t.add_row("extrinsic", summary["extrinsic"]["source"])
    t.add_row("map points", f"{summary['map_points']:,}")
    cpu = summary.get("stage_cpu_s", {})
    for k, v in summary["stage_s"].items():
        t.add_row(f"  time: {k}", f"{v:.2f} s wall, {cpu.get(k, float('nan')):.2f} s CPU")
    t.add_row("processing / recording time",
              f"{summary['processing_s']:.1f} s / {rec_s:.1f} s = "
              f"{summary['processing_s'] / max(rec_s, 1e-9):.3f} "
              f"(CPU {summary.get('processing_cpu_s', float('nan')) / max(rec_s, 1e-9):.3f})")
    for key in ("ate_cm", "ate_deg", "map_to_mesh_median_cm"):
        if key in summary:
            t.add_row(key, f"{summary[key]:.3f}")
    return t


@app.command("reconstruct", rich_help_panel="Run")
def reconstruct_command(
    recording: list[Path] = typer.Argument(
        None, help="our MCAP recording (one or more files of one recording), a pcap plus an IMU "
                   "log, or a `tripod simulate` folder"),
    output: Path = typer.Option(Path("reconstruction"), "-o", "--output", help="output folder"),
    imu: Path = typer.Option(None, "--imu", help="IMU log for a pcap (tripod IMU log or text "
                                                 "'t w x y z')"),
    config: Path = typer.Option(None, "--config", help="YAML config (see --print-default-config)"),
    calibration: Path = typer.Option(
        None, "--calibration", help="lidar-IMU extrinsic: YAML/JSON with q_imu_lidar and "
                                    "lever_arm_m, or a simulator's gt/calibration.json"),
    survey: bool = typer.Option(
        False, "--survey", help="also write the survey files: stations.e57 (one scan per "
                                "station with its pose) and map.laz (intensity, station, ASPRS "
                                "classes); = --set output.write_e57=true output.write_las=laz"),
    set_: list[str] = typer.Option(None, "--set", help="override a config key: a.b=value"),
    address: str = typer.Option(
        None, "--address", rich_help_panel="Engine",
        help="run fragments, odometry pairs and loop candidates as tasks on a running Ray "
             "cluster: auto or HOST:PORT (the same outputs; the recording stays on this machine)"),
    workers: int = typer.Option(
        0, "--workers", min=0, rich_help_panel="Engine",
        help="the same on a local Ray instance of N CPUs started for the run (0: in process, "
             "the default)"),
    max_retries: int = typer.Option(2, "--max-retries", min=0, rich_help_panel="Engine",
                                    help="retries of a task whose worker process died"),
    quiet: bool = typer.Option(False, "--quiet", help="no progress bars"),
    print_default_config: bool = typer.Option(False, "--print-default-config",
                                              help="print the default config and exit"),
) -> None:
    """Reconstruct an indoor model: stations, fragments, odometry, pose graph, map, report."""
    from rich.console import Console

    from tripod_shared.config_io import dump_config

    from ..reconstruction.config import ReconstructConfig
    from ..reconstruction.inputs import RecordingError

    if print_default_config:
        print(dump_config(ReconstructConfig()), end="")
        raise typer.Exit(0)
    if not recording:
        fail("give a recording (MCAP, pcap + --imu, or a simulate folder)")
    survey_outputs = {"output.write_e57": True, "output.write_las": "laz"} if survey else {}
    cfg = reconstruct_config(config, set_, calibration, defaults=survey_outputs)
    from ..reconstruction.pipeline import reconstruct, summary

    con = Console()
    engine = None
    if address or workers:
        from ..reconstruction.engine import EngineError, ray_engine

        if cfg.num_threads == 0:
            # all cores per task would oversubscribe every node: one thread (and CPU) per task
            cfg = cfg.model_copy(update={"num_threads": 1})
        try:
            engine = ray_engine(workers or 1, address, cfg.num_threads, max_retries)
        except EngineError as exc:
            fail(str(exc))
        if not quiet:
            con.print(f"engine: {engine.name}, {cfg.num_threads} CPU(s) per task")
    try:
        res = reconstruct(recording, output, cfg, imu_log=imu, quiet=quiet, engine=engine)
    except RecordingError as exc:
        fail(str(exc))
    finally:
        if engine is not None:
            engine.close()
    con.print(results_table(summary(res)))
    for n in res.notes:
        con.print(f"[yellow]note:[/] {n}")
    con.print(f"outputs in [bold]{output}[/]" + (f", report [bold]{res.files['report']}[/]"
                                                 if "report" in res.files else ""))
