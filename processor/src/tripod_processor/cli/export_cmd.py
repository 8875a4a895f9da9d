# SPDX-License-Identifier: BSD-3-Clause
"""``tripod export``: recordings and results in the formats other tools open.

* ``tripod export rosbag2 RECORDING -o DIR``: a rosbag2 folder (ROS 2 velodyne driver topics).
* ``tripod export e57 SOURCE -o FILE.e57``: a reconstruct folder as one scan per station with
  its pose, or any cloud as one scan.
* ``tripod export las CLOUD -o FILE.laz``: a cloud as LAS 1.4 / LAZ.
"""

from __future__ import annotations

from pathlib import Path

import typer

from . import app
from ._common import console, fail

export_app = typer.Typer(
    help="Export recordings and results: rosbag2 (ROS 2), E57 (survey scans), LAS/LAZ (maps).",
    no_args_is_help=True, add_completion=False, pretty_exceptions_enable=False)
app.add_typer(export_app, name="export", rich_help_panel="Run")


@export_app.command("rosbag2")
def export_rosbag2(
    recording: list[Path] = typer.Argument(
        ..., help="our MCAP recording (one or more files), a pcap plus --imu, or a "
                  "`tripod simulate` folder"),
    output: Path = typer.Option(..., "-o", "--output", help="rosbag2 folder to create"),
    imu: Path = typer.Option(None, "--imu", help="IMU log for a pcap"),
    calibration: Path = typer.Option(
        None, "--calibration", help="lidar-IMU mount for /tf_static (YAML/JSON with q_imu_lidar "
                                    "and lever_arm_m); default identity"),
) -> None:
    """A rosbag2 folder (metadata.yaml + MCAP): /velodyne_packets (velodyne_msgs/VelodyneScan,
    one per rotation), /imu/data (sensor_msgs/Imu orientation), /tf_static (imu -> velodyne).
    Play it with `ros2 bag play DIR`."""
    from ..export.rosbag2 import export_recording
    from ..reconstruction.inputs import RecordingError

    if output.exists() and any(output.iterdir()):
        fail(f"{output}: exists and is not empty")
    try:
        s = export_recording(recording, output, imu_log=imu, calibration=calibration)
    except RecordingError as exc:
        fail(str(exc))
    except (OSError, ValueError) as exc:
        fail(str(exc).splitlines()[0] if str(exc) else type(exc).__name__)
    console.print(f"{output}: {s.scans} scans ({s.packets} packets), {s.imu_samples} IMU "
                  f"samples, {(s.end_ns - s.start_ns) * 1e-9:.1f} s")


@export_app.command("e57")
def export_e57(
    source: Path = typer.Argument(..., help="a `tripod reconstruct` output folder, or a cloud "
                                            "(PLY/PCD)"),
    output: Path = typer.Option(..., "-o", "--output", help="E57 file to write"),
) -> None:
    """E57: from a reconstruct folder one scan per station (points in the station frame, its
    pose from stations.tum, intensity, label as `tripod:label`); from a cloud one scan with
    identity pose (fields intensity and label used when present)."""
    import numpy as np

    from ..io.e57 import NO_LABEL, E57Scan, write_e57
    from ._common import read_points

    if source.is_dir():
        from ..reconstruction.survey import scans_from_folder

        try:
            scans = scans_from_folder(source)
        except (ValueError, OSError) as exc:
            fail(str(exc))
    else:
        cloud, pts = read_points(source)
        names = cloud.dtype.names
        n = len(cloud)
        scans = [E57Scan(source.stem, pts.astype(np.float64), np.eye(4),
                         np.asarray(cloud["intensity"], np.float32) if "intensity" in names
                         else np.full(n, np.nan, np.float32),
                         np.asarray(cloud["label"]).astype(np.uint8) if "label" in names
                         else np.full(n, NO_LABEL, np.uint8))]
    output.parent.mkdir(parents=True, exist_ok=True)
    write_e57(output, scans)
    console.print(f"{output}: {len(scans)} scan(s), {sum(len(s.points) for s in scans):,} points")


@export_app.command("las")
def export_las(
    cloud: Path = typer.Argument(..., help="a cloud (PLY/PCD), e.g. map.ply or a `tripod "
                                           "segment` output"),
    output: Path = typer.Option(..., "-o", "--output", help=".las or .laz file to write"),
) -> None:
    """LAS 1.4 (.las) or LAZ (.laz): intensity, station (point_source_id = station + 1) and the
    label as ASPRS classification (floor 2, wall 6, ceiling 64, other 1) when the cloud has
    fields intensity, station, label."""
    import numpy as np

    from ..io.las import LasCloud, write_las
    from ..reconstruction.survey import asprs_codes
    from ._common import read_points

    if output.suffix.lower() not in (".las", ".laz"):
        fail(f"output must end in .las or .laz, not {output.suffix!r}")
    src, pts = read_points(cloud)
    names, n = src.dtype.names, len(src)
    las = LasCloud(pts.astype(np.float64),
                   np.asarray(src["intensity"], np.float32) if "intensity" in names
                   else np.full(n, np.nan, np.float32),
                   np.asarray(src["station"], np.int32) if "station" in names
                   else np.full(n, -1, np.int32),
                   asprs_codes(src["label"]) if "label" in names else asprs_codes(
                       np.full(n, 255, np.uint8)))
    output.parent.mkdir(parents=True, exist_ok=True)
    write_las(output, las)
    console.print(f"{output}: {n:,} points")
