# SPDX-License-Identifier: BSD-3-Clause
"""``tripod decode``: Velodyne packets (pcap/pcapng, raw payloads, tripod MCAP) → one cloud per
rotation, plus a JSON summary."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import NoReturn

import typer

from . import app
from ._common import console, fail

FORMATS = ("ply", "pcd")


FRAME_GLOB = "frame_[0-9][0-9][0-9][0-9][0-9][0-9].*"  # the frames write_frames names
OWN_FILES = ("summary.json", "decode_config.yaml")


def _write_frame(path: Path, frame, sensor: str, fmt: str) -> None:
    from ..io.clouds import write_pcd, write_ply

    if fmt == "ply":
        write_ply(path, frame.points, comments=[
            f"tripod decode frame {frame.index}",
            f"sensor {sensor}",
            f"stamp_host_ns {frame.stamp_host_ns}",
            f"stamp_device_ns {frame.stamp_device_ns}",
            "frame lidar: x forward, y left, z up [m]; time_offset_ns since "
            "stamp_device_ns (lidar clock)",
        ])
    else:
        write_pcd(path, frame.points)


def clear_old_output(outdir: Path) -> int:
    """Remove the files an earlier ``tripod decode`` left in ``outdir`` (its frames,
    summary.json, decode_config.yaml), so the folder describes one run; returns how many
    frames went. Other files are left alone."""
    old = [p for p in outdir.glob(FRAME_GLOB) if p.suffix in (".ply", ".pcd")]
    for p in old:
        p.unlink()
    for name in OWN_FILES:
        (outdir / name).unlink(missing_ok=True)
    return len(old)


def write_frames(run, outdir: Path | None, fmt: str = "ply", progress: bool = True,
                 on_first_frame=None) -> dict:
    """Iterate a :class:`~tripod_processor.decode.decoder.DecodeRun`, write each frame to
    ``outdir``
    (when given) as ``frame_NNNNNN.<fmt>``; return timing figures. Raises the decoder's errors.

    ``on_first_frame()`` is called once the decoder has accepted the input (the sensor is
    known and a first frame is ready), before anything is written.
    """
    from tqdm import tqdm

    bar = tqdm(total=None, unit=" frames", disable=None if progress else True, file=sys.stderr,
               leave=False, desc="decode")
    t0 = time.perf_counter()
    n = 0
    for frame in run:
        if n == 0 and on_first_frame is not None:
            on_first_frame()
        if outdir is not None:
            _write_frame(outdir / f"frame_{frame.index:06d}.{fmt}", frame, run.report.sensor,
                         fmt)
        n += 1
        bar.update(1)
    bar.close()
    return {"frames_written": n if outdir is not None else 0,
            "seconds": time.perf_counter() - t0}


def _table(summary: dict, input_path: str, outdir: Path | None, seconds: float) -> None:
    from rich.table import Table

    t = Table(title=f"tripod decode: {input_path}", show_header=False, title_justify="left")
    t.add_column("what", style="bold")
    t.add_column("value")
    ppf = summary["points_per_frame"]
    t.add_row("sensor", f"{summary['sensor']} (product {summary['product_id']}, "
              f"{summary['packet_period_us']} µs/packet)")
    t.add_row("return mode", summary["return_mode"])
    t.add_row("data packets", str(summary["packets"]))
    t.add_row("frames / rotations", f"{summary['frames']} / {summary['rotations']}")
    if ppf:
        full = sorted(ppf[1:-1]) or ppf
        t.add_row("points", f"{summary['points']} (median full frame {full[len(full) // 2]})")
    t.add_row("duration", f"{summary['duration_s']} s (lidar clock)")
    g = summary["gaps"]
    t.add_row("gaps", f"{g['count']} ({g['missing_packets']} packets missing, longest "
              f"{g['max_s'] * 1e3:.1f} ms)" if g["count"] else "none")
    pos = summary["position"]
    if pos["packets"]:
        nmea = ", ".join(f"{k} {v}" for k, v in pos["nmea"].items()) or "no NMEA"
        pps = ", ".join(f"{k} {v}" for k, v in pos["pps"].items())
        t.add_row("position packets", f"{pos['packets']} ({nmea}; PPS {pps})")
        if pos["first_utc"]:
            t.add_row("GPS time", f"{pos['first_utc']} … {pos['last_utc']}")
    if summary["skipped"]:
        t.add_row("skipped", ", ".join(f"{k} {v}" for k, v in summary["skipped"].items()))
    if outdir is not None:
        t.add_row("output", str(outdir))
    rate = summary["points"] / seconds if seconds > 0 else 0.0
    t.add_row("time", f"{seconds:.2f} s ({rate / 1e6:.2f} M points/s)")
    console.print(t)


def run_decode(input_path: Path, outdir: Path | None, *, summary_only: bool = False,
               fmt: str = "ply", config_path: Path | None = None,
               overrides: dict | None = None, ports: list[int] | None = None,
               progress: bool = True) -> dict:
    """The body of ``tripod decode`` (also used by ``tripod demo``); returns the summary.

    Errors end the program with one line and exit code 2 (via :func:`fail`).
    """
    from tripod_shared.config_io import ConfigError, dump_config, load_config

    from ..decode.decoder import DecodeConfig, DecodeError, decode_file
    from ..io.packets import SourceError

    if fmt not in FORMATS:
        fail(f"unknown format {fmt!r} (use {' or '.join(FORMATS)})")
    try:
        cfg = load_config(DecodeConfig, config_path, overrides)
    except ConfigError as exc:
        fail(str(exc))
    if cfg.decoder is not None:
        print(f"tripod: note: {config_path}: the key 'decoder' is deprecated and ignored (tripod "
              "always decodes with its native decoder); remove it", file=sys.stderr)
    try:
        run = decode_file(input_path, cfg, set(ports) if ports else None)
    except (FileNotFoundError, SourceError) as exc:  # their messages name the input
        fail(str(exc))
    if outdir is not None and outdir.exists() and not outdir.is_dir():
        fail(f"the output {outdir} exists and is not a folder")
    created = outdir is not None and not outdir.exists()
    prepared = False

    def prepare_output() -> None:
        # only once the decoder has accepted the input: a refused input leaves no folder, and
        # an earlier run's output stays until this one has something to replace it with
        nonlocal prepared
        prepared = True
        if outdir is None:
            return
        try:
            outdir.mkdir(parents=True, exist_ok=True)
            removed = clear_old_output(outdir)
        except OSError as exc:
            fail(f"cannot prepare the output folder {outdir}: {exc.strerror}")
        if removed:
            print(f"tripod: note: {outdir}: removed {removed} frame files of an earlier decode",
                  file=sys.stderr)
        dump_config(cfg, outdir / "decode_config.yaml")

    def failed(message: str) -> NoReturn:
        if outdir is not None and prepared:  # leave no half-written run behind
            clear_old_output(outdir)
            if created and not any(outdir.iterdir()):
                outdir.rmdir()
        fail(message)

    try:
        timing = write_frames(run, outdir, fmt, progress=progress, on_first_frame=prepare_output)
    except typer.Exit:  # fail() in prepare_output (click's Exit is a RuntimeError)
        raise
    except SourceError as exc:  # names the input already
        failed(str(exc))
    except DecodeError as exc:
        failed(f"{input_path}: {exc}")
    except OSError as exc:
        failed(f"{input_path}: {exc}")
    except RuntimeError as exc:  # a batch decoder refusing a packet (none known to)
        failed(f"{input_path}: {exc}")
    if not prepared:  # no frame at all
        prepare_output()
    summary = run.report.summary()
    summary["input"] = str(input_path)
    summary["input_format"] = run.source.kind
    for w in summary["warnings"]:
        print(f"tripod: warning: {input_path}: {w}", file=sys.stderr)
    if outdir is not None:
        (outdir / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
    if summary_only:
        print(json.dumps(summary))
    else:
        _table(summary, str(input_path), outdir, timing["seconds"])
    return summary


@app.command("decode", rich_help_panel="Inspect")
def decode_command(
    input_path: Path = typer.Argument(
        ..., metavar="INPUT",
        help="pcap/pcapng capture, raw 1206-byte payload file, or tripod MCAP"),
    output: Path = typer.Option(None, "-o", "--output", help="folder for one cloud per frame, "
                                "summary.json and decode_config.yaml"),
    summary: bool = typer.Option(False, "--summary", help="print one JSON object to stdout"),
    fmt: str = typer.Option("ply", "--format", help="cloud format: ply or pcd"),
    config: Path = typer.Option(None, "--config", help="YAML file with DecodeConfig keys"),
    sensor: str = typer.Option(None, "--sensor", help="auto, VLP-16 or 'Puck Hi-Res'"),
    min_range: float = typer.Option(None, "--min-range", help="drop nearer returns [m]"),
    max_range: float = typer.Option(None, "--max-range", help="drop farther returns [m]"),
    azimuth_min: float = typer.Option(
        None, "--azimuth-min", help="keep returns from this azimuth [deg] (0 = forward, "
        "clockwise seen from above)"),
    azimuth_max: float = typer.Option(
        None, "--azimuth-max", help="keep returns up to this azimuth [deg]; the range may "
        "cross 0 (--azimuth-min 270 --azimuth-max 90 keeps the front half)"),
    calibration: str = typer.Option(None, "--calibration",
                                    help="veloview, manual, or a velodyne YAML file"),
    port: list[int] = typer.Option(None, "--port", help="keep only these UDP ports (pcap)"),
    quiet: bool = typer.Option(False, "-q", "--quiet", help="no progress bar"),
) -> None:
    """Decode Velodyne VLP-16 packets into one point cloud per rotation.

    Frames are split where the block azimuth wraps (VeloView's rule). Clouds hold x, y, z [m]
    in the sensor frame (x forward, y left, z up), intensity, ring, time_offset_ns and
    return_type.
    """
    if output is None and not summary:
        fail("give -o OUTDIR to write the frames, or --summary for the JSON summary")
    overrides = {"sensor": sensor, "min_range_m": min_range, "max_range_m": max_range,
                 "azimuth_min_deg": azimuth_min, "azimuth_max_deg": azimuth_max,
                 "calibration": calibration}
    run_decode(input_path, output, summary_only=summary, fmt=fmt, config_path=config,
               overrides=overrides, ports=port or None, progress=not (quiet or summary))
