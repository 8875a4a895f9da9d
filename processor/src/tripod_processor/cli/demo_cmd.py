# SPDX-License-Identifier: BSD-3-Clause
"""``tripod demo``: the main job on bundled defaults.

For now it decodes the real VeloView VLP-16 capture beside the repository
(``../shared/data/velodyne/veloview-vlp16-20hz.pcap``) into one PLY per rotation and prints the
summary table; the full simulate → record → reconstruct run replaces it later.
"""

from __future__ import annotations

import os
from pathlib import Path

import typer

from . import app
from ._common import fail

DEMO_CAPTURE = Path("shared") / "data" / "velodyne" / "veloview-vlp16-20hz.pcap"


def find_demo_capture() -> Path | None:
    """The bundled capture: ``../shared/data/...`` from the repository root, found from the
    package location or from the working directory (and their parents)."""
    starts = [Path(__file__).resolve(), Path.cwd().resolve()]
    env = os.environ.get("TRIPOD_SHARED_DATA")
    if env:
        cand = Path(env) / "velodyne" / DEMO_CAPTURE.name
        if cand.is_file():
            return cand
    for start in starts:
        for parent in [start, *start.parents]:
            cand = parent / DEMO_CAPTURE
            if cand.is_file():
                return cand
    return None


@app.command("demo", rich_help_panel="Run")
def demo_command(
    output: Path = typer.Option(Path("demo-output"), "-o", "--output",
                                help="folder for the demo's outputs"),
    input_path: Path = typer.Option(None, "--input", help="capture to use instead of the "
                                    "bundled one"),
) -> None:
    """Run the main job on bundled defaults (now: decode a real VLP-16 capture)."""
    from .decode_cmd import run_decode

    capture = input_path or find_demo_capture()
    if capture is None:
        fail(f"the demo capture {DEMO_CAPTURE} was not found beside the repository "
             "(set TRIPOD_SHARED_DATA to the data folder, or pass --input)")
    run_decode(capture, output, progress=True)
