# SPDX-License-Identifier: BSD-3-Clause
"""Registration: clouds → relative poses (:mod:`.pairwise`: local ICP/GICP and global
FPFH + RANSAC on the C++ core) and poses → one consistent set (:mod:`.pose_graph`)."""

from .pairwise import (LOSSES, METHODS, GlobalResult, PreparedCloud, RegistrationResult,
                       default_schedule, prepare, register, register_global)

__all__ = ["GlobalResult", "LOSSES", "METHODS", "PreparedCloud", "RegistrationResult",
           "default_schedule", "prepare", "register", "register_global"]
