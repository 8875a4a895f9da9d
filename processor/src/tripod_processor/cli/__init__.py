# SPDX-License-Identifier: BSD-3-Clause
"""``tripod``: the processor's command line. One module per subcommand, registered below.

Heavy imports (open3d, torch) happen inside the commands, so ``tripod --help`` is instant.
"""

from __future__ import annotations

import importlib
import pkgutil
import sys

import typer

app = typer.Typer(
    name="tripod",
    help="Process VLP-16 + IMU tripod recordings into registered indoor models.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)



def _version(value: bool) -> None:
    if value:
        from .. import __version__, _ext  # noqa: F401  (fails loudly if the extension is missing)

        print(f"tripod {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(False, "--version", callback=_version, is_eager=True,
                                 help="Print the version (and check the C++ extension loads)."),
) -> None:
    """Process VLP-16 + IMU tripod recordings into registered indoor models."""


# Every module ``cli/<name>_cmd.py`` defines its command(s) on ``app`` when imported.
for _info in sorted(pkgutil.iter_modules(__path__), key=lambda i: i.name):
    if _info.name.endswith("_cmd"):
        importlib.import_module(f"{__name__}.{_info.name}")


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``tripod``; returns the exit code (2 for bad input, one line, no trace)."""
    try:
        app(args=argv, standalone_mode=True)
    except SystemExit as exc:
        return int(exc.code or 0)
    return 0


if __name__ == "__main__":
    sys.exit(main())
