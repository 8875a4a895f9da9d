# SPDX-License-Identifier: BSD-3-Clause
"""A tripod recording as a rosbag2 folder that drives the stock ROS 2 velodyne tools.

Topics (frames as the ROS velodyne driver and REP 145 name them):

==================  =================================  ========================================
topic               type                               content
==================  =================================  ========================================
/velodyne_packets   velodyne_msgs/msg/VelodyneScan     one rotation per message: the data
                                                       packets grouped at the azimuth wrap, each
                                                       VelodynePacket the host receive stamp and
                                                       the 1206 bytes verbatim; frame
                                                       ``velodyne``; header stamp the last
                                                       packet's (as the driver stamps it)
/imu/data           sensor_msgs/msg/Imu                every IMU sample: orientation
                                                       q_world_imu (rates and accelerations
                                                       absent: covariance[0] = -1); frame ``imu``
/tf_static          tf2_msgs/msg/TFMessage             the mount imu -> velodyne (R_imu_lidar,
                                                       lever arm [m]); latched
==================  =================================  ========================================

Stamps and ``log_time`` are host_realtime [ns] as recorded (a scan is logged at its last
packet). ``ros2 bag play DIR`` then feeds ``velodyne_pointcloud``'s transform node.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation
from tripod_shared import ros2_msgs as r2
from tripod_shared import velodyne as vl

from ..io.rosbag2 import Rosbag2Writer, qos_profile

TOPIC_SCANS = "/velodyne_packets"
TOPIC_IMU = "/imu/data"
TOPIC_TF_STATIC = "/tf_static"
FRAME_LIDAR = "velodyne"
FRAME_IMU = "imu"


@dataclass
class Rosbag2Summary:
    scans: int
    packets: int
    imu_samples: int
    start_ns: int
    end_ns: int


def packet_azimuth_cdeg(payload: np.ndarray) -> np.ndarray:
    """(P,) azimuth of each packet's first block [0.01 deg] of (P, 1206) uint8 packets."""
    return payload[:, 2].astype(np.int32) | (payload[:, 3].astype(np.int32) << 8)


def rotation_starts(payload: np.ndarray) -> np.ndarray:
    """Indices where a new rotation starts (always 0): where the first block's azimuth wraps
    (drops below the previous packet's), as the driver cuts scans at a full turn."""
    az = packet_azimuth_cdeg(payload)
    wraps = np.flatnonzero(np.diff(az) < 0) + 1
    return np.concatenate([[0], wraps]).astype(np.int64) if len(az) else np.zeros(0, np.int64)


def write_rosbag2(folder: str | os.PathLike, host_ns: np.ndarray, payload: np.ndarray,
                  imu_host_ns: np.ndarray | None, imu_q_wxyz: np.ndarray | None,
                  R_imu_lidar: np.ndarray | None = None, lever_arm_m=None) -> Rosbag2Summary:
    """Write the rosbag2 folder of the module docstring.

    Parameters
    ----------
    host_ns : (P,) int64, host receive time of each data packet
    payload : (P, 1206) uint8, the data packets in recording order
    imu_host_ns : (K,) int64 or None; imu_q_wxyz : (K, 4) q_world_imu, w first
    R_imu_lidar : (3, 3) mount rotation (identity if None); lever_arm_m : (3,) [m]
    """
    host_ns = np.asarray(host_ns, dtype=np.int64)
    starts = rotation_starts(payload)
    ends = np.append(starts[1:], len(payload))
    R = np.eye(3) if R_imu_lidar is None else np.asarray(R_imu_lidar, dtype=np.float64)
    lever = np.zeros(3) if lever_arm_m is None else np.asarray(lever_arm_m, dtype=np.float64)
    qx, qy, qz, qw = Rotation.from_matrix(R).as_quat()
    t_first = int(host_ns[0]) if len(host_ns) else 0
    if imu_host_ns is not None and len(imu_host_ns):
        t_first = min(t_first, int(imu_host_ns[0])) if len(host_ns) else int(imu_host_ns[0])
    n_imu = 0
    with Rosbag2Writer(folder, library="tripod export rosbag2") as bag:
        bag.add_topic(TOPIC_TF_STATIC, r2.TF_MESSAGE_TYPE, r2.TF_MESSAGE_MSGDEF,
                      qos_profile("transient_local"))
        bag.add_topic(TOPIC_SCANS, r2.VELODYNE_SCAN_TYPE, r2.VELODYNE_SCAN_MSGDEF)
        bag.add_topic(TOPIC_IMU, r2.IMU_TYPE, r2.IMU_MSGDEF)
        bag.write(TOPIC_TF_STATIC, t_first, r2.encode_tf_message(
            [(t_first, FRAME_IMU, FRAME_LIDAR, tuple(lever), (qw, qx, qy, qz))]))
        # merge scans and IMU samples in log-time order (a scan is logged at its last packet)
        scan_t = host_ns[ends - 1] if len(starts) else np.zeros(0, np.int64)
        imu_t = (np.asarray(imu_host_ns, dtype=np.int64) if imu_host_ns is not None
                 else np.zeros(0, np.int64))
        i = j = 0
        while i < len(starts) or j < len(imu_t):
            if j >= len(imu_t) or (i < len(starts) and scan_t[i] <= imu_t[j]):
                a, b = int(starts[i]), int(ends[i])
                stamps = host_ns[a:b].tolist()
                pk = [(t, payload[k].tobytes()) for t, k in zip(stamps, range(a, b))]
                bag.write(TOPIC_SCANS, int(scan_t[i]),
                          r2.encode_velodyne_scan(stamps[-1], FRAME_LIDAR, pk))
                i += 1
            else:
                t = int(imu_t[j])
                bag.write(TOPIC_IMU, t, r2.encode_imu_orientation(t, FRAME_IMU, imu_q_wxyz[j]))
                n_imu += 1
                j += 1
    t_end = max(int(host_ns[-1]) if len(host_ns) else 0, int(imu_t[-1]) if len(imu_t) else 0)
    return Rosbag2Summary(len(starts), len(payload), n_imu, t_first, t_end)


def export_recording(recording, folder: str | os.PathLike, *, imu_log=None, calibration=None
                     ) -> Rosbag2Summary:
    """Read a recording (our MCAP files, pcap + IMU log, or a simulate folder) through the
    processor's reader and write it as a rosbag2 folder. ``calibration``: an extrinsic file
    (:func:`tripod_processor.reconstruction.placement.load_extrinsic_file`) for /tf_static.

    Raises
    ------
    RecordingError
        Unreadable input (one-line message).
    """
    from ..reconstruction.inputs import read_recording
    from ..reconstruction.placement import Extrinsic, load_extrinsic_file

    rec = read_recording(recording, imu_log)
    ext = Extrinsic.identity()
    if calibration is not None:
        q, lever = load_extrinsic_file(calibration)
        ext = Extrinsic.from_config(q, lever)
    lid = rec.lidar
    imu_t = rec.imu.host_ns if rec.imu is not None else None
    imu_q = rec.imu.q_wxyz if rec.imu is not None else None
    assert lid.payload.shape[1] == vl.DATA_PACKET_SIZE
    return write_rosbag2(folder, lid.host_ns, lid.payload, imu_t, imu_q, ext.R_imu_lidar,
                         ext.lever_arm_m)
