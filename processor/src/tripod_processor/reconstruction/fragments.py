# SPDX-License-Identifier: BSD-3-Clause
"""Fragments: every packet of a station placed by the IMU into one dense, de-skewed cloud in the
lidar frame at the station's middle time."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..decode.timed import decode_timed_points
from ..preprocess import voxel_downsample
from .inputs import LidarPackets
from .placement import Extrinsic, ImuOrientation, place_points, pose_world_lidar
from .stations import Station


@dataclass
class Fragment:
    """A station's cloud and its IMU attitude.

    Attributes
    ----------
    station : Station
    points : (N, 3) float32 [m], lidar frame at ``station.mid_ns``, voxel-filtered
    R_world_lidar : (3, 3) IMU attitude of that frame (yaw from the drifting IMU)
    raw_points : int, points placed before the voxel filter
    """

    station: Station
    points: np.ndarray
    R_world_lidar: np.ndarray
    raw_points: int

    @property
    def up_in_lidar(self) -> np.ndarray:
        """The world's +z seen in the fragment's frame (the gravity prior)."""
        return self.R_world_lidar.T @ np.array([0.0, 0.0, 1.0])


def build_fragment(lidar: LidarPackets, station: Station, orient: ImuOrientation, ext: Extrinsic,
                   voxel_m: float, min_range: float, max_range: float,
                   num_threads: int = 0, chunk: int = 1000, max_points: int = 6_000_000
                   ) -> Fragment:
    """Decode, place and voxel-filter one station's packets.

    Decodes and places the station in chunks of ``chunk`` packets, then voxel-filters all its
    placed points at once (a 10 s station is ~3 M points, 36 MB); a long station is bounded by
    filtering what has gathered at half the voxel whenever it passes ``max_points``.
    """
    parts, raw = [], 0
    gathered, limit = 0, max_points
    for a in range(station.packet_start, station.packet_stop, chunk):
        b = min(station.packet_stop, a + chunk)
        pts = decode_timed_points(lidar.payload, lidar.lidar_ns, a, b, min_range=min_range,
                                  max_range=max_range, num_threads=num_threads)
        if len(pts) == 0:
            continue
        raw += len(pts)
        xyz = np.stack([pts["x"], pts["y"], pts["z"]], axis=1)
        placed = place_points(xyz, pts["time_ns"], orient, ext, station.mid_ns, num_threads)
        parts.append(placed)
        gathered += len(placed)
        if gathered > limit:
            parts = [voxel_downsample(np.concatenate(parts), voxel_m * 0.5, num_threads)]
            gathered = len(parts[0])
            limit = gathered + max_points
    if parts:
        down = voxel_downsample(np.concatenate(parts), voxel_m, num_threads)
    else:
        down = np.zeros((0, 3), np.float32)
    R = pose_world_lidar(orient, ext, np.array([station.mid_ns]))[0, :3, :3]
    return Fragment(station, down, R, raw)
