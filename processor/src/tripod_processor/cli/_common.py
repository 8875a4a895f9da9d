# SPDX-License-Identifier: BSD-3-Clause
"""Helpers shared by the subcommands: one-line errors with exit code 2, console, cloud input."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import NoReturn

import typer
from rich.console import Console

console = Console(stderr=True)

EXIT_BAD_INPUT = 2


class InputError(Exception):
    """Bad user input (missing file, unreadable data): reported as one line, exit code 2."""


def fail(message: str, code: int = EXIT_BAD_INPUT) -> NoReturn:
    """Print ``tripod: error: <message>`` on one line to stderr and exit with ``code``."""
    print(f"tripod: error: {message}", file=sys.stderr)
    raise typer.Exit(code)


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
