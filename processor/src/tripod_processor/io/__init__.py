# SPDX-License-Identifier: BSD-3-Clause
"""Input and output of recordings and clouds.

:mod:`.events` (the one reader API: every recording as typed, time-ordered events; the
data/position rule), :mod:`.pcap` (pcap/pcapng UDP datagrams), :mod:`.packets` (the decoder's
batched lidar packet sources: pcap, MCAP, raw payloads), :mod:`.imu_log` (the host's IMU byte
log), :mod:`.clouds` (PLY/PCD point clouds), :mod:`.replay` (a recording played back to sockets
and serial ports in real time).
"""
