# SPDX-License-Identifier: BSD-3-Clause
"""Helpers shared by the subcommands: one-line errors with exit code 2, console."""

from __future__ import annotations

import sys
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
