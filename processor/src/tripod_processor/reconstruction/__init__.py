# SPDX-License-Identifier: BSD-3-Clause
"""Reconstruction: a tripod recording in, a registered indoor model out (``tripod reconstruct``).

Modules, in data-flow order: ``inputs`` (recording → packets, IMU, marks), ``placement`` (clocks,
slerp, extrinsic, de-skew), ``stations`` (segmentation), ``calibration`` (IMU time offset),
``fragments``, ``odometry`` (pairwise registration), ``slam`` (loops + pose graph), ``outputs``,
``report``, ``evaluation`` (against ground truth), ``pipeline`` (orchestration).
"""

from .config import ReconstructConfig
from .inputs import RecordingError

__all__ = ["ReconstructConfig", "RecordingError", "reconstruct"]


def reconstruct(*args, **kwargs):
    """See :func:`tripod_processor.reconstruction.pipeline.reconstruct`."""
    from .pipeline import reconstruct as _run

    return _run(*args, **kwargs)
