# SPDX-License-Identifier: BSD-3-Clause
"""Decoding: lidar packets → frames of points, with a report of what the capture held.

:mod:`.decoder` is the streaming frame decoder (packets from :mod:`tripod_processor.io`, one
frame per revolution, gaps, position packets); :mod:`.batch` is the interface of the batch
decoder it calls for the points, :mod:`.native` the C++ core's batch VLP-16 decoder (the
default); :mod:`.timed` decodes packet ranges into points with their own lidar time
(the reconstruction's decoding); :mod:`.scanline` smooths their ranges along each laser's scan
line (the fragments' points).
"""

from .batch import BatchDecoder, BatchDecoderFactory
from .decoder import (DecodeConfig, DecodeError, DecodeReport, DecodeRun, Frame, FrameDecoder,
                      Gap, PositionReport, decode_file, identify_sensor, to_veloview_xyz)
from .native import POINT_DTYPE, CalibrationError, NativeVlp16Decoder

__all__ = ["BatchDecoder", "BatchDecoderFactory", "CalibrationError", "DecodeConfig",
           "DecodeError", "DecodeReport", "DecodeRun", "Frame", "FrameDecoder", "Gap",
           "NativeVlp16Decoder", "POINT_DTYPE",
           "PositionReport", "decode_file", "identify_sensor", "to_veloview_xyz"]
