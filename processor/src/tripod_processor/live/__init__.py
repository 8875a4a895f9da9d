# SPDX-License-Identifier: BSD-3-Clause
"""``tripod live``: the daemon's Zenoh stream (``stream``) shown through Foxglove (``view``)."""

from .stream import LiveStream, Rotation, RotationCutter, open_session
from .view import LiveConfig, LiveView

__all__ = ["LiveConfig", "LiveStream", "LiveView", "Rotation", "RotationCutter", "open_session"]
