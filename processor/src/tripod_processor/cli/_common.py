# SPDX-License-Identifier: BSD-3-Clause
"""Helpers shared by the subcommands: one-line errors (exit code 2 for bad input, 1 for a job
that ran and failed), console."""

from __future__ import annotations

import sys
from typing import NoReturn

import typer
from rich.console import Console

console = Console(stderr=True)

EXIT_BAD_INPUT = 2
#: the input was read, but the job did not succeed (e.g. a registration found no alignment)
EXIT_FAILED = 1


class InputError(Exception):
    """Bad user input (missing file, unreadable data): reported as one line, exit code 2."""


def fail(message: str, code: int = EXIT_BAD_INPUT) -> NoReturn:
    """Print ``tripod: error: <message>`` on one line to stderr and exit with ``code``."""
    print(f"tripod: error: {message}", file=sys.stderr)
    raise typer.Exit(code)


def unit_hint(src, tgt) -> str:
    """A hint when the two clouds' sizes differ by far more than a partial overlap explains
    (a cloud in millimetres beside one in metres); '' otherwise."""
    import numpy as np

    def size(p) -> float:
        p = p[np.isfinite(p).all(axis=1)]
        if not len(p):
            return 0.0
        return float(np.linalg.norm(np.percentile(p, 95, axis=0) - np.percentile(p, 5, axis=0)))

    s, t = size(src), size(tgt)
    if s > 0 and t > 0 and max(s / t, t / s) > 20:
        return (f" (the source spans {s:.3g}, the target {t:.3g} units: are both in metres? "
                "millimetres give a ratio near 1000)")
    return ""

