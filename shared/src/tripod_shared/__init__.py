# SPDX-License-Identifier: BSD-3-Clause
"""Formats shared by ``tripod-daemon`` and ``tripod``: the single source of truth.

Modules
-------
timebase   integer-nanosecond time, named clocks, ROS time conversions
velodyne   VLP-16 UDP payload layouts (data 1206 B, position 512 B), header checks
tfp        Tinkerforge TFP framing and the IMU Brick 2.0 quaternion callback
cdr        minimal little-endian CDR (ROS 2) encoder/decoder used by ``messages``
messages   message types recorded and published (CDR bytes + ros2msg definitions)
topics     MCAP topic names and Zenoh key expressions
recording  MCAP writer/reader for tripod recordings
config_io  YAML config loading with strict keys for the components' typed configs
"""

__version__ = "0.1.0"
