# SPDX-License-Identifier: BSD-3-Clause
"""Digital twin of the tripod: simulated VLP-16 + IMU captures with ground truth.

``simulate(SimConfig(...), out_dir)`` writes a capture directory; the pieces (scenes,
trajectory, lidar and IMU models) are usable on their own.
"""

from .capture import SimSummary, build_rig, build_scene, simulate
from .config import ImuConfig, LidarConfig, MotionConfig, SimConfig
from .scenes import CLASS_NAMES, NO_RETURN, SCENE_NAMES, Scene, load_scene_file, make_scene

__all__ = ["CLASS_NAMES", "ImuConfig", "LidarConfig", "MotionConfig", "NO_RETURN", "SCENE_NAMES",
           "Scene", "SimConfig", "SimSummary", "build_rig", "build_scene", "load_scene_file",
           "make_scene", "simulate"]
