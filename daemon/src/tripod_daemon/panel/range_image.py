# SPDX-License-Identifier: BSD-3-Clause
"""A 16-row range image of one rotation, from raw VLP-16 data packets, for the panel's picture.

Only the panel does this, from a few hundred packets a second at most: the daemon never decodes.
It is a picture, not a measurement: each data block's azimuth is used for both of its firing
sequences (at most 0.2 deg off), and in dual-return mode the later block of a pair overwrites
the earlier one in its cell.
"""

from __future__ import annotations

import numpy as np

from tripod_shared.velodyne import (
    AZIMUTH_UNIT_DEG,
    BLOCK_SIZE,
    BLOCKS_PER_PACKET,
    DATA_PACKET_SIZE,
    DISTANCE_UNIT_M,
    LASERS,
)

#: VLP-16 laser id -> elevation [deg] (interleaved: -15, +1, -13, +3, ...)
VLP16_ELEVATION_DEG = np.array([-15, 1, -13, 3, -11, 5, -9, 7, -7, 9, -5, 11, -3, 13, -1, 15])
#: laser id -> image row (row 0: +15 deg, the top)
ROW_OF_LASER = ((15 - VLP16_ELEVATION_DEG) // 2).astype(np.intp)

COLUMNS = 360  # one column per degree of azimuth
NEAR_M, FAR_M = 0.5, 100.0  # the grey scale's ends [m]


def azimuths_cdeg(packets: np.ndarray) -> np.ndarray:
    """Azimuth of each data block.

    Parameters
    ----------
    packets : (N, 1206) uint8

    Returns
    -------
    (N, 12) uint16, [0.01 deg]
    """
    b = packets[:, : BLOCKS_PER_PACKET * BLOCK_SIZE].reshape(-1, BLOCKS_PER_PACKET, BLOCK_SIZE)
    return b[:, :, 2].astype(np.uint16) | (b[:, :, 3].astype(np.uint16) << 8)


def one_rotation(packets: np.ndarray) -> np.ndarray:
    """The packets of the last complete rotation (between the last two azimuth wraps of the
    first block), or all of them when there is no complete rotation."""
    az = azimuths_cdeg(packets)[:, 0].astype(np.int32)
    wraps = np.flatnonzero(np.diff(az) < -18000) + 1  # index of the first packet after a wrap
    if len(wraps) >= 2:
        return packets[wraps[-2] : wraps[-1]]
    return packets


def range_image(packets: np.ndarray) -> np.ndarray:
    """Distances binned by laser and azimuth degree.

    Parameters
    ----------
    packets : (N, 1206) uint8
        Raw data packets; blocks whose flag is not FF EE are ignored.

    Returns
    -------
    (16, 360) float32, [m]; 0 where no return. Row 0 is the top laser (+15 deg), column k
    covers azimuth [k, k+1) deg.
    """
    img = np.zeros((LASERS, COLUMNS), np.float32)
    if packets.size == 0:
        return img
    n = packets.shape[0]
    blocks = packets[:, : BLOCKS_PER_PACKET * BLOCK_SIZE].reshape(n, BLOCKS_PER_PACKET, BLOCK_SIZE)
    valid = (blocks[:, :, 0] == 0xFF) & (blocks[:, :, 1] == 0xEE)  # (N, 12)
    az = azimuths_cdeg(packets)
    col = (az.astype(np.int32) * AZIMUTH_UNIT_DEG).astype(np.intp) % COLUMNS  # (N, 12)
    ch = blocks[:, :, 4:].reshape(n, BLOCKS_PER_PACKET, 2 * LASERS, 3)
    dist = (ch[..., 0].astype(np.uint16) | (ch[..., 1].astype(np.uint16) << 8)) * np.float32(
        DISTANCE_UNIT_M)  # (N, 12, 32) [m]
    rows = np.tile(ROW_OF_LASER, 2)  # channel 0..31 -> row (two firing sequences per block)
    v = valid[:, :, None].repeat(2 * LASERS, axis=2)
    r = np.broadcast_to(rows, dist.shape)[v]
    c = np.broadcast_to(col[:, :, None], dist.shape)[v]
    img[r, c] = dist[v]
    return img


def to_grey(img_m: np.ndarray) -> np.ndarray:
    """(16, 360) distances [m] -> uint8: 0 no return, 1 (near) .. 255 (far), log scale."""
    out = np.zeros(img_m.shape, np.uint8)
    hit = img_m > 0
    t = np.log(np.clip(img_m[hit], NEAR_M, FAR_M) / NEAR_M) / np.log(FAR_M / NEAR_M)
    out[hit] = (1 + t * 254).astype(np.uint8)
    return out


def from_payloads(payloads: list[bytes]) -> np.ndarray:
    """(N, 1206) uint8 of the payloads that are full data packets."""
    good = [p for p in payloads if len(p) == DATA_PACKET_SIZE]
    if not good:
        return np.zeros((0, DATA_PACKET_SIZE), np.uint8)
    return np.frombuffer(b"".join(good), np.uint8).reshape(-1, DATA_PACKET_SIZE)
