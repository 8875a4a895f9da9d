# SPDX-License-Identifier: BSD-3-Clause
"""The interface of a batch VLP-16 decoder, as :class:`~.decoder.FrameDecoder` uses it.

:class:`~.decoder.FrameDecoder` groups packets, tells the sensor apart, splits rotations and
stamps frames; the points themselves come from a *batch decoder*: a chunk of packets in, the
chunk's points out, in one call. The product's is :class:`~.native.NativeVlp16Decoder` (the
default). Another one (the tests' velodyne-decoder oracle, ``tests/processor/vd_oracle.py``) is
handed to the frame decoder as a :class:`BatchDecoderFactory`::

    FrameDecoder(config, batch_decoder=MyDecoder)

A factory is called once per stream, when the sensor is known; it raises ``ValueError`` (with a
one-line message) for settings it cannot honour, which the frame decoder reports as a
:class:`~.decoder.DecodeError`.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
import velodyne_decoder as vd

from .native import NativeBatch


class BatchDecoder(Protocol):
    """Decodes chunks of one stream's data packets, in stream order (state such as the return
    mode carries over from chunk to chunk)."""

    def decode(self, packets: np.ndarray, stamps_ns: np.ndarray,
               seg_first_block: np.ndarray | None = None,
               seg_ref_ns: np.ndarray | None = None) -> NativeBatch:
        """Points of a chunk, as :meth:`.native.NativeVlp16Decoder.decode` gives them.

        Parameters
        ----------
        packets : np.ndarray, shape (N, 1206), uint8
            Data packets (headers already checked by the frame decoder).
        stamps_ns : np.ndarray, shape (N,), int64
            Lidar clock [ns] of each packet.
        seg_first_block, seg_ref_ns : np.ndarray, shape (S,), int64
            The chunk's segments (frames): flat block index (packet * 12 + block) where each
            starts, sorted, and its reference time [ns].

        Returns
        -------
        NativeBatch
            ``points`` (:data:`.native.POINT_DTYPE`, in packet, block, firing order, with
            ``time_offset_ns`` = firing time - the point's segment reference),
            ``block_first_point`` ((N * 12 + 1,): first point of each block; a dual-return
            block pair's points belong to its even block) and ``time_offset_clipped``; the
            frame decoder reads only these three.
        """
        ...


class BatchDecoderFactory(Protocol):
    """Makes the batch decoder of one stream (:class:`.native.NativeVlp16Decoder` is one)."""

    def __call__(self, calibration: vd.Calibration | None, *, model: vd.Model,
                 min_range_m: float, max_range_m: float, min_angle_deg: float,
                 max_angle_deg: float, num_threads: int) -> BatchDecoder:
        """``calibration`` None: the built-in table of ``model``; angles [deg] from min
        clockwise to max (across 0 when min > max); ``num_threads`` 0 = all cores."""
        ...


__all__ = ["BatchDecoder", "BatchDecoderFactory"]
