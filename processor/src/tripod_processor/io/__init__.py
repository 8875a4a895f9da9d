# SPDX-License-Identifier: BSD-3-Clause
"""Input and output of recordings and clouds.

:mod:`.pcap` (pcap/pcapng UDP datagrams), :mod:`.packets` (lidar packet sources: pcap, MCAP,
raw payloads), :mod:`.imu_log` (the host's IMU byte log), :mod:`.clouds` (PLY/PCD point
clouds), :mod:`.replay` (a recording played back to sockets and serial ports in real time).
"""
