# SPDX-License-Identifier: BSD-3-Clause
"""The VLP-16 beam model every simulator of the project builds on.

One table of the 16 lasers (elevation, vertical offset, ring; VLP-16 manual table 9-1) and one
beam direction formula. Users: :mod:`.lidar` (the packet-level digital twin), :mod:`.rooms`
(the synthetic rooms of the segmenter and the heightmap benches) and
:mod:`tripod_processor.compression.synthetic` (the codec's training and test clouds). They
differ only in what they cast the beams at and in their sampling (head motion, azimuth step,
noise), each documented where it is defined.
"""

from __future__ import annotations

import numpy as np

#: laser elevation [deg] by laser id (firing order), VLP-16 manual table 9-1
LASER_ELEVATION_DEG = np.array([-15, 1, -13, 3, -11, 5, -9, 7, -7, 9, -5, 11, -3, 13, -1, 15],
                               dtype=np.float64)
#: elevation [deg] by ring (ascending: the decoder's ``ring`` field)
RING_ELEVATION_DEG = np.sort(LASER_ELEVATION_DEG)
#: vertical offset of each laser's origin along the lidar z axis [m] (VLP-16 manual table 9-1,
#: "vertical correction"; velodyne-decoder applies it: point = range * direction + (0, 0, offset))
LASER_VERT_OFFSET_M = np.array([11.2, -0.7, 9.7, -2.2, 8.1, -3.7, 6.6, -5.1, 5.1, -6.6, 3.7, -8.1,
                                2.2, -9.7, 0.7, -11.2], dtype=np.float64) * 1e-3
#: ring (rank of elevation, the decoder's ``ring`` field) of each laser id
LASER_RING = np.argsort(np.argsort(LASER_ELEVATION_DEG)).astype(np.uint8)
#: azimuth between firings at 600 rpm [deg]
AZIMUTH_STEP_DEG = 0.2


def directions(azimuth_rad, elevation_rad) -> np.ndarray:
    """Unit beam directions (..., 3) in the sensor frame, azimuth counter-clockwise from x
    (math convention), for broadcastable azimuth and elevation arrays [rad]."""
    return np.stack([np.cos(elevation_rad) * np.cos(azimuth_rad),
                     np.cos(elevation_rad) * np.sin(azimuth_rad),
                     np.broadcast_to(np.sin(elevation_rad), np.broadcast(azimuth_rad,
                                                                         elevation_rad).shape)],
                    -1)


def firing_directions(azimuth_deg: np.ndarray) -> np.ndarray:
    """Unit directions (..., 16, 3) in the lidar frame for azimuths (..., 16) [deg], Velodyne's
    convention (azimuth clockwise seen from above, so y = -sin): the lasers in firing order."""
    az = np.radians(azimuth_deg)
    el = np.radians(LASER_ELEVATION_DEG)
    ce = np.cos(el)
    return np.stack([ce * np.cos(az), -ce * np.sin(az), np.broadcast_to(np.sin(el), az.shape)],
                    axis=-1)
