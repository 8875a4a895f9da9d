# SPDX-License-Identifier: BSD-3-Clause
"""Reading the user's input files for the subcommands (a bad file: one line, exit code 2)."""

from __future__ import annotations

from pathlib import Path

from ._common import fail


def read_points(path: Path):
    """The cloud at ``path`` (structured array) and its (N, 3) float32 xyz; a bad file is one
    line and exit code 2."""
    from ..io.clouds import CloudFormatError, read_cloud, xyz

    try:
        cloud = read_cloud(path)
    except FileNotFoundError:
        fail(f"no such file: {path}")
    except (CloudFormatError, ValueError, OSError) as exc:
        fail(f"{path}: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}")
    if cloud.dtype.names is None or not {"x", "y", "z"} <= set(cloud.dtype.names):
        fail(f"{path}: the cloud has no x, y, z fields")
    return cloud, xyz(cloud, dtype="float32")
