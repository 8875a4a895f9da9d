# SPDX-License-Identifier: BSD-3-Clause
"""LAS 1.4 / LAZ point clouds (laspy; lazrs compresses LAZ): the map as surveyors exchange it.

Layout written (point data record format 6, LAS 1.4):

* x, y, z: metres in the file's local frame (tripod's ``map`` frame: z up along gravity),
  stored as int32 with scale 0.0001 m (0.1 mm) and an offset at the cloud's minimum corner
  (quantisation ±0.05 mm). No CRS record: the frame is local, not georeferenced.
* intensity: uint16, the sensor's 0–255 reflectivity scaled by 256 as the LAS spec asks
  ("normalised to 16 bits"); read back ``intensity / 256``.
* point_source_id: the station the point was seen from, **station index + 1** (LAS reserves 0
  for "no source"; 0 here: unknown).
* classification: ASPRS codes given by the caller (see
  :data:`tripod_processor.reconstruction.survey.ASPRS_CLASS`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

SCALE_M = 1e-4  # [m] per LAS coordinate unit
INTENSITY_SCALE = 256  # 8-bit sensor reflectivity -> 16-bit LAS intensity


@dataclass
class LasCloud:
    """A map cloud with the attributes tripod writes to LAS.

    Attributes
    ----------
    points : (N, 3) float64 [m], z up
    intensity : (N,) float32, sensor reflectivity 0–255 (NaN: unknown, written as 0)
    station : (N,) int32, station index (-1: unknown)
    classification : (N,) uint8, ASPRS classification code
    """

    points: np.ndarray
    intensity: np.ndarray
    station: np.ndarray
    classification: np.ndarray


def write_las(path: str | os.PathLike, cloud: LasCloud) -> None:
    """Write ``cloud`` as LAS 1.4 (``.las``) or LAZ (``.laz``, lazrs backend)."""
    import laspy

    path = os.fspath(path)
    pts = np.asarray(cloud.points, dtype=np.float64).reshape(-1, 3)
    n = len(pts)
    hdr = laspy.LasHeader(point_format=6, version="1.4")
    hdr.scales = np.array([SCALE_M] * 3)
    hdr.offsets = np.floor(pts.min(axis=0)) if n else np.zeros(3)
    hdr.generating_software = "tripod"
    hdr.system_identifier = "tripod map (local frame, m, z up)"
    las = laspy.LasData(hdr)
    las.x, las.y, las.z = pts[:, 0], pts[:, 1], pts[:, 2]
    inten = np.nan_to_num(np.asarray(cloud.intensity, dtype=np.float64), nan=0.0)
    las.intensity = np.clip(np.round(inten * INTENSITY_SCALE), 0, 65535).astype(np.uint16)
    st = np.asarray(cloud.station, dtype=np.int64)
    las.point_source_id = np.clip(st + 1, 0, 65535).astype(np.uint16)
    las.classification = np.asarray(cloud.classification, dtype=np.uint8)
    las.return_number = np.ones(n, np.uint8)
    las.number_of_returns = np.ones(n, np.uint8)
    if path.lower().endswith(".laz"):
        las.write(path, laz_backend=laspy.LazBackend.Lazrs)
    else:
        las.write(path)


def read_las(path: str | os.PathLike) -> LasCloud:
    """Read a LAS/LAZ file written by :func:`write_las` (or any LAS with these fields)."""
    import laspy

    las = laspy.read(os.fspath(path))
    pts = np.stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)], axis=1)
    return LasCloud(pts, np.asarray(las.intensity, dtype=np.float32) / INTENSITY_SCALE,
                    np.asarray(las.point_source_id, dtype=np.int32) - 1,
                    np.asarray(las.classification, dtype=np.uint8))
