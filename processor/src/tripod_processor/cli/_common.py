# SPDX-License-Identifier: BSD-3-Clause
"""Helpers shared by the subcommands: one-line errors (exit code 2 for bad input, 1 for a job
that ran and failed), console, cloud input."""

from __future__ import annotations

import sys
from pathlib import Path
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


#: help of the ``--up`` option of the scene commands
UP_HELP = ("the cloud's up direction (against gravity) X,Y,Z in its own frame; overrides the "
           "one the file carries (tripod reconstruct writes it); without either the cloud must "
           "be roughly z up")


def read_points_up(path: Path, up_option: str | None):
    """(cloud, (N, 3) float32 xyz, up (3,) or None, where the up came from: "--up", "file" or
    "none") of the cloud at ``path``: ``--up`` (when given) wins over the file's own. A bad
    file or ``--up`` is one line and exit code 2."""
    from ..io.clouds import CloudFormatError, read_meta
    from ..scene.gravity import parse_up

    cloud, pts = read_points(path)
    if up_option:
        try:
            return cloud, pts, parse_up(up_option), "--up"
        except ValueError as exc:
            fail(str(exc))
    try:
        up = read_meta(path).up
    except (CloudFormatError, OSError) as exc:
        fail(str(exc).splitlines()[0])
    return cloud, pts, up, "file" if up is not None else "none"


def parse_sets(items: list[str] | None) -> dict:
    """``--set KEY=VALUE`` options as a dict of dotted keys to YAML-parsed values."""
    import yaml

    out = {}
    for it in items or []:
        key, sep, val = it.partition("=")
        if not sep or not key:
            fail(f"--set expects KEY=VALUE, got {it!r}")
        out[key.strip()] = yaml.safe_load(val)
    return out


def reconstruct_config(config: Path | None, sets: list[str] | None, calibration: Path | None,
                       defaults: dict | None = None, forced: dict | None = None):
    """The effective ``ReconstructConfig`` of ``tripod reconstruct`` and ``tripod batch``: the
    file, then ``--set``, then the ``--calibration`` file's extrinsic and ``defaults`` where
    ``--set`` did not give them, then ``forced``; a bad value is one line and exit code 2."""
    from tripod_shared.config_io import ConfigError, load_config

    from ..reconstruction.config import ReconstructConfig

    overrides = parse_sets(sets)
    for key, value in (defaults or {}).items():
        overrides.setdefault(key, value)
    if calibration is not None:
        from ..reconstruction.placement import load_extrinsic_file

        try:
            q, lever = load_extrinsic_file(calibration)
        except (OSError, ValueError) as exc:
            fail(f"calibration: {exc}")
        overrides.setdefault("placement.extrinsic.q_imu_lidar", q)
        overrides.setdefault("placement.extrinsic.lever_arm_m", lever)
    overrides.update(forced or {})
    try:
        return load_config(ReconstructConfig, config, overrides)
    except ConfigError as exc:
        fail(str(exc))
