# SPDX-License-Identifier: BSD-3-Clause
"""``tripod batch``: every recording under the inputs reconstructed as its own Ray task
(library: :mod:`tripod_processor.batch`)."""

from __future__ import annotations

from pathlib import Path

import typer

from . import app
from ._common import fail, reconstruct_config


def batch_table(res):
    """A rich table: one row per recording."""
    from rich.table import Table

    from ..batch.index import COLUMNS, row

    t = Table(title=f"tripod batch: {res.engine}, {res.wall_s:.1f} s", header_style="bold")
    for c in COLUMNS[:-1]:
        t.add_column(c, justify="left" if c in ("recording", "status") else "right")
    t.add_column("error")
    colour = {"done": "green", "skipped": "cyan", "failed": "red"}
    for o in res.outcomes:
        cells = row(o)
        cells[1] = f"[{colour[o['status']]}]{cells[1]}[/]"
        t.add_row(*cells, o.get("error", ""))
    return t


def merge_config(sets: list[str], threads: int):
    """The MergeConfig of ``--set merge.KEY=value`` items (one line and exit 2 on a bad one)."""
    from tripod_shared.config_io import ConfigError, load_config

    from ..reconstruction.merge import MergeConfig
    from ._common import parse_sets

    overrides = parse_sets(sets)
    overrides.setdefault("num_threads", threads)
    try:
        return load_config(MergeConfig, None, overrides)
    except ConfigError as exc:
        fail(f"merge: {exc}")


def merge_table(mres):
    """A rich table of the merged model: one row per component."""
    from rich.table import Table

    from ..reconstruction.merge import merge_summary

    s = merge_summary(mres)
    t = Table(title=f"merged model ({mres.outdir}): {s['links_kept']} links between recordings, "
                    f"{s['recording_pairs_joined']} recording pairs joined "
                    f"({s['recording_pairs_proximity']} by proximity; "
                    f"{s['recording_pairs_left_out']} left out by the shortlist), "
                    f"{s['processing_s']:.1f} s", header_style="bold")
    for c in ("component", "recordings", "stations", "folder"):
        t.add_column(c, justify="right" if c in ("component", "stations") else "left")
    for c in s["components"]:
        t.add_row(str(c["component"]), ", ".join(c["recordings"]), str(c["stations"]),
                  "." if c["component"] == 0 else f"component-{c['component']}/")
    return t


@app.command("batch", rich_help_panel="Run")
def batch_command(
    inputs: list[Path] = typer.Argument(
        None, help="recordings or folders to search: our MCAP files (split parts grouped), "
                   "pcap + IMU log pairs (X.pcap with X.tripimu), `tripod simulate` folders"),
    output: Path = typer.Option(Path("batch"), "-o", "--output",
                                help="output folder: one folder per recording, index.md/html"),
    workers: int = typer.Option(1, "--workers", min=1,
                                help="CPUs of the local Ray instance (parallel recordings)"),
    address: str = typer.Option(None, "--address",
                                help="use a running Ray cluster: auto or HOST:PORT (paths must "
                                     "be the same on every node)"),
    threads: int = typer.Option(1, "--threads-per-task", min=1,
                                help="CPUs (and reconstruction threads) per recording"),
    max_retries: int = typer.Option(2, "--max-retries", min=0,
                                    help="retries of a recording whose worker process died"),
    force: bool = typer.Option(False, "--force", help="reconstruct even what is up to date"),
    split_large: int = typer.Option(
        100, "--split-large", min=0,
        help="a recording of at least this many stations spreads its fragments and "
             "registrations over the engine as tasks (0: never; the same outputs)"),
    merge: bool = typer.Option(False, "--merge",
                               help="join the recordings into one model in OUTDIR/merged: links "
                                    "between their stations, one pose graph, one map"),
    config: Path = typer.Option(None, "--config", help="reconstruction YAML config"),
    calibration: Path = typer.Option(None, "--calibration",
                                     help="lidar-IMU extrinsic, as for tripod reconstruct"),
    set_: list[str] = typer.Option(None, "--set", help="override a config key: a.b=value "
                                                       "(merge.KEY=value: the merge's)"),
    list_only: bool = typer.Option(False, "--list", help="list the recordings found and exit"),
    quiet: bool = typer.Option(False, "--quiet", help="no progress bar"),
) -> None:
    """Reconstruct many recordings (skipping those up to date) on Ray; index page at the end;
    with --merge, one model of them all."""
    from rich.console import Console
    from tqdm import tqdm

    from ..batch import batch_reconstruct, discover
    from ..reconstruction.engine import EngineError

    if not inputs:
        fail("give recordings or folders to search")
    recs, notes = discover(list(inputs))
    con = Console()
    for n in notes:
        con.print(f"[yellow]note:[/] {n}")
    if not recs:
        fail("no recording found (MCAP, pcap + IMU log, or simulate folder)")
    if list_only:
        for r in recs:
            con.print(f"{r.name}  [dim]{r.kind}[/]  " + ", ".join(str(p) for p in r.inputs)
                      + (f" + {r.imu}" if r.imu else ""))
        raise typer.Exit(0)
    rec_sets = [s for s in set_ or [] if not s.startswith("merge.")]
    merge_sets = [s[len("merge."):] for s in set_ or [] if s.startswith("merge.")]
    cfg = reconstruct_config(config, rec_sets, calibration, forced={"num_threads": threads})
    mcfg = None
    if merge:
        mcfg = merge_config(merge_sets, threads)
    elif merge_sets:
        fail("merge.* settings need --merge")

    bar = tqdm(total=len(recs), desc="recordings", unit="rec", disable=quiet,
               dynamic_ncols=True)

    def on_done(o: dict, done: int, total: int) -> None:
        bar.n = done
        bar.refresh()
        if o["status"] == "failed" and not quiet:
            bar.write(f"failed: {o['name']}: {o['error']}")

    mbar = None
    mstep = ""

    def on_merge(step: str, done: int, total: int) -> None:
        nonlocal mbar, mstep
        if quiet:
            return
        if mbar is None:
            bar.close()
            mbar = tqdm(total=total, desc=f"merge {step}", unit="pair", dynamic_ncols=True)
        if step != mstep:  # the hypotheses of every pair, then the shortlisted pairs
            mstep = step
            mbar.set_description(f"merge {step}")
            mbar.total = total
        mbar.n = done
        mbar.refresh()

    try:
        res = batch_reconstruct(recs, output, cfg, workers=workers, address=address,
                                max_retries=max_retries, force=force, split_large=split_large,
                                on_done=on_done,
                                merge=mcfg, on_merge=on_merge)
    except EngineError as exc:
        fail(str(exc))
    finally:
        bar.close()
        if mbar is not None:
            mbar.close()
    con.print(batch_table(res))
    if res.merge is not None:
        con.print(merge_table(res.merge))
    con.print(f"index [bold]{output / 'index.html'}[/] and [bold]{output / 'index.md'}[/]")
    if res.count("failed"):
        raise typer.Exit(1)
