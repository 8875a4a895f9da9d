# SPDX-License-Identifier: BSD-3-Clause
"""Fragments: every packet of a station placed by the IMU into one dense, de-skewed cloud in the
lidar frame at the station's middle time."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..decode.timed import decode_xyz_time
from ..preprocess import lookup_keys, voxel_downsample, voxel_keys, voxel_sums
from .inputs import LidarPackets
from .placement import (Extrinsic, ImuOrientation, place_points, pose_world_lidar,
                        station_anchor_rotation)
from .stations import Station


@dataclass
class Fragment:
    """A station's cloud and its IMU attitude.

    Attributes
    ----------
    station : Station
    points : (N, 3) float32 [m], lidar frame at ``station.mid_ns``, voxel-filtered
    R_world_lidar : (3, 3) IMU attitude of that frame (yaw from the drifting IMU; fitted over
        the station's samples, :func:`~.placement.station_anchor_rotation`, unless asked not to)
    raw_points : int, points placed before the voxel filter
    intensity : (N,) float32 or None, mean reflectivity (0–255) of each point's voxel (NaN: a
        centroid on a voxel face that missed its voxel); built only when asked (survey outputs)
    anchor : how the anchor attitude came ("slerped": not fitted; else the fit's ``outcome``,
        :func:`~.placement.station_anchor_rotation`: "fit", "fit, pan slerped", or why the
        slerped one was kept, e.g. "off by 0.41°")
    """

    station: Station
    points: np.ndarray
    R_world_lidar: np.ndarray
    raw_points: int
    intensity: np.ndarray | None = None
    anchor: str = "slerped"

    @property
    def tilt_fitted(self) -> bool:
        """Was the anchor's tilt averaged over the station's IMU samples (not one slerped
        sample)? The pan angle may still be slerped ("fit, pan slerped")."""
        return self.anchor in ("fit", "fit, pan slerped")

    @property
    def up_in_lidar(self) -> np.ndarray:
        """The world's +z seen in the fragment's frame (the gravity prior)."""
        return self.R_world_lidar.T @ np.array([0.0, 0.0, 1.0])


def build_fragment(lidar: LidarPackets, station: Station, orient: ImuOrientation, ext: Extrinsic,
                   voxel_m: float, min_range: float, max_range: float,
                   num_threads: int = 0, chunk: int = 1000, max_points: int = 6_000_000,
                   with_intensity: bool = False, anchor_fit: bool = True,
                   anchor_max_deviation_deg: float = 0.3, denoise_firings: int = 0,
                   denoise_fit: str = "mean", denoise_max_step_m: float = 0.15) -> Fragment:
    """Decode, place and voxel-filter one station's packets.

    Decodes and places the station in chunks of ``chunk`` packets, then voxel-filters all its
    placed points at once (a 10 s station is ~3 M points, 36 MB); a long station is bounded by
    filtering what has gathered at half the voxel whenever it passes ``max_points``.
    ``with_intensity``: also the mean intensity of each output voxel (from every placed point;
    per-voxel sums are kept per chunk and merged at the end). ``anchor_fit``: the fragment's
    frame is the lidar's at the IMU attitude fitted over the station's samples
    (:func:`~.placement.station_anchor_rotation`) rather than slerped at its middle time, whose
    white noise would turn the whole station; the points are placed at the slerped attitude and
    moved rigidly onto the fitted one. A fit more than ``anchor_max_deviation_deg`` from the
    slerped attitude is not used (``Fragment.anchor`` says why). ``denoise_firings`` > 0: the
    ranges smoothed along each laser's scan line over that many firings either side with
    ``denoise_fit``, leaving out neighbours farther than ``denoise_max_step_m`` [m] in range,
    before placement (:mod:`..decode.scanline`).
    """
    parts, raw = [], 0
    key_parts = []
    gathered, limit = 0, max_points
    for a in range(station.packet_start, station.packet_stop, chunk):
        b = min(station.packet_stop, a + chunk)
        xyz, t_ns, inten = decode_xyz_time(lidar.payload, lidar.lidar_ns, a, b,
                                           min_range=min_range, max_range=max_range,
                                           num_threads=num_threads, with_intensity=with_intensity,
                                           denoise_firings=denoise_firings,
                                           denoise_fit=denoise_fit,
                                           denoise_max_step_m=denoise_max_step_m)
        if len(xyz) == 0:
            continue
        raw += len(xyz)
        placed = place_points(xyz, t_ns, orient, ext, station.mid_ns, num_threads)
        parts.append(placed)
        if with_intensity:  # per-chunk sums: a chunk revisits its voxels every rotation
            key_parts.append(voxel_sums(voxel_keys(placed, voxel_m), inten))
        gathered += len(placed)
        if gathered > limit:
            parts = [voxel_downsample(np.concatenate(parts), voxel_m * 0.5, num_threads)]
            gathered = len(parts[0])
            limit = gathered + max_points
    if parts:
        down = voxel_downsample(np.concatenate(parts), voxel_m, num_threads)
    else:
        down = np.zeros((0, 3), np.float32)
    T = pose_world_lidar(orient, ext, np.array([station.mid_ns]))[0]
    R = T[:3, :3]
    intensity = None
    if with_intensity:
        if key_parts:
            uk, s, c = voxel_sums(*(np.concatenate(a) for a in zip(*key_parts)))
            intensity = lookup_keys(uk, (s / c).astype(np.float32), voxel_keys(down, voxel_m),
                                    np.float32(np.nan))
        else:
            intensity = np.zeros(0, np.float32)
    how = "slerped"
    if anchor_fit:
        # x_fit = R_fitᵀ·(R_slerp·x + R_wi·ℓ − R_wi_fit·ℓ): the frame the fitted attitude gives
        info: dict = {}
        R_wi = station_anchor_rotation(orient, station.start_ns, station.end_ns, station.mid_ns,
                                       max_deviation_deg=anchor_max_deviation_deg, info=info)
        how = info["outcome"]
        R_fit = R_wi @ ext.R_imu_lidar
        C = R_fit.T @ R
        o = R_fit.T @ (T[:3, 3] - R_wi @ ext.lever_arm_m)
        down = (down.astype(np.float64) @ C.T + o).astype(np.float32)
        R = R_fit
    return Fragment(station, down, R, raw, intensity, how)
