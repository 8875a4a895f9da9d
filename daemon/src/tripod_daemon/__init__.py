# SPDX-License-Identifier: BSD-3-Clause
"""tripod capture daemon: receive, stamp at the read, publish over Zenoh, record MCAP. Never decodes."""

__version__ = "0.1.0"
